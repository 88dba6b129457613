"""Progress for long commands: rich bars and spinners on a terminal, plain lines anywhere else.

rich redraws a bar in place, which a log file, a CI job or ``nohup`` cannot show: there a long run
printed nothing at all until it ended. Every command with a progress bar or a spinner gets it from
here: on a terminal the usual rich display, otherwise a :class:`PlainProgress` (the same ``Progress``
API) that prints one line when a task starts, at each tenth of the way, at least every
``PROXYBENCH_PROGRESS_SECONDS`` (default 30 s) while it moves, and when it ends.

>>> from rich.console import Console
>>> from rich.progress import MofNCompleteColumn, TextColumn
>>> import io
>>> out = Console(file=io.StringIO())
>>> with progress_bar(TextColumn("episodes"), MofNCompleteColumn(), console=out) as bar:
...     task = bar.add_task("", total=4)
...     for _ in range(4):
...         bar.advance(task)
>>> print(out.file.getvalue().splitlines()[-1])
episodes 4/4 (100%)
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    SpinnerColumn,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.text import Text

from proxybench.cli.app import console as _stdout

__all__ = ["PlainProgress", "PlainStatus", "progress_bar", "stage_bars", "stage_progress", "status"]


def _interval() -> float:
    try:
        return max(float(os.environ.get("PROXYBENCH_PROGRESS_SECONDS", "30")), 0.0)
    except ValueError:
        return 30.0


class PlainProgress(Progress):
    """A rich ``Progress`` that prints plain lines instead of redrawing: for logs, CI and ``nohup``."""

    def __init__(self, *columns: str | ProgressColumn, console: Console | None = None, **kwargs: Any):
        kwargs.pop("transient", None)
        super().__init__(*columns, console=console or _stdout, disable=True, **kwargs)
        self.interval = _interval()
        self._printed: dict[TaskID, tuple[float, int, float]] = {}  # time, tenth, completed of the last line

    def add_task(self, description: str, *args: Any, **kwargs: Any) -> TaskID:
        task_id = super().add_task(description, *args, **kwargs)
        self._report(task_id, force=True)
        return task_id

    def update(self, task_id: TaskID, **kwargs: Any) -> None:
        super().update(task_id, **kwargs)
        self._report(task_id)

    def advance(self, task_id: TaskID, advance: float = 1) -> None:
        super().advance(task_id, advance)
        self._report(task_id)

    def line(self, task_id: TaskID) -> str:
        """The task as one plain line: its text columns (no bar, no spinner) and the share done."""
        task = self._tasks[task_id]
        parts = []
        for column in self.columns:
            if isinstance(column, BarColumn | SpinnerColumn):
                continue
            cell = Text.from_markup(column.format(task=task)) if isinstance(column, str) else column(task)
            text = cell.plain if isinstance(cell, Text) else str(cell)
            if text.strip():
                parts.append(text.strip())
        if task.total:
            parts.append(f"({min(100.0, 100.0 * task.completed / task.total):.0f}%)")
        return " ".join(parts)

    def _report(self, task_id: TaskID, force: bool = False) -> None:
        task = self._tasks[task_id]
        now = time.monotonic()
        tenth = int(10 * task.completed / task.total) if task.total else 0
        last_t, last_tenth, last_done = self._printed.get(task_id, (now, -1, -1.0))
        moved = task.completed != last_done
        if force or (moved and (task.finished or tenth > last_tenth or now - last_t >= self.interval)):
            self._printed[task_id] = (now, tenth, task.completed)
            self.console.print(self.line(task_id), markup=False, highlight=False, emoji=False)


def progress_bar(*columns: str | ProgressColumn, console: Console | None = None, **kwargs: Any) -> Progress:
    """A rich ``Progress`` on a terminal, else a :class:`PlainProgress` with the same columns and API."""
    out = console or _stdout
    if out.is_terminal:
        return Progress(*columns, console=out, **kwargs)
    return PlainProgress(*columns, console=out, **kwargs)


def stage_bars(elapsed: bool = False) -> Progress:
    """Bars for a study's stages (one per stage, added as the stage starts; see :func:`stage_progress`)."""
    columns = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
               *([TimeElapsedColumn()] if elapsed else []), TimeRemainingColumn()]
    return progress_bar(*columns, transient=True)


def stage_progress(bar: Progress) -> Callable[[str, int, int], None]:
    """A study's ``progress(stage, done, total)`` callback drawing on ``bar``: a bar per stage."""
    tasks: dict[str, TaskID] = {}

    def progress(stage: str, done: int, total: int) -> None:
        if stage not in tasks:
            tasks[stage] = bar.add_task(stage, total=total)
        bar.update(tasks[stage], completed=done, total=total)

    return progress


class PlainStatus:
    """The plain-line stand-in for ``console.status``: prints the status when it changes (at most every
    ``PROXYBENCH_PROGRESS_SECONDS``, and always the first)."""

    def __init__(self, text: str, console: Console | None = None):
        self.console = console or _stdout
        self.interval = _interval()
        self._last_t: float | None = None
        self._last_text = ""
        self._pending: str | None = None
        self.update(text)

    def update(self, text: str) -> None:
        now = time.monotonic()
        if text == self._last_text:
            return
        if self._last_t is None or now - self._last_t >= self.interval:
            self._last_t, self._last_text, self._pending = now, text, None
            self.console.print(Text.from_markup(text).plain, markup=False, highlight=False, emoji=False)
        else:
            self._pending = text

    def flush(self) -> None:
        """Print the newest status not yet shown (at the end, so the log shows where it ended)."""
        if self._pending is not None and self._pending != self._last_text:
            self._last_t = None
            self.update(self._pending)


@contextmanager
def status(text: str, console: Console | None = None) -> Iterator[Any]:
    """``console.status(text)`` (a spinner) on a terminal, else a :class:`PlainStatus`; both have ``update``."""
    out = console or _stdout
    if out.is_terminal:
        with out.status(text) as spinner:
            yield spinner
        return
    plain = PlainStatus(text, out)
    try:
        yield plain
    finally:
        plain.flush()
