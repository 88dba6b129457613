"""The private pipe format between proxybench and its DTPS bridge process: length-prefixed CBOR maps.

Each message is a 4-byte big-endian length followed by that many bytes of one CBOR map. The bridge runs
in the SDK's own environment (another interpreter, another pydantic), so this module imports only the
standard library and ``cbor2`` (which both environments have): proxybench imports it as
``proxybench.dtps.pipe``, the bridge loads this very file by its path. Nothing here trusts the other side:
a length over :data:`MAX_MESSAGE` or a value that is not a map is a :class:`PipeError`.

Requests (proxybench → bridge) carry ``op``, events (bridge → proxybench) carry ``ev``; the keys of each
are listed in docs/dtps.md ("The bridge").
"""

from __future__ import annotations

import os
import struct
from typing import Any

import cbor2

__all__ = ["MAX_MESSAGE", "PipeError", "Reader", "pack"]

#: the largest message either side accepts [bytes] (a 640×480 JPEG is ~20 KB; a map layer a few hundred KB)
MAX_MESSAGE = 16 << 20
_HEAD = struct.Struct(">I")


class PipeError(ValueError):
    """The other side wrote something that is not a message of this format."""


def pack(message: dict[str, Any]) -> bytes:
    """One message as bytes on the pipe."""
    body = cbor2.dumps(message)
    return _HEAD.pack(len(body)) + body


class Reader:
    """Splits a byte stream into messages: feed it what ``read`` returned, take complete messages out."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.eof = False

    def feed(self, data: bytes) -> None:
        if not data:
            self.eof = True
        self._buf += data

    def read_from(self, fd: int, size: int = 1 << 20) -> int:
        """Read what is there from a non-blocking ``fd`` (0 at end of stream, -1 when nothing is ready)."""
        try:
            data = os.read(fd, size)
        except BlockingIOError:
            return -1
        self.feed(data)
        return len(data)

    def next(self) -> dict[str, Any] | None:
        """The next complete message, or None until more bytes arrive."""
        if len(self._buf) < _HEAD.size:
            return None
        (n,) = _HEAD.unpack_from(self._buf)
        if n > MAX_MESSAGE:
            raise PipeError(f"a message of {n} bytes (more than {MAX_MESSAGE})")
        if len(self._buf) < _HEAD.size + n:
            return None
        body = bytes(self._buf[_HEAD.size : _HEAD.size + n])
        del self._buf[: _HEAD.size + n]
        try:
            msg = cbor2.loads(body)
        except Exception as exc:  # cbor2 raises several types on bad input
            raise PipeError(f"not CBOR: {exc}") from None
        if not isinstance(msg, dict):
            raise PipeError(f"a {type(msg).__name__}, not a map")
        return msg
