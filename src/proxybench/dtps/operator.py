"""The person who puts a real robot back at its start: a prompt, answered on the terminal or from a file.

A real Duckiebot cannot be teleported: before each episode someone places it at the start pose proxybench
prints and answers (Enter: it is there; ``q``: abort). :class:`TerminalOperator` asks on stderr and reads
the answers from the terminal, or from a file (``--dtps-reset-input``: scripted runs, tests). Every wait has
a deadline; an answer that never comes, an input that ended or an abort is a
:class:`~proxybench.protocol.RobotFailure` (``aborted``) saying which.
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import sys
import time
from dataclasses import dataclass
from typing import IO, Protocol

from proxybench.protocol.failures import RobotFailure

__all__ = ["Operator", "PlaceRequest", "TerminalOperator"]


@dataclass(frozen=True)
class PlaceRequest:
    """Put the robot at ``start`` (x [m], y [m], θ [rad]); ``now``: where it says it is; ``note``: why asked again."""

    robot: str
    start: tuple[float, float, float]
    now: tuple[float, float, float] | None
    seed: int
    tile: tuple[int, int] | None = None
    note: str = ""

    def text(self) -> str:
        x, y, th = self.start
        tile = f" (tile {self.tile[0]},{self.tile[1]})" if self.tile else ""
        now = "no pose from it yet" if self.now is None else \
            f"it reports x={self.now[0]:.3f} m, y={self.now[1]:.3f} m, θ={math.degrees(self.now[2]):.1f}°"
        note = f"{self.note} " if self.note else ""
        return (f"[proxybench] {note}DTPS robot {self.robot}: place it at x={x:.3f} m, y={y:.3f} m, "
                f"θ={math.degrees(th):.1f}°{tile} for the episode of seed {self.seed}; {now}. "
                "Press Enter when it stands there (q, Enter: abort).")


class Operator(Protocol):
    """Whoever places the robot: returns when it is placed; :class:`RobotFailure` ``aborted`` otherwise."""

    def place(self, request: PlaceRequest, deadline: float) -> None: ...

    def close(self) -> None: ...


class TerminalOperator:
    """Prompts on ``output`` (default stderr) and reads one answer line per prompt from ``source``: a file (one
    line per answer) or an open file descriptor, else the terminal (``/dev/tty``), else stdin."""

    def __init__(self, source: str | int | None = None, output: IO[str] | None = None):
        self.output = output or sys.stderr
        self.source = source
        self._own = False
        if isinstance(source, int):
            self._fd, self._from = source, f"file descriptor {source}"
        elif source is not None:
            self._fd = os.open(source, os.O_RDONLY)
            self._own = True
            self._from = source
        else:
            try:
                self._fd = os.open("/dev/tty", os.O_RDONLY | os.O_NOCTTY)
                self._own, self._from = True, "the terminal"
            except OSError:
                self._fd, self._from = sys.stdin.fileno(), "stdin"
        self._buf = b""

    def place(self, request: PlaceRequest, deadline: float) -> None:
        print(request.text(), file=self.output, flush=True)
        line = self._readline(deadline)
        if line is None:
            raise RobotFailure("aborted", f"no answer to the reset prompt for {request.robot}: {self._from} ended "
                                          "(no operator? give the answers with --dtps-reset-input FILE, or use "
                                          "--dtps-reset teleport|pose-file)")
        if line.strip().lower() in ("q", "quit", "abort"):
            raise RobotFailure("aborted", f"the operator aborted at the reset prompt for {request.robot}")

    def _readline(self, deadline: float) -> str | None:
        """One line from the source by ``deadline`` (monotonic); None at its end; ``aborted`` at the deadline."""
        while b"\n" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise RobotFailure("aborted", f"no answer to the reset prompt from {self._from} in time")
            ready, _, _ = select.select([self._fd], [], [], min(left, 1.0))
            if not ready:
                continue
            data = os.read(self._fd, 4096)
            if not data:
                if self._buf:
                    line, self._buf = self._buf, b""
                    return line.decode(errors="replace")
                return None
            self._buf += data
        line, _, self._buf = self._buf.partition(b"\n")
        return line.decode(errors="replace")

    def close(self) -> None:
        if self._own:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._own = False
