"""A virtual environment of its own, for software whose pins proxybench's environment cannot hold.

duckietown-sdk (``dtps/env.py``: dtps-http pins pydantic exactly) and gym-duckietown (``gym/environment.py``:
numpy 1.23, pyglet 1.5) each live in one, in the user's cache folder, and proxybench reaches them only by
running their interpreter. What the two share is here: where the folder is, making it, and what a check found.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["VenvStatus", "cache_folder", "make_venv", "venv_python"]


@dataclass
class VenvStatus:
    """What a check found: the folder, its interpreter, the versions it runs, and every problem (each naming its
    fix)."""

    path: Path
    python: Path
    versions: dict[str, str] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def cache_folder(variable: str, name: str) -> Path:
    """``$variable`` if set, else ``$XDG_CACHE_HOME/proxybench/NAME``, else ``~/.cache/proxybench/NAME``."""
    if os.environ.get(variable):
        return Path(os.environ[variable])
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "proxybench" / name


def venv_python(path: Path) -> Path:
    return path / "bin" / "python"


def make_venv(path: Path, say: Callable[[str], None], message: str) -> None:
    """Create the environment at ``path`` with this interpreter's venv module, saying ``message``, unless it exists."""
    if venv_python(path).exists():
        return
    say(message)
    path.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "venv", str(path)], check=True)
