"""Progress for long commands: rich bars and spinners on a terminal, plain lines anywhere else.

rich redraws a bar in place, which a log file, a CI job or ``nohup`` cannot show: there a long run
printed nothing at all until it ended. Every command with a progress bar or a spinner gets it from
here: on a terminal the usual rich display, otherwise a :class:`PlainProgress` (the same ``Progress``
API) that prints one line when a task starts, at each tenth of the way, at least every
``PROXYBENCH_PROGRESS_SECONDS`` (default 30 s) while it moves, and when it ends (also when the work ends
without a last update: the final count is printed as the bar closes). Times remaining come from an exponential
moving average of the rate (:class:`SteadyTimeRemainingColumn`), not rich's 30-s window, which jumped with every
batch of episodes (6 min → 12 min → 1.5 min).

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

import math
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

__all__ = ["PlainProgress", "PlainStatus", "RateEstimate", "SteadyTimeRemainingColumn", "progress_bar", "stage_bars",
           "stage_progress", "status"]

#: time constant of the rate's moving average [s]: long against a batch of episodes, short against a study
RATE_TAU_S = 60.0


class RateEstimate:
    """Steps per second as an exponential moving average over time (time constant ``tau``), for a steady ETA.

    The first observation is the baseline only (a resumed run starts at its cached count: no speed in that), the
    next gives the first rate, and each later one moves it by ``1 − exp(−Δt/τ)`` of the way to the rate since
    the one before: a burst of steps a moment apart moves it by the burst over τ, not by a near-infinite rate.

    >>> r = RateEstimate(tau=60.0)
    >>> r.observe(0.0, 100); r.observe(10.0, 110); round(r.rate, 3)
    1.0
    >>> r.eta(50)
    50.0
    """

    def __init__(self, tau: float = RATE_TAU_S):
        self.tau = tau
        self.rate: float | None = None
        self._last: tuple[float, float] | None = None

    def observe(self, t: float, completed: float) -> None:
        """The count ``completed`` at time ``t`` [s] (unchanged counts are ignored; the clock only moves on)."""
        if self._last is None:
            self._last = (t, completed)
            return
        t0, c0 = self._last
        if completed == c0 or t <= t0:
            return
        step_rate = max(completed - c0, 0.0) / (t - t0)
        if self.rate is None:
            self.rate = step_rate
        else:
            self.rate += (1.0 - math.exp(-(t - t0) / self.tau)) * (step_rate - self.rate)
        self._last = (t, completed)

    def eta(self, remaining: float) -> float | None:
        """Seconds for ``remaining`` steps at the estimated rate; None before there is a rate."""
        if not self.rate:
            return None
        return remaining / self.rate


class SteadyTimeRemainingColumn(TimeRemainingColumn):
    """rich's time-remaining column with the rate of :class:`RateEstimate` (one per task)."""

    def __init__(self, *args: Any, tau: float = RATE_TAU_S, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.tau = tau
        self._rates: dict[TaskID, RateEstimate] = {}

    def render(self, task: Any) -> Text:
        if task.total is None or task.finished:
            return super().render(task)
        rate = self._rates.setdefault(task.id, RateEstimate(self.tau))
        rate.observe(task.get_time(), task.completed)
        eta = rate.eta(max(task.total - task.completed, 0.0))
        if eta is None:
            return Text("--:--" if self.compact else "-:--:--", style="progress.remaining")
        minutes, seconds = divmod(int(math.ceil(eta)), 60)
        hours, minutes = divmod(minutes, 60)
        text = (f"{minutes:02d}:{seconds:02d}" if self.compact and not hours
                else f"{hours:d}:{minutes:02d}:{seconds:02d}")
        return Text(text, style="progress.remaining")


def _steady(column: str | ProgressColumn) -> str | ProgressColumn:
    """rich's own time-remaining column → the steady one (same settings); anything else as it is."""
    if type(column) is TimeRemainingColumn:
        return SteadyTimeRemainingColumn(compact=column.compact, elapsed_when_finished=column.elapsed_when_finished,
                                         table_column=column.get_table_column())
    return column


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

    def stop(self) -> None:
        """Print each task's last count if its last line did not show it (work that ended between lines)."""
        for task_id, task in list(self._tasks.items()):
            if self._printed.get(task_id, (0.0, -1, None))[2] != task.completed:
                self._report(task_id, force=True)
        super().stop()

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
    columns = tuple(_steady(c) for c in columns)
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
        if stage not in tasks:  # its first count is the baseline: how long that much took is not known
            tasks[stage] = bar.add_task(stage, total=total, completed=done)  # (a study's first target once read 1 s)
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
