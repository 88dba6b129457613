"""How far a real-time plant fell behind the wall clock, and saying so while it happens.

A plant run in real time publishes frame k at T0 + t_k; when simulating (or the robot link) is slower than the
camera's rate, frames go out late and the run drifts behind the wall clock. That used to show only in the
episode's metadata (issue 39: `dtps serve --seconds 90` ran 250–290 s, 126 s behind, and said nothing).
:class:`Lateness` counts it per episode and warns through ``warn`` when the plant is *behind*: more than
``lag_s`` behind at worst, or more than ``share`` of the frames late (after ``min_frames``). Warnings are
rate-limited: once per episode, then again only when the worst lag has doubled since the last one, so a
plant drifting steadily warns a handful of times per episode, never per frame. The first warning ends with
``hint``: what the caller offers instead (lock-step, a smaller camera); later ones point back to it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

__all__ = ["Lateness"]


@dataclass
class Lateness:
    """One episode's lateness: frames, late frames (published more than a frame period after their slot), worst
    lag [s]; ``warn`` (None: count only) hears a warning when it is behind (see the module docstring)."""

    warn: Callable[[str], None] | None = None
    hint: str = ""
    cause: str = "this machine cannot keep the camera's rate"  # why it is late, as the warning says it
    lag_s: float = 0.5
    share: float = 0.10
    min_frames: int = 20
    frames: int = 0
    late: int = 0
    worst: float = 0.0
    warned_at: float | None = field(default=None, repr=False)  # the worst lag at the last warning
    warnings: int = 0
    hinted: bool = field(default=False, repr=False)  # the hint was given (kept across episodes: said once)

    def begin(self) -> None:
        """A new episode: counts back to zero, the next warning allowed at once."""
        self.frames = self.late = self.warnings = 0
        self.worst = 0.0
        self.warned_at = None

    def frame(self, lag: float, dt: float | None) -> None:
        """One frame published ``lag`` seconds after its slot; ``dt``: the frame period (None: the first frame)."""
        self.frames += 1
        if dt is not None and lag > dt:
            self.late += 1
        self.worst = max(self.worst, lag)
        if self.warn is None or not self.behind():
            return
        if self.warned_at is None or self.worst >= 2 * max(self.warned_at, self.lag_s):
            self.warned_at = self.worst
            self.warnings += 1
            self.warn(self.message())

    def behind(self) -> bool:
        """Whether the plant is behind: ``lag_s`` at worst, or ``share`` of ``min_frames`` or more frames late."""
        return self.worst > self.lag_s or (self.frames >= self.min_frames and self.late > self.share * self.frames)

    def message(self) -> str:
        """The warning; its first ends with the hint, later ones point back to it."""
        text = (f"real time is not kept: {self.worst:.1f} s behind the wall clock at worst, {self.late} of "
                f"{self.frames} frames late ({self.cause})")
        if not self.hint:
            return text
        text += f"; {self.hint}" if not self.hinted else "; what to do: see the first warning"
        self.hinted = True
        return text

    def summary(self) -> str:
        """``450 frames, 12 late, worst lag 0.73 s``: the episode's line."""
        return f"{self.frames} frames, {self.late} late, worst lag {self.worst:.2f} s"
