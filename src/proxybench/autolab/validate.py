"""The DTA's validation phase (thesis §5.3.5): is a localised run fit to be scored?

A run is **invalid**, with the reason, when

- **the robot was lost**: the active robot went unseen for longer than ``lost_s`` while the run was recorded
  (at its start, between two sightings, or before the recording ended);
- **the illumination changed**: some watchtower's frames grew brighter or darker than its first second's
  median by more than ``light_change`` (relative, a frame's mean grey); a robot passing below moves it by a
  few per cent, a lamp going out by tens;
- **it ended prematurely**: the recording stops more than ``end_slack_s`` before the episode's planned length
  without a reason the log states (a robot that left the road ends its run, a recording that crashed does not).

Invalid runs are kept out of the target's episodes and listed in its manifest (``excluded``) with the reason,
so that ``proxybench target check`` and every report say so: nothing is dropped silently.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from proxybench.autolab.localize import Localization
from proxybench.autolab.logs import Log

__all__ = ["Thresholds", "Verdict", "validate_run"]


@dataclass(frozen=True)
class Thresholds:
    """When a run is invalid: lost longer than ``lost_s`` [s], light changed by more than ``light_change``
    [relative], recording ended more than ``end_slack_s`` [s] early."""

    lost_s: float = 1.0
    light_change: float = 0.2
    end_slack_s: float = 1.0


@dataclass
class Verdict:
    """Whether a run may be scored, and why not."""

    valid: bool
    reasons: list[str] = field(default_factory=list)


def _span(log: Log) -> tuple[float, float]:
    """(first, last) frame time of the recording [s]."""
    return min(s.frames[0].t for s in log.streams), max(s.frames[-1].t for s in log.streams)


def lost_gap(times: np.ndarray, start: float, end: float) -> tuple[float, float]:
    """(longest time unseen [s], when it began) over [start, end], sightings at ``times``."""
    edges = np.concatenate([[start], np.asarray(times, dtype=np.float64), [end]])
    gaps = np.diff(edges)
    k = int(np.argmax(gaps))
    return float(gaps[k]), float(edges[k])


def light_changes(loc: Localization) -> dict[str, tuple[float, float]]:
    """Per watchtower: (largest relative change of brightness from its first second's median, when)."""
    out = {}
    for name, rows in loc.brightness.items():
        if rows.size == 0:
            continue
        t, b = rows[:, 0], rows[:, 1]
        ref = float(np.median(b[t <= t[0] + 1.0]))
        rel = np.abs(b - ref) / max(ref, 1.0)
        k = int(np.argmax(rel))
        out[name] = (float(rel[k]), float(t[k]))
    return out


def validate_run(log: Log, loc: Localization, limits: Thresholds | None = None) -> Verdict:
    """The DTA's verdict on one localised run (see the module docstring)."""
    limits = limits or Thresholds()
    m = log.manifest
    reasons = []
    first, last = _span(log)
    track = loc.robots.get(m.active)
    if track is None or track.t.size == 0:
        reasons.append(f"robot {m.active!r} never localised (no watchtower saw its roof tag)")
    else:
        end = last if m.termination is None else min(last, float(track.t[-1]))
        gap, since = lost_gap(track.t, first, end)
        if gap > limits.lost_s:
            reasons.append(f"robot {m.active!r} lost for {gap:.1f} s from t = {since - m.start:.1f} s "
                           f"(threshold {limits.lost_s:g} s)")
    changes = light_changes(loc)
    if changes:
        name, (rel, when) = max(changes.items(), key=lambda kv: kv[1][0])
        if rel > limits.light_change:
            reasons.append(f"illumination changed by {100 * rel:.0f} % at t = {when - m.start:.1f} s (watchtower "
                           f"{name}; threshold {100 * limits.light_change:.0f} %)")
    if m.seconds is not None and m.termination is None:
        recorded = last - m.start
        if recorded < m.seconds - limits.end_slack_s:
            reasons.append(f"ended prematurely: recorded {recorded:.1f} s of {m.seconds:g} s, and the log gives no "
                           "reason (termination)")
    return Verdict(not reasons, reasons)
