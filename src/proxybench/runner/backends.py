"""Where jobs run: in this process, in a local process pool, or on a Ray cluster — one interface.

A backend takes batches of jobs (see ``jobs.batch_group``: episodes that can share one batched
simulator) and yields ``JobResult``s as they finish (any order). Workers keep their simulators between
batches, and use one compiled-kernel thread each, since the pool already uses the cores.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from multiprocessing import get_context
from typing import Protocol

from proxybench.runner.execute import execute_batch
from proxybench.runner.jobs import Job, JobResult

__all__ = ["Backend", "InlineBackend", "LocalBackend", "RayBackend", "make_backend"]


class Backend(Protocol):
    """Runs batches of jobs; yields results as they complete."""

    workers: int

    def run(self, batches: Iterable[list[Job]], out_dir: str | None) -> Iterator[JobResult]: ...

    def close(self) -> None: ...


class InlineBackend:
    """Everything in this process, one job after the other (debugging, tests, single episodes)."""

    workers = 1

    def run(self, batches: Iterable[list[Job]], out_dir: str | None) -> Iterator[JobResult]:
        for batch in batches:
            yield from execute_batch(batch, out_dir)

    def close(self) -> None:
        pass


#: thread-count variables a worker sets (unless the user did) for libraries that start after it
_ONE_THREAD = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


def _init_worker() -> None:
    """One compiled-kernel, OpenMP and PyTorch thread per worker: the pool already uses every core, and
    threads that wait by spinning would take cores from the other workers."""
    for var in _ONE_THREAD:
        os.environ.setdefault(var, "1")  # PyTorch, BLAS and agent subprocesses started from here on
    import sys

    import numba
    from numba.core import config
    from numba.np.ufunc import parallel

    # Numba read NUMBA_NUM_THREADS when it was imported, before this ran (unpickling the work imports it). Its
    # next config reload (at the first compile, i.e. on a fresh install) would find the variable changed after
    # the threads started and raise; so read it now, or where the threads already run, keep it as they are.
    if not getattr(parallel, "_is_initialized", False):
        config.reload_config()
    elif os.environ.get("NUMBA_NUM_THREADS") != str(config.NUMBA_NUM_THREADS):
        os.environ["NUMBA_NUM_THREADS"] = str(config.NUMBA_NUM_THREADS)
    numba.set_num_threads(1)
    if "torch" in sys.modules:  # already started with its own threads
        sys.modules["torch"].set_num_threads(1)


class LocalBackend:
    """A process pool sized to the cores (spawned processes: safe with Numba's threads)."""

    def __init__(self, workers: int | None = None):
        self.workers = max(1, workers or os.cpu_count() or 1)
        self._pool: ProcessPoolExecutor | None = None

    def run(self, batches: Iterable[list[Job]], out_dir: str | None) -> Iterator[JobResult]:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(self.workers, mp_context=get_context("spawn"), initializer=_init_worker)
        pending: set[Future] = set()
        # keep a bounded number in flight so that an interrupt loses little and memory stays flat
        for batch in batches:
            pending.add(self._pool.submit(execute_batch, batch, out_dir))
            if len(pending) >= 2 * self.workers:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in done:
                    yield from f.result()
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                yield from f.result()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


class RayBackend:
    """The same API on Ray: a local instance by default, or a cluster at ``address``."""

    def __init__(self, workers: int | None = None, address: str | None = None):
        try:
            import ray
        except ImportError as exc:
            raise RuntimeError("the Ray backend needs Ray: pip install 'proxybench[ray]'") from exc
        self._ray = ray
        self.workers = max(1, workers or os.cpu_count() or 1)
        if not ray.is_initialized():
            kwargs = {"address": address} if address else {"num_cpus": self.workers}
            ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False, **kwargs)
        self._remote = ray.remote(num_cpus=1)(_ray_execute)

    def run(self, batches: Iterable[list[Job]], out_dir: str | None) -> Iterator[JobResult]:
        ray = self._ray
        pending = []
        for batch in batches:
            pending.append(self._remote.remote(batch, out_dir))
            if len(pending) >= 2 * self.workers:
                done, pending = ray.wait(pending, num_returns=1)
                for results in ray.get(done):
                    yield from results
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for results in ray.get(done):
                yield from results

    def close(self) -> None:
        if self._ray.is_initialized():
            self._ray.shutdown()


def _ray_execute(batch: list[Job], out_dir: str | None) -> list[JobResult]:
    _init_worker()
    return execute_batch(batch, out_dir)


def make_backend(name: str, workers: int | None = None) -> Backend:
    """``inline`` | ``local`` | ``ray`` → a backend."""
    if name == "inline":
        return InlineBackend()
    if name == "local":
        return LocalBackend(workers) if (workers or os.cpu_count() or 1) > 1 else InlineBackend()
    if name == "ray":
        return RayBackend(workers)
    raise ValueError(f"unknown backend {name!r} (inline, local, ray)")
