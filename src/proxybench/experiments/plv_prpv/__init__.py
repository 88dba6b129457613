"""The plv_prpv study: its config, run, measures' glue and report side by side."""
