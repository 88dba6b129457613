"""Request-body size limits, enforced while the body streams in (a lying Content-Length cannot get past)."""

from __future__ import annotations

import asyncio
import json
import weakref
from collections.abc import Sequence

__all__ = ["BodyLimit", "ConcurrencyLimit"]


class _TooLarge(Exception):
    pass


class BodyLimit:
    """ASGI middleware: 413 with a clear message once a request body exceeds its path's limit."""

    def __init__(self, app, limits: Sequence[tuple[str, int]], default: int) -> None:
        self.app = app
        self.limits = list(limits)
        self.default = default

    def _limit(self, path: str) -> int:
        return next((n for prefix, n in self.limits if path.startswith(prefix)), self.default)

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self._limit(scope["path"])
        declared = dict(scope.get("headers") or []).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            await self._refuse(send, limit)
            return
        seen = 0
        started = False
        exceeded = False

        async def counting_receive():
            nonlocal seen, exceeded
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    exceeded = True
                    raise _TooLarge
            return message

        async def tracking_send(message) -> None:
            nonlocal started
            if exceeded:  # the app turned our exception into its own error reply: answer 413 instead
                if not started:
                    started = True
                    await self._refuse(send, limit)
                return
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counting_receive, tracking_send)
        except _TooLarge:
            if not started:
                await self._refuse(send, limit)

    @staticmethod
    async def _refuse(send, limit: int) -> None:
        body = json.dumps({"detail": f"request body exceeds the limit of {limit} bytes"}).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})


class ConcurrencyLimit:
    """ASGI middleware: at most ``limit`` requests in progress; the rest wait their turn on the event loop.

    Waiting here holds nothing, so the resources a request needs once admitted (a worker thread, a database
    connection, the SQLite write turn) are sized to ``limit`` and can never run out — without it, requests
    that had taken pooled connections could wait for worker threads held by requests waiting for
    connections (a deadlock seen with 200 clients). One process has one GIL: more requests at once only
    add switching.
    """

    def __init__(self, app, limit: int) -> None:
        self.app = app
        self.limit = limit
        self._sems: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        loop = asyncio.get_running_loop()
        sem = self._sems.get(loop)
        if sem is None:
            sem = self._sems[loop] = asyncio.Semaphore(self.limit)
        async with sem:
            await self.app(scope, receive, send)
