"""What every report shares: matplotlib off-screen, figures saved as PNG + SVG, the code version behind them."""

from __future__ import annotations

import base64
import html
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from proxybench.plots import pyplot, save_figure

__all__ = ["html_img", "html_table", "pyplot", "save_figure", "source_commit"]


def html_img(path: Path, alt: str) -> str:
    """A PNG embedded in the page (a report is one file a person can mail)."""
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}" style="max-width:100%">'


def html_table(head: Sequence[Any], rows: Sequence[Sequence[Any]]) -> str:
    """A plain HTML table, every cell escaped."""
    return ("<table><tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in head) + "</tr>"
            + "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
            + "</table>")


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
