"""The plan study: its config, run, measures' glue and report side by side."""
