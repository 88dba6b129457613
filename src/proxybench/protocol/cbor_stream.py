"""Reading a stream of CBOR maps written back to back with no length prefix (the zuper-nodes wire).

A reader must find where one item ends before it can decode it: :class:`CborStream` lets cbor2 decode the
next item and takes its end from the file position, and :func:`item_end` scans CBOR headers (never the
contents of byte strings) for what cbor2 cannot settle: incomplete items, and the ill-formed encodings it
would accept.
"""

from __future__ import annotations

import io
import os
import re
from collections import deque
from typing import Any

import cbor2

from proxybench.untrusted import short_repr

__all__ = ["CborStream", "GarbageError", "NotAMapError", "TruncatedError", "WireError", "item_end"]

_MAX_DEPTH = 256
#: bytes that may be a two-byte simple value under 32 (ill-formed, RFC 8949 §3.3), which cbor2 accepts
_SIMPLE_8BIT = re.compile(rb"\xf8[\x00-\x1f]")
_CONTAINERS_TO_SCAN = frozenset({cbor2.CBORSimpleValue, cbor2.CBORTag, cbor2.FrozenDict, set, frozenset})
#: most maps decoded ahead of the one asked for (an answer to a pipelined step holds 5)
_AHEAD = 8


# ---------------------------------------------------------------------------------------------- errors
class WireError(Exception):
    """The byte stream or a message is unusable; ``reason`` is an :data:`~.failures.REASONS` code."""

    reason = "garbage"


class GarbageError(WireError):
    reason = "garbage"


class NotAMapError(WireError):
    reason = "not-a-map"


class TruncatedError(WireError):
    reason = "truncated"


# ------------------------------------------------------------------------------------- stream reader
def _header(buf, pos: int, end: int) -> tuple[int, int, int] | None:
    """(major type, argument or -1 for indefinite, position after the header), or None if incomplete."""
    ib = buf[pos]
    major, ai = ib >> 5, ib & 0x1F
    if ai < 24:
        return major, ai, pos + 1
    if ai < 28:
        n = 1 << (ai - 24)
        if pos + 1 + n > end:
            return None
        val = int.from_bytes(buf[pos + 1:pos + 1 + n], "big")
        if major == 7 and ai == 24 and val < 32:
            raise GarbageError(f"invalid simple value encoding at byte {pos}")
        return major, val, pos + 1 + n
    if ai == 31 and major in (2, 3, 4, 5):
        return major, -1, pos + 1
    raise GarbageError(f"invalid CBOR initial byte 0x{ib:02x} at byte {pos}")


def item_end(buf: bytes | bytearray, pos: int = 0, end: int | None = None) -> int:
    """Index just past the CBOR item that starts at ``pos``; -1 if ``buf[pos:end]`` holds only part of it.

    Raises :class:`GarbageError` on bytes that cannot start or continue a CBOR item. Only headers are read,
    so a large byte string is skipped in O(1).
    """
    end = len(buf) if end is None else end
    stack = [1]  # items still to read at each open level; -1: indefinite, until a break byte
    while stack:
        if stack[-1] == 0:
            stack.pop()
            continue
        if pos >= end:
            return -1
        if buf[pos] == 0xFF:
            if stack[-1] != -1:
                raise GarbageError(f"unexpected break byte at byte {pos}")
            stack.pop()
            pos += 1
            continue
        head = _header(buf, pos, end)
        if head is None:
            return -1
        major, val, pos = head
        if stack[-1] > 0:
            stack[-1] -= 1
        if major in (2, 3):
            if val >= 0:
                pos += val
                if pos > end:
                    return -1
            else:
                stack.append(-1)
        elif major == 4 and val:
            stack.append(val)
        elif major == 5 and val:
            stack.append(2 * val if val > 0 else -1)
        elif major == 6:
            stack.append(1)
        if len(stack) > _MAX_DEPTH:
            raise GarbageError("CBOR nesting too deep")
    return pos


def _holds_simple_value(obj: Any) -> bool:
    """Whether a decoded item may hold a simple value (True also for the rare tags, sets and frozen maps,
    left to :func:`item_end`): where an ill-formed ``f8 xx`` header would have gone. A walk of the decoded
    values is ~3x cheaper than scanning the headers, and JPEG bytes hold ``f8 xx`` pairs more often than not."""
    stack = [obj]
    while stack:
        value = stack.pop()
        kind = type(value)
        if kind is dict:
            stack += value.values()
            stack += value.keys()
        elif kind is list or kind is tuple:
            stack += value
        elif kind in _CONTAINERS_TO_SCAN:
            return True
    return False


def _looks_like_text(raw: bytes | bytearray) -> bool:
    """Printable text (a stray ``print``): all of ``raw``, or a first line ending in a newline (protocol
    messages may follow it in the same read)."""
    line = raw.find(b"\n")
    if line > 0:
        raw = raw[:line]
    return all(32 <= b < 127 or b in (9, 13) for b in raw)


class CborStream:
    """Incremental reader of a stream of CBOR maps, fed from bytes or a (non-blocking) file descriptor.

    :meth:`next` returns the next complete map, None when more bytes are needed, and raises
    :class:`GarbageError` (not CBOR, or text such as a stray ``print`` on stdout), :class:`NotAMapError`
    (a well-formed non-map value), or :class:`TruncatedError` (the stream ended inside an item).
    A message must start with a map header (0xa0-0xbf), so anything else is classified at once.
    """

    def __init__(self, read_size: int = 1 << 20):
        self._buf = bytearray()
        self._start = 0
        self._scratch = bytearray(read_size)
        self._view = memoryview(self._scratch)
        self.eof = False
        self.bytes_read = 0
        # one decoder for the stream (building one costs more than decoding a small map); reading one byte at
        # a time, it stops exactly at the end of the item it decodes
        self._decoder = cbor2.CBORDecoder(io.BytesIO(b""), read_size=1, max_depth=_MAX_DEPTH)
        self._ready: deque[tuple[dict, int]] = deque()  # maps decoded ahead, with their sizes in bytes

    @property
    def pending(self) -> int:
        """Buffered bytes not yet returned as messages (those decoded ahead included)."""
        return len(self._buf) - self._start

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        self._buf += data
        self.bytes_read += len(data)

    def feed_eof(self) -> None:
        self.eof = True

    def read_from(self, fd: int) -> int | None:
        """One read from ``fd``: bytes read, 0 at end of file, None if it would block."""
        try:
            n = os.readv(fd, [self._view])
        except BlockingIOError:
            return None
        if n == 0:
            self.eof = True
        else:
            self.feed(self._view[:n])
        return n

    def next(self) -> dict | None:
        if self._ready:
            obj, size = self._ready.popleft()
            self._consume(self._start + size)
            return obj
        start, buf = self._start, self._buf
        end = len(buf)
        if start >= end:
            return None
        first = buf[start]
        if 0xA0 <= first <= 0xBF:
            obj = self._fast_map(start, end)
            if obj is not None:
                return obj
        elif _looks_like_text(buf[start:start + 256]):
            raise GarbageError(f"text where a CBOR map was expected: {bytes(buf[start:start + 200])!r}")
        stop = item_end(buf, start, end)
        if stop < 0:
            if self.eof:
                raise TruncatedError(f"stream ended {end - start} bytes into a message: "
                                     f"{bytes(buf[start:start + 40]).hex()}...")
            return None
        obj = self._decode(start, stop)
        self._consume(stop)
        if not isinstance(obj, dict):
            raise NotAMapError(f"a CBOR {type(obj).__name__} where a map was expected: {short_repr(obj, 200)}")
        return obj

    def _fast_map(self, start: int, end: int) -> dict | None:
        """Decode the item at ``start`` with cbor2, which reads exactly one item from its file, so the file's
        position afterwards is where the item ends: no Python header scan and no re-encoding (3-10x faster
        than either). cbor2 accepts one ill-formed encoding the header scan rejects, a two-byte simple value
        under 32 (decoded as a CBORSimpleValue), so an item holding both the bytes that may start one and a
        simple value is checked by :func:`item_end` too.
        Anything cbor2 cannot decode here (incomplete, invalid) falls back to :func:`item_end`.

        The complete maps that follow in the buffer (the rest of an answer) are decoded in the same pass and
        handed out by the next calls, at most :data:`_AHEAD` (a flood stays bounded by the caller's message
        limit); an item that would need a check is left for its own call."""
        buf, decoder = self._buf, self._decoder
        with memoryview(buf) as mv, mv[start:end] as rest:
            decoder.fp = fp = io.BytesIO(rest)
        try:
            obj = decoder.decode()
        except Exception:
            return None
        stop = start + fp.tell()
        if _SIMPLE_8BIT.search(buf, start, stop) is not None and _holds_simple_value(obj) and \
                item_end(buf, start, stop) != stop:
            return None
        pos = stop
        while pos < end and 0xA0 <= buf[pos] <= 0xBF and len(self._ready) < _AHEAD:
            try:
                ahead = decoder.decode()
            except Exception:
                break
            after = start + fp.tell()
            if _SIMPLE_8BIT.search(buf, pos, after) is not None and _holds_simple_value(ahead):
                break
            self._ready.append((ahead, after - pos))
            pos = after
        self._consume(stop)
        return obj

    def _decode(self, start: int, stop: int) -> Any:
        with memoryview(self._buf) as mv, mv[start:stop] as raw:
            try:
                return cbor2.loads(raw)
            except Exception as exc:  # invalid UTF-8, bad tag content, ...
                raise GarbageError(f"undecodable CBOR ({exc}): {bytes(raw[:40]).hex()}...") from exc

    def _consume(self, stop: int) -> None:
        if stop >= len(self._buf):
            self._buf.clear()
            self._start = 0
        elif stop > 1 << 16:
            del self._buf[:stop]
            self._start = 0
        else:
            self._start = stop
