"""When a compiled kernel runs on several threads, and how the threads share its work.

Why this exists: a ``parallel=True`` loop waits for its slowest thread, and Numba's default OpenMP
threads spin while they wait. With one busy neighbour on a 2-core machine (a PyTorch training loop, a
second sweep) a frame split in two fixed halves waits for the half whose thread the OS has parked, and a
160×120 frame fell from ~4,000 to ~200 steps/s. So:

- the work is cut into small chunks that threads take from a shared counter (:func:`fetch_add`): a
  parked thread delays a frame by the chunk it holds, not by half the frame, and rows of unequal cost
  (sky against near road) balance themselves;
- small work (a small frame) always runs on the calling thread: waking a second thread costs more
  than it saves (:data:`MIN_PARALLEL_WORK`);
- larger work is timed as it runs, on one thread and on all, and the faster is kept (re-checked now and
  then, :class:`ThreadChoice`): with a neighbour on the other core the kernels go back to one thread
  instead of collapsing, and come back when the core is free again;
- a forked child (Gymnasium's async vector env, ``multiprocessing`` with fork) runs on one thread and
  never enters the threading layer (GNU OpenMP aborts a forked child that does), and a process pool
  sets one thread per worker (``runner.backends``); ``numba.set_num_threads(1)`` forces one thread.
"""

from __future__ import annotations

import os
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import ClassVar

import numba as nb
from numba.core import cgutils, types
from numba.extending import intrinsic

__all__ = [
    "MIN_PARALLEL_WORK", "ThreadChoice", "claim_threads", "fetch_add", "force_parallel", "in_forked_child",
    "release_threads", "threads_available",
]

#: below this many pixel-samples (pixels × sub-frames) per call a kernel runs on one thread: measured on
#: 2 shared cores, a 160×120 frame (19,200; ~0.1 ms) gained ~25 % from a second thread when the machine
#: was quiet and took 7× longer when it was not; too short a call to time both modes reliably
MIN_PARALLEL_WORK = 60_000

_forked = False
_forced: bool | None = None


def _after_fork_in_child() -> None:
    global _forked
    _forked = True


os.register_at_fork(after_in_child=_after_fork_in_child)


def in_forked_child() -> bool:
    """True in a process made by ``fork()`` from one that imported proxybench."""
    return _forked


def threads_available() -> int:
    """Threads a kernel may use now: 1 in a forked child, else Numba's current setting."""
    return 1 if _forked else nb.get_num_threads()


_slot = threading.Lock()


def claim_threads() -> bool:
    """Take the right to run a parallel kernel now (False if another Python thread holds it: run serial
    then). One parallel kernel at a time: two would share the same cores anyway, and Numba's workqueue
    layer (the fallback where OpenMP and TBB are missing) aborts the process on concurrent launches."""
    return _slot.acquire(blocking=False)


def release_threads() -> None:
    """Give back what :func:`claim_threads` took."""
    _slot.release()


def force_parallel(value: bool | None) -> None:
    """Run every kernel call that may be parallel on all threads (True) or on one (False), instead of
    timing both (None, the default); for tests and benchmarks. Work below ``MIN_PARALLEL_WORK``, a forked
    child and ``numba.set_num_threads(1)`` stay on one thread whatever this says."""
    global _forced
    _forced = value


@intrinsic
def fetch_add(typingctx, arr, idx, val):
    """Atomically add ``val`` to ``arr[idx]`` (int64 array) and return the old value (a shared work counter)."""
    if not (isinstance(arr, types.Array) and arr.dtype == types.int64 and isinstance(idx, types.Integer)
            and isinstance(val, types.Integer)):
        return None
    sig = types.int64(arr, idx, val)

    def codegen(context, builder, signature, args):
        arr_t, idx_t, val_t = signature.args
        ary = context.make_array(arr_t)(context, builder, args[0])
        index = context.cast(builder, args[1], idx_t, types.intp)
        ptr = cgutils.get_item_pointer(context, builder, arr_t, ary, [index])
        value = context.cast(builder, args[2], val_t, types.int64)
        return builder.atomic_rmw("add", ptr, value, "seq_cst")

    return sig, codegen


class ThreadChoice:
    """Picks one thread or all for repeated calls of one kernel on one size of work, by timing both.

    Each call asks :meth:`parallel` and reports its wall time with :meth:`record`. Calls run on one thread
    until that has been timed; then all threads are tried for ``probe_calls`` calls, and the mode with the
    lower median of its recent timings is kept (parallel must take at most ``margin`` of one thread's time:
    it takes a second core from whatever else runs, and a close call on a loaded machine is often a loss).
    The other mode is tried again after ``probe_every`` seconds, an interval
    that doubles (up to ``max_interval``) each time the try loses, and is at least the try's lost time
    divided by ``try_budget``: a parallel call beside a busy neighbour can cost several serial ones (44–80
    ms against 11 ms measured), so lost tries take at most that share of the time, and a machine that
    becomes quiet is still noticed within ``max_interval``. Get one with :meth:`shared`:
    the load is the machine's, so every simulator with the same work size shares what was measured.
    """

    _registry: ClassVar[dict[tuple, ThreadChoice]] = {}

    def __init__(self, min_work: int = MIN_PARALLEL_WORK, probe_every: float = 0.5, probe_calls: int = 3,
                 max_interval: float = 30.0, margin: float = 0.8, window: int = 5, try_budget: float = 0.01,
                 clock: Callable[[], float] = time.perf_counter):
        self.clock = clock
        self.min_work = min_work
        self.probe_every = probe_every
        self.probe_calls = probe_calls
        self.max_interval = max_interval
        self.margin = margin
        self.try_budget = try_budget
        self._try_lost = 0.0  # seconds the current try took beyond what the kept mode would have
        self.samples: dict[bool, deque[float]] = {False: deque(maxlen=window), True: deque(maxlen=window)}
        self.current = False
        self._interval = probe_every
        self._next_probe = 0.0
        self._probe_left = 0
        self._lock = threading.Lock()

    @classmethod
    def shared(cls, key: tuple) -> ThreadChoice:
        """The choice for kernels of work size ``key``, shared in this process."""
        choice = cls._registry.get(key)
        if choice is None:
            choice = cls._registry.setdefault(key, cls())
        return choice

    def _best(self) -> bool:
        ser, par = self.samples[False], self.samples[True]
        if len(ser) < 2 or len(par) < 2:
            return self.current
        return statistics.median(par) < self.margin * statistics.median(ser)

    def _losing(self, mode: bool, sample: float) -> bool:
        """One call of a try already shows ``mode`` cannot win: stop the try (a parallel call on a loaded
        machine can cost many serial ones, so a try should not insist)."""
        other = self.samples[not mode]
        if not other:
            return False
        ref = statistics.median(other)
        return sample * self.margin >= ref if mode else sample >= self.margin * ref

    def parallel(self, work: int) -> bool:
        """Run the next call of ``work`` units (pixel-samples) on all threads?"""
        if work < self.min_work or threads_available() < 2:
            return False
        if _forced is not None:
            return _forced
        with self._lock:
            if self._probe_left > 0:
                self._probe_left -= 1
                return not self.current
            if len(self.samples[False]) < 2:
                return False
            if self.clock() >= self._next_probe:  # a try: judged on fresh timings only
                self.samples[not self.current].clear()
                self._try_lost = 0.0
                self._probe_left = self.probe_calls - 1
                return not self.current
            return self.current

    def record(self, parallel: bool, seconds: float, work: int) -> None:
        """Report the wall time of a call that :meth:`parallel` was asked about."""
        if work < self.min_work:
            return
        sample = seconds / work
        with self._lock:
            self.samples[parallel].append(sample)
            if parallel != self.current:  # a call of a try
                kept = self.samples[self.current]
                if kept:
                    self._try_lost += seconds - statistics.median(kept) * work
                if self._probe_left > 0 and self._losing(parallel, sample):
                    self._probe_left = 0
                if self._probe_left == 0:  # the try is over
                    best = self._best() if len(self.samples[parallel]) >= 2 else self.current
                    lost_share = max(0.0, self._try_lost) / self.try_budget
                    self._interval = (self.probe_every if best != self.current
                                      else min(max(2 * self._interval, lost_share), self.max_interval))
                    self._next_probe = self.clock() + self._interval
                    self.current = best
            else:
                self.current = self._best()
