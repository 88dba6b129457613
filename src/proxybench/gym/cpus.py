"""Which CPUs gym-duckietown's process runs on (``proxybench gym serve --cpus``).

The node, its caller and gym's process wake each other every frame. Beside other busy work the scheduler
often runs gym's process on the same core as them, or as the neighbour, and the node loses a third of gym's
speed; gym's process on a CPU of its own, the node on the others, keeps most of it
(``benchmarks/bench_gym.py --pin``; docs/targets.md has the figures). Opt-in: two nodes on one machine need
different CPUs. ``--cpus auto`` finds one: the last CPU that no other ``auto`` node of this user holds, held by
a lock file per CPU for the node's life (the kernel drops the lock when the process ends, however it ends).
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterable
from pathlib import Path

from proxybench.private import PrivateFileError, make_private_folder, open_private, user_folder

__all__ = ["CpuClaim", "CpuError", "check_cpus", "choose_cpus", "claim_cpu", "cpu_list", "lock_dir", "parse_cpus",
           "pin_node"]


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


class CpuClaim:
    """A CPU held for one node's gym process until :meth:`release` (or the process's end)."""

    def __init__(self, cpu: int, fd: int):
        self.cpu, self._fd = cpu, fd

    def release(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)  # closing the file drops its lock
            self._fd = -1


def lock_dir() -> Path:
    """Where ``--cpus auto`` keeps its lock files: ``gym-cpus`` in the user's private folder (made and checked;
    :class:`CpuError` naming the path where something planted there is not ours)."""
    try:
        return user_folder("gym-cpus")
    except PrivateFileError as exc:
        raise CpuError(f"--cpus auto: {exc}") from None


def claim_cpu(folder: Path | None = None) -> CpuClaim | None:
    """The last CPU this process may use that no other claim holds, leaving the node at least one other; None
    where there is one CPU only, or every one is held (then gym runs where the scheduler puts it). A lock file that
    is not ours (a link, a folder, another user's) skips its CPU; its content is never read."""
    allowed = sorted(os.sched_getaffinity(0))
    if len(allowed) < 2:
        return None
    if folder is None:
        folder = lock_dir()
    else:
        try:
            make_private_folder(folder)
        except PrivateFileError as exc:  # a planted folder or link: not trusted
            raise CpuError(f"--cpus auto: {exc}") from None
    for cpu in reversed(allowed):
        try:  # a planted link, folder, FIFO or another user's file is not our lock: that CPU is skipped
            fd = open_private(folder / f"cpu{cpu}.lock")
        except PrivateFileError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        return CpuClaim(cpu, fd)
    return None


def choose_cpus(text: str | None) -> tuple[list[int] | None, CpuClaim | None]:
    """What ``--cpus TEXT`` asks for: nothing (None), a checked list, or for ``auto`` a claimed CPU (the claim,
    to keep while gym runs; no CPUs and no claim where none is free)."""
    if text is None:
        return None, None
    if text.strip() == "auto":
        claim = claim_cpu()
        return ([claim.cpu] if claim is not None else None), claim
    return check_cpus(parse_cpus(text)), None


def cpu_list(cpus: Iterable[int]) -> str:
    """CPU numbers as a comma-separated list, in order (as messages and taskset show them)."""
    return ",".join(str(c) for c in sorted(cpus))


def check_cpus(cpus: list[int]) -> list[int]:
    """``cpus`` if this process may run on all of them and keeps at least one other for the node."""
    allowed = os.sched_getaffinity(0)
    missing = sorted(set(cpus) - allowed)
    if missing:
        raise CpuError(f"--cpus: CPU {cpu_list(missing)} is not available here (this process may use CPUs "
                       f"{cpu_list(allowed)})")
    if not allowed - set(cpus):
        raise CpuError(f"--cpus {cpu_list(cpus)}: that leaves no CPU for the node itself (it may use CPUs "
                       f"{cpu_list(allowed)}); give gym fewer")
    return cpus


def pin_node(gym_pid: int, cpus: list[int]) -> None:
    """gym's process ``gym_pid`` on ``cpus`` (checked), this process (the node) on the other CPUs it may use."""
    check_cpus(cpus)
    try:
        os.sched_setaffinity(gym_pid, cpus)
        os.sched_setaffinity(0, os.sched_getaffinity(0) - set(cpus))
    except OSError as exc:
        raise CpuError(f"--cpus {cpu_list(cpus)}: {exc.strerror or exc}") from None
