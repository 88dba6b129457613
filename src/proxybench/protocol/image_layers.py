"""The checks every layer of a container image passes before anything of it is unpacked.

An image comes from a stranger, so each layer (a tar stream, plain, gzip or zstd) is read once, as a stream,
before ``umoci`` writes a single file: its compressed bytes must hash to the manifest's digest and size, its
uncompressed bytes to the config's ``diff_id``, and every member must keep to the root file system:

- a path never holds a ``..`` component and never names the root itself;
- a hard link's target is a path inside the root under the same rules;
- no member is written *through* a symbolic link that this or an earlier layer made (``etc -> /`` then
  ``etc/passwd``): the tar engine would follow it, and where it leads is the host's file system;
- a whiteout (``.wh.NAME``) removes one name in its own folder, never ``.``, ``..`` or the root;
- no devices (a rootless unpack cannot make them; an agent has no use for them), no sparse members;
- members, bytes and time are bounded across the whole image (:class:`~proxybench.protocol.images.ImageLimits`),
  so a layer of a million empty files stops at the limit, after reading that many headers, not a million.

Errors are :class:`ImageError`, one line naming the layer (its index and digest) and the member at fault.
"""

from __future__ import annotations

import gzip
import hashlib
import io
import posixpath
import tarfile
import time
import zlib
from typing import IO

from proxybench.protocol.package import BoundedTarInfo, PackageError

__all__ = ["LAYER_TYPES", "ImageError", "LayerBudget", "SymlinkTracker", "scan_layer", "sniff"]

CHUNK = 1 << 20
_MAX_PATH = 4096
_MAX_COMPONENT = 255
_WHITEOUT = ".wh."
_OPAQUE = ".wh..wh..opq"
#: layer media type → compression
LAYER_TYPES = {
    "application/vnd.oci.image.layer.v1.tar": "none",
    "application/vnd.oci.image.layer.v1.tar+gzip": "gzip",
    "application/vnd.oci.image.layer.v1.tar+zstd": "zstd",
    "application/vnd.docker.image.rootfs.diff.tar": "none",
    "application/vnd.docker.image.rootfs.diff.tar.gzip": "gzip",
}


class ImageError(ValueError):
    """A container image that is refused; the message names the layer, member or field at fault."""


class LayerBudget:
    """Members, uncompressed bytes and time spent over the whole image; raises :class:`ImageError` when any runs
    out, so one budget bounds every layer together."""

    def __init__(self, max_members: int, max_bytes: int, deadline: float) -> None:
        self.max_members, self.max_bytes, self.deadline = max_members, max_bytes, deadline
        self.members = 0
        self.bytes = 0

    def count(self, where: str) -> None:
        self.members += 1
        if self.members > self.max_members:
            raise ImageError(f"{where}: the image holds more than {self.max_members} members")
        self.clock(where)

    def spend(self, n: int, where: str) -> None:
        self.bytes += n
        if self.bytes > self.max_bytes:
            raise ImageError(f"{where}: the image unpacks to more than {self.max_bytes} bytes")

    def clock(self, where: str) -> None:
        if time.monotonic() > self.deadline:
            raise ImageError(f"{where}: checking the image took longer than its time limit")


class _Hashed(io.RawIOBase):
    """A stream read through once, its bytes hashed and counted as they are read: a layer's compressed bytes (the
    manifest's digest and size), or with a ``budget`` its uncompressed tar stream (the config's diff_id), each
    read spent against the budget."""

    def __init__(self, inner: IO[bytes], budget: LayerBudget | None = None, where: str = "") -> None:
        self.inner, self.budget, self.where = inner, budget, where
        self.sha = hashlib.sha256()
        self.size = 0

    def readable(self) -> bool:
        return True

    def readinto(self, buf) -> int:  # type: ignore[no-untyped-def]
        data = self.inner.read(len(buf))
        buf[: len(data)] = data
        self.sha.update(data)
        self.size += len(data)
        if self.budget is not None:
            self.budget.spend(len(data), self.where)
        return len(data)


def _decompressor(raw: IO[bytes], compression: str) -> IO[bytes]:
    if compression == "gzip":
        return gzip.GzipFile(fileobj=raw, mode="rb")  # type: ignore[return-value]
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().stream_reader(raw, read_across_frames=True)  # type: ignore[return-value]
    return raw


def layer_path(name: str, where: str) -> str:
    """A member's path relative to the root (``./usr/bin`` and ``/usr/bin`` → ``usr/bin``), refused when it holds
    ``..``, a NUL, an over-long name, or names the root itself where a file belongs."""
    if "\x00" in name or len(name) > _MAX_PATH:
        raise ImageError(f"{where}: member {name[:80]!r}: NUL or a path over {_MAX_PATH} characters")
    parts = [p for p in name.split("/") if p not in ("", ".")]
    if ".." in parts:
        raise ImageError(f"{where}: member {name!r}: path has a '..' component (it would leave the root)")
    if any(len(p.encode("utf-8", "surrogateescape")) > _MAX_COMPONENT for p in parts):
        raise ImageError(f"{where}: member {name[:80]!r}: a name longer than {_MAX_COMPONENT} bytes")
    return "/".join(parts)


def _ancestors(path: str) -> list[str]:
    """``a/b/c`` → ``a``, ``a/b``."""
    parts = path.split("/")[:-1]
    return ["/".join(parts[: k + 1]) for k in range(len(parts))]


class SymlinkTracker:
    """The paths that are symbolic links in the image as applied so far, so that a member written below one (the
    tar engine would follow it) is refused. ``holders``: folders with a link somewhere below, so that removing a
    folder scans the links only where there are some."""

    def __init__(self) -> None:
        self.links: set[str] = set()
        self.holders: dict[str, int] = {}
        self.this_layer: set[str] = set()

    def start_layer(self) -> None:
        self.this_layer = set()

    def check(self, path: str, member: str, where: str) -> None:
        for parent in _ancestors(path):
            if parent in self.links:
                raise ImageError(f"{where}: member {member!r} is written through the symbolic link {parent!r} "
                                 "(the unpacker would follow it out of its folder)")

    def _add(self, path: str) -> None:
        if path not in self.links:
            self.links.add(path)
            for a in _ancestors(path):
                self.holders[a] = self.holders.get(a, 0) + 1

    def _drop(self, path: str) -> None:
        if path in self.links:
            self.links.discard(path)
            for a in _ancestors(path):
                self.holders[a] -= 1
                if not self.holders[a]:
                    del self.holders[a]

    def _drop_below(self, folder: str, keep_this_layer: bool = False) -> None:
        if folder and folder not in self.holders:
            return
        prefix = folder + "/" if folder else ""
        for link in [s for s in self.links if s.startswith(prefix)]:
            if not (keep_this_layer and link in self.this_layer):
                self._drop(link)

    def put(self, path: str, is_link: bool, is_dir: bool) -> None:
        """A member at ``path``: a link replaces what was there; anything else replaces a link there (and a
        non-folder everything below it)."""
        if is_link:
            self._drop_below(path)
            self._add(path)
            self.this_layer.add(path)
            return
        self._drop(path)
        if not is_dir:
            self._drop_below(path)

    def whiteout(self, path: str) -> None:
        self._drop(path)
        self._drop_below(path)

    def opaque(self, folder: str) -> None:
        self._drop_below(folder, keep_this_layer=True)


def _whiteout(path: str, member: str, where: str, links: SymlinkTracker) -> None:
    folder, base = posixpath.split(path)
    if base == _OPAQUE:
        links.opaque(folder)
        return
    target = base[len(_WHITEOUT):]
    if target in ("", ".", "..") or target.startswith(_WHITEOUT):
        raise ImageError(f"{where}: member {member!r}: a whiteout of {target or '(nothing)'!r} "
                         f"({'the root or its parent' if target in ('.', '..') else 'not a name'})")
    links.whiteout(posixpath.join(folder, target))


def _member(m: tarfile.TarInfo, where: str, links: SymlinkTracker) -> None:
    """One member's checks, then its effect on the links seen so far."""
    path = layer_path(m.name, where)
    links.check(path, m.name, where)
    if posixpath.basename(path).startswith(_WHITEOUT):
        if not (m.isfile() and m.size == 0) and not m.isdir():
            raise ImageError(f"{where}: member {m.name!r}: a whiteout must be an empty file")
        _whiteout(path, m.name, where, links)
        return
    if not path and not m.isdir():
        raise ImageError(f"{where}: member {m.name!r}: only a folder can stand for the root")
    if m.ischr() or m.isblk():
        raise ImageError(f"{where}: member {m.name!r}: device files are not allowed")
    if m.islnk():
        target = layer_path(m.linkname, where)
        if not target:
            raise ImageError(f"{where}: member {m.name!r}: a hard link to the root")
        links.check(target, m.name, where)
        if target in links.links:
            raise ImageError(f"{where}: member {m.name!r}: a hard link to the symbolic link {target!r}")
    elif m.issym():
        if not m.linkname or "\x00" in m.linkname or len(m.linkname) > _MAX_PATH:
            raise ImageError(f"{where}: member {m.name!r}: a symbolic link with an empty or over-long target")
    elif not (m.isfile() or m.isdir() or m.isfifo()):
        raise ImageError(f"{where}: member {m.name!r}: tar type {m.type!r} is not allowed")
    if path:
        links.put(path, m.issym(), m.isdir())


def _next(tf: tarfile.TarFile, stream: IO[bytes]) -> tarfile.TarInfo | None:
    """The next member; a stream that ends after a member without the end-of-archive blocks (umoci 0.4's own
    layers do) ends the layer, as it does for Docker and umoci. A member cut short still fails: at unpacking."""
    try:
        return tf.next()
    except tarfile.ReadError as exc:
        if str(exc) == "unexpected end of data" and tf.offset > 0 and not stream.read(1):
            return None
        raise


def sniff(head: bytes) -> str:
    """The compression the first bytes of a layer show."""
    if head[:2] == b"\x1f\x8b":
        return "gzip"
    if head[:4] == b"\x28\xb5\x2f\xfd":
        return "zstd"
    return "none"


def scan_layer(blob: IO[bytes], *, index: int, digest: str, size: int, diff_id: str, compression: str,
               budget: LayerBudget, links: SymlinkTracker) -> None:
    """Read the layer ``blob`` once: check its digest and size (the manifest's), its uncompressed digest
    (``diff_id``, the config's) and every member (module docstring). Raises :class:`ImageError`."""
    where = f"layer {index} ({digest[:19]})"
    links.start_layer()
    metered = _Hashed(blob)
    raw = io.BufferedReader(metered, CHUNK)
    try:
        plain = _Hashed(_decompressor(raw, compression), budget, where)  # type: ignore[arg-type]
        stream = io.BufferedReader(plain, CHUNK)
        with tarfile.open(fileobj=stream, mode="r|", tarinfo=BoundedTarInfo) as tf:
            while (m := _next(tf, stream)) is not None:
                tf.members.clear()  # a stream is read once: keep no list of every member
                budget.count(where)
                _member(m, where, links)
        while stream.read(CHUNK):  # the tar's end padding counts in the diff_id
            budget.clock(where)
        while raw.read(CHUNK):  # and trailing bytes in the digest
            budget.clock(where)
    except ImageError:
        raise
    except PackageError as exc:
        raise ImageError(f"{where}: {exc}") from None
    except (tarfile.TarError, zlib.error, EOFError, OSError, ValueError) as exc:
        raise ImageError(f"{where}: not a readable {compression if compression != 'none' else 'plain'} tar "
                         f"layer ({exc})") from None
    if metered.size != size:
        raise ImageError(f"{where}: {metered.size} bytes, not the manifest's {size}")
    if f"sha256:{metered.sha.hexdigest()}" != digest:
        raise ImageError(f"{where}: its bytes hash to sha256:{metered.sha.hexdigest()}, not the manifest's digest")
    if f"sha256:{plain.sha.hexdigest()}" != diff_id:
        raise ImageError(f"{where}: its uncompressed bytes hash to sha256:{plain.sha.hexdigest()}, not the config's "
                         f"diff_id {diff_id}")
