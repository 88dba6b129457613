"""Connections, before any request: a deadline for each request's headers, a cap per client address, and
enough file descriptors.

uvicorn closes an idle connection only *between* requests (``timeout_keep_alive``), and only after a first
one: a socket that connects and sends nothing, or half a request line, is kept for good. With the usual
limit of 1,024 open files, ~2,100 such sockets from anyone stopped every worker (``/health`` failed).
:class:`GuardedHttpToolsProtocol` (uvicorn's httptools protocol, which ``serve`` uses) therefore

- gives every request ``header_timeout`` seconds from the moment the connection opens, or the previous
  response ends, until its headers are complete; then the connection is closed (the body has its own
  limits: :mod:`.limits`);
- keeps at most ``max_per_address`` connections per client address in each worker process; a connection
  beyond them is answered 503 and closed at once (0: no cap, e.g. behind a front that sets its own);

and :func:`raise_open_files` lifts the process's soft ``RLIMIT_NOFILE`` to its hard limit at start.
Settings come from :func:`configure` (``create_app`` calls it with the server's :class:`Settings`).
"""

from __future__ import annotations

import asyncio
import resource
from collections import Counter
from dataclasses import dataclass

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

__all__ = ["PROTOCOL", "ConnectionRules", "GuardedHttpToolsProtocol", "configure", "raise_open_files"]

#: what ``uvicorn.run(http=…)`` takes to use the guarded protocol (an import string: worker processes load it)
PROTOCOL = "proxybench.server.connections:GuardedHttpToolsProtocol"
_BUSY = b'{"detail": "too many connections from your address; close some and retry"}'
_REFUSED = (b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\nretry-after: 5\r\n"
            b"connection: close\r\ncontent-length: " + str(len(_BUSY)).encode() + b"\r\n\r\n" + _BUSY)


@dataclass
class ConnectionRules:
    header_timeout: float = 10.0  # s from connect (or the end of the last response) to complete headers
    max_per_address: int = 256  # open connections per client address and worker process (0: no cap)


_rules = ConnectionRules()
_open: Counter[str] = Counter()  # this process's open connections by client address


def configure(header_timeout: float, max_per_address: int) -> None:
    """The rules for connections of this process (one event loop per uvicorn worker)."""
    _rules.header_timeout, _rules.max_per_address = header_timeout, max_per_address


def open_connections() -> dict[str, int]:
    """Open connections of this process by client address (for tests and diagnostics)."""
    return dict(_open)


def raise_open_files() -> tuple[int, int]:
    """Lift the soft limit of open files to the hard one (many clients, each a socket); the new (soft, hard)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = hard if hard != resource.RLIM_INFINITY else max(soft, 1 << 20)
    if soft != resource.RLIM_INFINITY and soft < want:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
            soft = want
        except (ValueError, OSError):
            pass
    return soft, hard


class GuardedHttpToolsProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with a header deadline and a per-address cap (see the module's docstring)."""

    _address = ""
    _counted = False
    _header_timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._address = self.client[0] if self.client else ""
        cap = _rules.max_per_address
        if cap and _open[self._address] >= cap:
            transport.write(_REFUSED)
            transport.close()
            return
        _open[self._address] += 1
        self._counted = True
        self._arm()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        if self._counted:
            self._counted = False
            _open[self._address] -= 1
            if _open[self._address] <= 0:
                del _open[self._address]
        super().connection_lost(exc)

    def on_headers_complete(self) -> None:
        self._disarm()
        super().on_headers_complete()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if self.timeout_keep_alive_task is not None:  # idle again, waiting for the next request's headers
            self._arm()

    def _arm(self) -> None:
        self._disarm()
        self._header_timer = self.loop.call_later(_rules.header_timeout, self._headers_too_slow)

    def _disarm(self) -> None:
        if self._header_timer is not None:
            self._header_timer.cancel()
            self._header_timer = None

    def _headers_too_slow(self) -> None:
        self._header_timer = None
        if not self.transport.is_closing():
            self.transport.close()
