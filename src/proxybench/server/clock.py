"""The server's clock for leases and evaluator health: monotonic, so a wall-clock step cannot end leases.

``now()`` is ``CLOCK_MONOTONIC`` shifted to read like UNIX seconds: the shift (wall time minus monotonic
time) is taken once, when the server starts, and handed to every worker process in
``PROXYBENCH_SERVER_CLOCK_ANCHOR`` (workers on one machine share the monotonic clock, so they agree to the
microsecond). An NTP step or a manual ``date -s`` while the server runs moves neither lease expiries nor
"last seen" times; a restart re-anchors on the wall clock, so stored times stay comparable across restarts.
Times people read (created, finished) stay wall-clock times.
"""

from __future__ import annotations

import os
import time

__all__ = ["ANCHOR_ENV", "anchor", "now"]

ANCHOR_ENV = "PROXYBENCH_SERVER_CLOCK_ANCHOR"


def _initial_anchor() -> float:
    raw = os.environ.get(ANCHOR_ENV)
    if raw:
        try:
            return float(raw)
        except ValueError:
            pass
    return time.time() - time.monotonic()


_anchor = _initial_anchor()


def anchor() -> float:
    """The shift in use (to hand to worker processes)."""
    return _anchor


def now() -> float:
    """Server time in seconds: monotonic, on the scale of UNIX time."""
    return _anchor + time.monotonic()
