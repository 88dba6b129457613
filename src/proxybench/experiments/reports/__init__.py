"""Reports of the studies: terminal tables, figures (PNG + SVG) and self-contained HTML pages, in one place."""
