"""Content-addressed file store: ``artifacts/ab/abcdef…`` by SHA-256, written atomically, size-limited.

Storing by hash makes uploads idempotent (the same bytes twice are one file) and lets a client check
what it downloads.
"""

from __future__ import annotations

import errno
import hashlib
import os
import re
import tempfile
import time
from collections.abc import Iterable
from pathlib import Path

from sqlalchemy.orm import Session

from proxybench.server.models import Artifact

__all__ = ["ArtifactStore", "TooLarge", "is_sha256"]

_SHA256 = re.compile(r"^[0-9a-f]{64}$")


class TooLarge(ValueError):
    """More bytes than the limit; nothing was stored."""


def is_sha256(text: str) -> bool:
    return bool(_SHA256.match(text))


class ArtifactStore:
    """Files under ``root``, named by hash; the ``artifacts`` table records size and media type."""

    def __init__(self, root: Path) -> None:
        self.root = root
        root.mkdir(parents=True, exist_ok=True)

    def path(self, sha256: str) -> Path:
        if not is_sha256(sha256):
            raise ValueError(f"not a SHA-256 hex digest: {sha256!r}")
        return self.root / sha256[:2] / sha256

    def has(self, sha256: str) -> bool:
        return self.path(sha256).is_file()

    def write(self, chunks: Iterable[bytes], max_bytes: int, expected: str | None = None) -> tuple[str, int]:
        """Stream ``chunks`` to the store; returns (sha256, size). Raises TooLarge or ValueError (hash mismatch)."""
        digest = hashlib.sha256()
        size = 0
        fd, tmp = tempfile.mkstemp(dir=self.root, prefix=".upload-")
        try:
            with os.fdopen(fd, "wb") as f:
                for chunk in chunks:
                    size += len(chunk)
                    if size > max_bytes:
                        raise TooLarge(f"upload exceeds {max_bytes} bytes")
                    digest.update(chunk)
                    f.write(chunk)
                f.flush()
                os.fsync(f.fileno())
            sha = digest.hexdigest()
            if expected is not None and sha != expected:
                raise ValueError(f"content hash is {sha}, not the {expected} named in the request")
            dest = self.path(sha)
            dest.parent.mkdir(exist_ok=True)
            os.replace(tmp, dest)
            return sha, size
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)

    def adopt(self, path: Path, expected: str, size: int) -> int:
        """Move a file already hashed (a spooled request body) into the store under ``expected``; returns
        its size. The file is flushed to disk first, so a crash cannot leave a torn artifact."""
        if not is_sha256(expected):
            raise ValueError(f"not a SHA-256 hex digest: {expected!r}")
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        dest = self.path(expected)
        dest.parent.mkdir(exist_ok=True)
        try:
            os.replace(path, dest)
        except OSError as exc:
            if exc.errno != errno.EXDEV:
                raise
            with open(path, "rb") as f:  # another file system: copy (and hash again)
                return self.write(iter(lambda: f.read(1 << 20), b""), size, expected)[1]
        return size

    def record(self, session: Session, sha256: str, size: int, media_type: str, user_id: int | None) -> Artifact:
        """The table row for a stored file (created once; later uploads of the same bytes reuse it)."""
        row = session.get(Artifact, sha256)
        if row is None:
            row = Artifact(sha256=sha256, size=size, media_type=media_type, created_at=time.time(),
                           uploaded_by=user_id)
            session.add(row)
            session.flush()
        return row
