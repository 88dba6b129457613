"""The repeatability study: its config, run, measures' glue and report side by side."""
