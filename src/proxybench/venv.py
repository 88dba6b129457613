"""A virtual environment of its own, for software whose pins proxybench's environment cannot hold.

duckietown-sdk (``dtps/env.py``: dtps-http pins pydantic exactly) and gym-duckietown (``gym/environment.py``:
numpy 1.23, pyglet 1.5) each live in one, in the user's cache folder, and proxybench reaches them only by
running their interpreter. What the two share is here: where the folder is, making it, installing into it with
pip while saying how far it got (:func:`pip_install`, :class:`Steps`: a setup takes minutes on a busy machine
and must not be silent meanwhile), and what a check found.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["PipError", "Steps", "VenvStatus", "cache_folder", "duration", "make_venv", "pip_install",
           "requirement_count", "venv_python"]

Say = Callable[[str], None]


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


def make_venv(path: Path) -> None:
    """Create the environment at ``path`` with this interpreter's venv module, unless it exists."""
    if venv_python(path).exists():
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "venv", str(path)], check=True)


def duration(seconds: float) -> str:
    """``3.2 s``, ``4 min 05 s``: a step's or a setup's time as a person reads it."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(round(seconds), 60)
    return f"{minutes} min {secs:02d} s"


class Steps:
    """A setup's numbered, timed steps: ``2/4 creating the virtual environment`` when one starts, its time when
    it ends, ``2/4 virtual environment: in place`` for one with nothing to do, and the total at the end.
    ``clock`` is injectable so that tests need no wall clock."""

    def __init__(self, total: int, say: Say, clock: Callable[[], float] = time.monotonic):
        self.total, self.say, self.clock = total, say, clock
        self.k = 0
        self.worked = False  # whether any step did something (else the setup "had nothing to do")
        self.start = clock()

    def _next(self) -> str:
        self.k += 1
        return f"{self.k}/{self.total}"

    def in_place(self, text: str) -> None:
        """A step with nothing to do: say so and move on."""
        self.say(f"{self._next()} {text}")

    @contextmanager
    def step(self, text: str, *, work: bool = True) -> Iterator[None]:
        """A step that runs (``work``: it changes something, unlike a check); its time is said when it ends."""
        number = self._next()
        self.say(f"{number} {text} ...")
        began = self.clock()
        self.worked = self.worked or work
        yield
        self.say(f"    {number} done in {duration(self.clock() - began)}")

    def elapsed(self) -> float:
        return self.clock() - self.start


class PipError(RuntimeError):
    """pip failed; ``tail`` holds its last output lines (what went wrong)."""

    def __init__(self, cmd: Sequence[str], returncode: int, tail: list[str]):
        self.cmd, self.returncode, self.tail = list(cmd), returncode, tail
        super().__init__(f"{' '.join(self.cmd)} failed (exit status {returncode}):\n" + "\n".join(tail))


def requirement_count(lines: Sequence[str]) -> int:
    """How many packages a requirements file's lines name (comments, blanks and pip options left out)."""
    return sum(1 for line in lines if line.strip() and not line.lstrip().startswith(("#", "-")))


def pip_install(python: Path, args: Sequence[str], say: Say, *, expected: int | None = None,
                every: float = 15.0, clock: Callable[[], float] = time.monotonic) -> None:
    """``python -m pip install ARGS``, saying how far it got: packages fetched so far (of ``expected`` when
    known), at most every ``every`` seconds, and when it moves on to installing them. :class:`PipError` with
    pip's last lines on failure."""
    cmd = [str(python), "-m", "pip", "install", "--disable-pip-version-check", "--progress-bar", "off", *args]
    tail: deque[str] = deque(maxlen=15)
    fetched, began = 0, clock()
    last_said = began
    of = f"/{expected}" if expected else ""
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1) as proc:
        assert proc.stdout is not None
        for line in proc.stdout:
            line = line.rstrip()
            tail.append(line)
            if line.startswith(("Collecting ", "Processing ")):  # from an index / from a local file or link
                fetched += 1
                if clock() - last_said >= every:
                    last_said = clock()
                    say(f"    {fetched}{of} packages fetched ({duration(last_said - began)})")
            elif line.startswith("Installing collected packages:"):
                count = len(line.partition(":")[2].split(","))
                say(f"    {fetched}{of} packages fetched; installing {count} of them "
                    f"({duration(clock() - began)})")
                last_said = clock()
    if proc.returncode != 0:
        raise PipError(cmd, proc.returncode, list(tail))
