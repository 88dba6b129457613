"""The front door: every request's body is read in full, within limits of size and time, *before* the
request is admitted to the app; at most ``concurrency`` admitted requests run at once.

Why this order: a client that sends half a body and stalls then holds nothing but its own socket. (Before,
eight such clients held all eight admission slots and froze the API, the web console and /health; one
stalled artifact upload held SQLite's write turn and froze every write.) Bodies arrive on the event loop,
where waiting costs nothing; small ones are kept in memory, larger ones spooled to a file (and hashed on
the way, so an artifact upload is stored by renaming that file). A body must keep coming: a pause longer
than ``timeout`` seconds, or an average rate below ``min_rate`` bytes/s once ``timeout`` seconds have
passed, ends the request with 408 and closes the connection. Over its path's size limit: 413.

At most ``max_readers`` bodies are received at once, ``max_readers_per_address`` of them from one client
address (so one address cannot take them all); a request without a body (no length, or 0) never counts.
Admission is a semaphore of ``concurrency`` slots (the app's worker threads, database connections and
SQLite write turn are sized to it, so they can never run out); at most ``queue`` requests wait for one,
for at most ``queue_timeout`` seconds (then 503 with Retry-After). A slot is given back as soon as the
response starts (the database work is committed by then), and a client that stops reading its response
for ``send_timeout`` seconds is disconnected, so slow readers hold no slot either.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import os
import tempfile
import weakref
from collections import Counter
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["BODY_SCOPE_KEY", "BodyRules", "RequestGate", "SpooledBody"]

BODY_SCOPE_KEY = "proxybench.body"


@dataclass(frozen=True)
class BodyRules:
    """Per-path size limits (longest matching prefix first) and how fast a body must arrive."""

    limits: Sequence[tuple[str, int]]
    default: int
    timeout: float = 30.0  # s: longest pause between pieces, and the grace period before min_rate applies
    min_rate: float = 16_384.0  # bytes/s on average after the grace period
    spool_dir: Path | None = None
    spool_over: int = 64 << 10  # bodies above this many bytes go to a file
    max_readers: int = 1024  # bodies being received at once (beyond: 503)
    max_readers_per_address: int = 32  # of them from one client address (beyond: 503)

    def limit(self, path: str) -> int:
        return next((n for prefix, n in self.limits if path.startswith(prefix)), self.default)


@dataclass
class SpooledBody:
    """A request body as received: in memory (``data``) or in a file (``path``), with its SHA-256."""

    size: int = 0
    sha256: str = ""
    data: bytes | None = None
    path: Path | None = None
    _chunks: list[bytes] = field(default_factory=list, repr=False)

    def discard(self) -> None:
        if self.path is not None:
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()


class _Refusal(Exception):
    def __init__(self, status: int, message: str, headers: Sequence[tuple[bytes, bytes]] = ()) -> None:
        super().__init__(message)
        self.status, self.message, self.headers = status, message, list(headers)


def _has_body(headers: dict[bytes, bytes]) -> bool:
    """Whether a request announces a body (a length above 0, or chunks): only those wait for bytes."""
    if b"transfer-encoding" in headers:
        return True
    length = headers.get(b"content-length", b"0").strip()
    return not (length.isdigit() and int(length) == 0)


async def _answer(send, status: int, message: str, headers: Sequence[tuple[bytes, bytes]] = ()) -> None:
    body = json.dumps({"detail": message}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close"), *headers]})
    await send({"type": "http.response.body", "body": body})


class RequestGate:
    """ASGI middleware: bounded body reading, then bounded admission (see the module's docstring)."""

    def __init__(self, app, *, body: BodyRules, concurrency: int, queue: int = 2048, queue_timeout: float = 60.0,
                 send_timeout: float = 60.0, authorize: Callable[[dict], Awaitable[bool]] | None = None) -> None:
        self.app = app
        self.authorize = authorize
        self.rules = body
        self.concurrency = concurrency
        self.queue = queue
        self.queue_timeout = queue_timeout
        self.send_timeout = send_timeout
        self._loops: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        if body.spool_dir is not None:
            body.spool_dir.mkdir(parents=True, exist_ok=True)

    def _state(self) -> dict[str, Any]:
        loop = asyncio.get_running_loop()
        state = self._loops.get(loop)
        if state is None:
            state = self._loops[loop] = {"sem": asyncio.Semaphore(self.concurrency), "waiting": 0, "reading": 0,
                                         "by_address": Counter()}
        return state

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        state = self._state()
        try:
            body = await self._receive_body(scope, receive, state)
        except _Refusal as exc:
            await _answer(send, exc.status, exc.message, exc.headers)
            return
        if body is None:  # the client went away
            return
        try:
            await self._admitted(scope, receive, send, state, body)
        finally:
            body.discard()

    # -- the body ------------------------------------------------------------------------------------

    async def _receive_body(self, scope, receive, state) -> SpooledBody | None:
        rules = self.rules
        limit = rules.limit(scope["path"])
        headers = dict(scope.get("headers") or [])
        declared = headers.get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            raise _Refusal(413, f"request body exceeds the limit of {limit} bytes")
        if limit > rules.default and self.authorize is not None and not await self.authorize(scope):
            # a large upload (artifact, archive) from someone without a valid token: not a byte of it is read
            raise _Refusal(401, "invalid, revoked or missing API token: send 'Authorization: Bearer <token>' "
                                "(large uploads are refused before their body is read)")
        if not _has_body(headers):  # nothing to wait for: never counted against anyone's readers
            return await self._read(receive, limit)
        address = (scope.get("client") or ("",))[0]
        by_address: Counter[str] = state["by_address"]
        if by_address[address] >= rules.max_readers_per_address:
            raise _Refusal(503, f"too many request bodies from your address are being received "
                                f"({rules.max_readers_per_address}); finish those first", [(b"retry-after", b"2")])
        if state["reading"] >= rules.max_readers:
            raise _Refusal(503, f"too many request bodies are being received ({rules.max_readers}); try again",
                           [(b"retry-after", b"2")])
        state["reading"] += 1
        by_address[address] += 1
        try:
            return await self._read(receive, limit)
        finally:
            state["reading"] -= 1
            by_address[address] -= 1
            if by_address[address] <= 0:
                del by_address[address]

    async def _read(self, receive, limit: int) -> SpooledBody | None:
        rules = self.rules
        loop = asyncio.get_running_loop()
        start = loop.time()
        body = SpooledBody()
        digest = hashlib.sha256()
        spool = None
        try:
            while True:
                allowed = start + rules.timeout + body.size / rules.min_rate - loop.time()
                wait = min(rules.timeout, allowed)
                try:
                    if wait <= 0:
                        raise TimeoutError
                    async with asyncio.timeout(wait):
                        message = await receive()
                except TimeoutError:
                    why = (f"no data for {rules.timeout:g} s" if wait == rules.timeout else
                           f"less than {rules.min_rate:g} bytes/s on average")
                    raise _Refusal(408, f"request body arrived too slowly ({why}, {body.size} bytes received); "
                                        "the connection is closed") from None
                if message["type"] == "http.disconnect":
                    if spool is not None:
                        spool.close()
                    body.discard()
                    return None
                chunk = message.get("body", b"")
                if chunk:
                    body.size += len(chunk)
                    if body.size > limit:
                        raise _Refusal(413, f"request body exceeds the limit of {limit} bytes")
                    digest.update(chunk)
                    if spool is None and body.size > rules.spool_over and rules.spool_dir is not None:
                        fd, name = tempfile.mkstemp(dir=rules.spool_dir, prefix=".body-")
                        spool = os.fdopen(fd, "wb")
                        body.path = Path(name)
                        for earlier in body._chunks:
                            spool.write(earlier)
                        body._chunks.clear()
                    if spool is not None:
                        spool.write(chunk)
                    else:
                        body._chunks.append(chunk)
                if not message.get("more_body", False):
                    break
        except BaseException:
            if spool is not None:
                spool.close()
            body.discard()
            raise
        if spool is not None:
            spool.close()
        else:
            body.data = b"".join(body._chunks)
            body._chunks.clear()
        body.sha256 = digest.hexdigest()
        return body

    # -- admission -----------------------------------------------------------------------------------

    async def _admitted(self, scope, receive, send, state, body: SpooledBody) -> None:
        sem: asyncio.Semaphore = state["sem"]
        if sem.locked():
            if state["waiting"] >= self.queue:
                await _answer(send, 503, f"server busy: {self.queue} requests are waiting already",
                              [(b"retry-after", b"2")])
                return
            state["waiting"] += 1
            try:
                async with asyncio.timeout(self.queue_timeout):
                    await sem.acquire()
            except TimeoutError:
                await _answer(send, 503, f"server busy: no turn within {self.queue_timeout:g} s",
                              [(b"retry-after", b"5")])
                return
            finally:
                state["waiting"] -= 1
        else:
            await sem.acquire()
        held = True

        def release() -> None:
            nonlocal held
            if held:
                held = False
                sem.release()

        scope[BODY_SCOPE_KEY] = body
        replay = _Replay(body, receive)

        async def guarded_send(message) -> None:
            if message["type"] == "http.response.start":
                release()  # the work is done (committed); sending is not worth a slot
            async with asyncio.timeout(self.send_timeout):
                await send(message)

        try:
            await self.app(scope, replay, guarded_send)
        finally:
            release()


class _Replay:
    """``receive`` for the app: the body already received (in memory or from its file), then the client's
    own messages (a disconnect)."""

    def __init__(self, body: SpooledBody, receive) -> None:
        self.body, self.receive = body, receive
        self.file = None
        self.done = False

    async def __call__(self) -> dict[str, Any]:
        if self.done:
            return await self.receive()
        if self.body.path is None:
            self.done = True
            return {"type": "http.request", "body": self.body.data or b"", "more_body": False}
        if self.file is None:
            self.file = open(self.body.path, "rb")  # noqa: SIM115 - closed at its end
        chunk = self.file.read(1 << 20)
        more = len(chunk) == 1 << 20 and self.file.tell() < self.body.size
        if not more:
            self.file.close()
            self.done = True
        return {"type": "http.request", "body": chunk, "more_body": more}
