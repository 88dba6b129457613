"""Unpacking an agent archive that :func:`~proxybench.protocol.package.check_archive` admitted.

The members are written here, not by ``tarfile.extractall`` / ``ZipFile.extractall``: only the files and
folders the check admitted, each file created anew (``O_EXCL | O_NOFOLLOW``), so it works the same on
every Python the project accepts (``extractall(filter=)`` is missing before 3.11.4, e.g. in Debian 12's
system Python 3.11.2, where every ``.tar*`` package ended ``error``). An error while unpacking is the
archive's fault (:class:`~proxybench.protocol.package.PackageError`); a full disk or quota is the host's
(``OSError``).
"""

from __future__ import annotations

import errno
import lzma
import os
import stat
import tarfile
import zipfile
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

from proxybench.protocol.package import (
    CHUNK,
    AgentManifest,
    BoundedTarInfo,
    PackageError,
    check_archive,
    member_path,
    open_source,
)

__all__ = ["extract_archive"]

def extract_archive(data: bytes | str | os.PathLike[str] | IO[bytes], dest: Path, **limits: Any) -> AgentManifest:
    """Check, then unpack into ``dest`` (created; must be empty). Returns the manifest; raises
    :class:`PackageError` naming the member at fault (``OSError`` for a full disk)."""
    manifest = check_archive(data, **limits)
    dest.mkdir(parents=True, exist_ok=True)
    if any(dest.iterdir()):
        raise PackageError(f"{dest}: unpack folder is not empty")
    root = dest.resolve()
    f, _, opened = open_source(data)
    name = ""
    try:
        for name, is_dir, executable, reader in _members_of(f):
            _place(root, member_path(name), is_dir, executable, reader)
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.ENOMEM):
            raise
        raise PackageError(f"member {name[:200]!r}: cannot be unpacked ({exc.strerror or exc})") from None
    except (zipfile.BadZipFile, tarfile.TarError, zlib.error, lzma.LZMAError, EOFError) as exc:
        raise PackageError(f"member {name[:200]!r}: damaged ({exc})") from None
    finally:
        if opened:
            f.close()
    return manifest


def _members_of(f: IO[bytes]) -> Iterator[tuple[str, bool, bool, Callable[[], Any]]]:
    """(name, is folder, executable, open its data) of every member of a checked zip or tar, in order."""
    f.seek(0)
    if zipfile.is_zipfile(f):
        f.seek(0)
        with zipfile.ZipFile(f) as zf:
            for info in zf.infolist():
                yield info.filename, info.is_dir(), bool((info.external_attr >> 16) & 0o111), \
                    (lambda info=info: zf.open(info))
        return
    f.seek(0)
    with tarfile.open(fileobj=f, mode="r:*", tarinfo=BoundedTarInfo) as tf:
        for m in tf:
            yield m.name, m.isdir(), bool(m.mode & 0o111), (lambda m=m: tf.extractfile(m))


def _place(root: Path, norm: str, is_dir: bool, executable: bool, reader: Callable[[], Any]) -> None:
    """Write one member under ``root``: its folders, then (for a file) a new file with its bytes."""
    parts = [] if norm == "." else norm.split("/")
    folder = root
    for part in parts[:-1] if not is_dir else parts:
        folder = folder / part
        try:
            os.mkdir(folder, 0o755)
        except FileExistsError:
            if not stat.S_ISDIR(os.lstat(folder).st_mode):
                raise NotADirectoryError(errno.ENOTDIR, f"{folder.relative_to(root)} is not a folder") from None
    if is_dir:
        return
    fd = os.open(root / norm, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC,
                 0o755 if executable else 0o644)
    with open(fd, "wb") as out, reader() as src:
        while chunk := src.read(CHUNK):
            out.write(chunk)
