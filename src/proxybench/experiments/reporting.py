"""What every report shares: matplotlib off-screen, figures saved as PNG + SVG, the code version behind them."""

from __future__ import annotations

import subprocess
from pathlib import Path

from proxybench.plots import pyplot, save_figure

__all__ = ["pyplot", "save_figure", "source_commit"]


def source_commit() -> str:
    """The git commit of the proxybench sources in use (``+dirty`` with local changes), or why it is unknown."""
    here = Path(__file__).resolve().parent
    try:
        rev = subprocess.run(["git", "-C", str(here), "rev-parse", "--short=12", "HEAD"], capture_output=True,
                             text=True, timeout=5)
        if rev.returncode != 0:
            return "unknown (not a git checkout)"
        dirty = subprocess.run(["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5)
        return rev.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown (git not available)"
