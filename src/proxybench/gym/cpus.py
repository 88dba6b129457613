"""Which CPUs gym-duckietown's process runs on (``proxybench gym serve --cpus``).

The node, its caller and gym's process wake each other every frame. Beside other busy work the scheduler
often runs gym's process on the same core as them, or as the neighbour, and the node loses a third of gym's
speed; gym's process on a CPU of its own, the node on the others, keeps most of it
(``benchmarks/bench_gym.py --pin``; docs/targets.md has the figures). Opt-in: two nodes on one machine need
different CPUs, which only the user knows.
"""

from __future__ import annotations

import os
from collections.abc import Iterable

__all__ = ["CpuError", "check_cpus", "parse_cpus", "pin_node"]


class CpuError(ValueError):
    """A ``--cpus`` value that cannot be used here (says which and why)."""


def parse_cpus(text: str) -> list[int]:
    """CPU numbers from a list like ``3``, ``2,3`` or ``0-1,4`` (as ``taskset -c`` takes them)."""
    cpus: set[int] = set()
    for part in text.split(","):
        lo, sep, hi = part.strip().partition("-")
        try:
            first, last = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise CpuError(f"--cpus {text!r}: {part.strip()!r} is not a CPU number or a range like 2-3") from None
        if first < 0 or last < first:
            raise CpuError(f"--cpus {text!r}: {part.strip()!r} is not a CPU number or a range like 2-3")
        cpus.update(range(first, last + 1))
    return sorted(cpus)


def _ranges(cpus: Iterable[int]) -> str:
    return ",".join(str(c) for c in sorted(cpus))


def check_cpus(cpus: list[int]) -> list[int]:
    """``cpus`` if this process may run on all of them and keeps at least one other for the node."""
    allowed = os.sched_getaffinity(0)
    missing = sorted(set(cpus) - allowed)
    if missing:
        raise CpuError(f"--cpus: CPU {_ranges(missing)} is not available here (this process may use CPUs "
                       f"{_ranges(allowed)})")
    if not allowed - set(cpus):
        raise CpuError(f"--cpus {_ranges(cpus)}: that leaves no CPU for the node itself (it may use CPUs "
                       f"{_ranges(allowed)}); give gym fewer")
    return cpus


def pin_node(gym_pid: int, cpus: list[int]) -> None:
    """gym's process ``gym_pid`` on ``cpus`` (checked), this process (the node) on the other CPUs it may use."""
    check_cpus(cpus)
    try:
        os.sched_setaffinity(gym_pid, cpus)
        os.sched_setaffinity(0, os.sched_getaffinity(0) - set(cpus))
    except OSError as exc:
        raise CpuError(f"--cpus {_ranges(cpus)}: {exc.strerror or exc}") from None
