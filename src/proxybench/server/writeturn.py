"""SQLite's one writer at a time, taken in turn instead of by busy-waiting, across threads and processes.

Writing requests queue on an asyncio lock of their event loop *before* they take a worker thread (SQLite's
own busy handler sleeps in steps of up to 100 ms: p99 of seconds under load; a thread lock deadlocked
once, waiting writers holding every worker thread). With several server processes on one SQLite file,
the holder of a process's lock then takes an ``flock`` on ``<data_dir>/write.lock`` (in a worker thread:
at most one per process waits there), so the processes take turns too. PostgreSQL needs none of this
(row locks), so there is no turn to take on it.
"""

from __future__ import annotations

import asyncio
import fcntl
import os
import weakref
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from starlette.concurrency import run_in_threadpool

__all__ = ["WriteTurn"]


class WriteTurn:
    """``async with turn.hold(): …`` — the right to write, for one request (``lock_file``: shared by processes)."""

    def __init__(self, lock_file: Path | None = None) -> None:
        self._locks: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        self._fd = os.open(lock_file, os.O_RDWR | os.O_CREAT, 0o600) if lock_file is not None else None

    def _lock(self) -> asyncio.Lock:
        loop = asyncio.get_running_loop()
        lock = self._locks.get(loop)
        if lock is None:
            lock = self._locks[loop] = asyncio.Lock()
        return lock

    @asynccontextmanager
    async def hold(self) -> AsyncIterator[None]:
        async with self._lock():
            if self._fd is None:
                yield
                return
            await run_in_threadpool(fcntl.flock, self._fd, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(self._fd, fcntl.LOCK_UN)

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
