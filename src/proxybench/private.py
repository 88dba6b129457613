"""This user's private folder for per-run files (locks), safe from the other users of the machine.

The temporary folder is shared: another local user may create a file, a folder or a link there under the name we
are about to use, so that our run waits on their lock forever, or root creates or truncates the file the link
points to (issue 38 item 3). Every per-run file of proxybench therefore lives in ``<tmp>/proxybench-<uid>/``, made
mode 0700 and checked each time it is used (a real folder, not a link, owned by us, no access for anyone else), and
is opened with ``O_NOFOLLOW`` and checked to be a regular file of ours. A lock is waited for with a deadline; the
holder writes its process id and command into the lock file, so that the error at the deadline names it.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import stat
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["LockTimeout", "PrivateFileError", "check_private_folder", "hold_lock", "lock_holder",
           "make_private_folder", "open_private",
           "user_folder"]

#: how much of a lock file is read to name its holder (anything longer is someone's garbage)
_HOLDER_BYTES = 512


class PrivateFileError(OSError):
    """A per-run folder or file that is not safely ours (one line: which path and why)."""


class LockTimeout(TimeoutError):
    """A lock still held by another process at the deadline (the message names the holder and the file)."""


def _why_not_private(info: os.stat_result, *, folder: bool) -> str | None:
    """Why a path with ``info`` (from lstat/fstat) is not ours to use, or None when it is."""
    if stat.S_ISLNK(info.st_mode):
        return "is a symbolic link"
    if folder and not stat.S_ISDIR(info.st_mode):
        return "is not a folder"
    if not folder and not stat.S_ISREG(info.st_mode):
        return "is not a regular file"
    if info.st_uid != os.getuid():
        return f"belongs to user id {info.st_uid}, not to us ({os.getuid()})"
    if folder and info.st_mode & 0o022:
        return f"has mode {stat.S_IMODE(info.st_mode):o}: others may write there (we make it 700)"
    return None


def check_private_folder(path: Path) -> Path:
    """``path`` if it is a real folder of ours where nobody else may write; else :class:`PrivateFileError`."""
    try:
        info = os.lstat(path)
    except OSError as exc:
        raise PrivateFileError(f"{path}: {exc.strerror}") from None
    why = _why_not_private(info, folder=True)
    if why is not None:
        raise PrivateFileError(f"{path} {why}: refused (remove it, or set TMPDIR to another folder)")
    return path


def make_private_folder(path: Path) -> Path:
    """Make ``path`` (mode 700) unless it exists, then check it: what someone planted there is never trusted."""
    try:
        os.mkdir(path, 0o700)
    except FileExistsError:
        pass
    except OSError as exc:
        raise PrivateFileError(f"{path}: cannot make it: {exc.strerror}") from None
    return check_private_folder(path)


def user_folder(name: str | None = None, *, base: Path | None = None) -> Path:
    """``<tmp>/proxybench-<uid>`` (or its subfolder ``name``), made and checked private (see the module)."""
    root = make_private_folder(Path(base or tempfile.gettempdir()) / f"proxybench-{os.getuid()}")
    return root if name is None else make_private_folder(root / name)


def open_private(path: Path, *, mode: int = 0o600) -> int:
    """A read-write descriptor of the regular file ``path`` of ours (made if missing), never through a link and
    never blocking on a FIFO; :class:`PrivateFileError` for anything else that sits there."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK, mode)
    except OSError as exc:
        raise PrivateFileError(f"{path}: {exc.strerror}: refused") from None
    why = _why_not_private(os.fstat(fd), folder=False)
    if why is not None:
        os.close(fd)
        raise PrivateFileError(f"{path} {why}: refused")
    return fd


def lock_holder(fd: int) -> str:
    """Who wrote the lock file (``pid N: command``), as one short printable line; ``unknown`` for garbage."""
    with contextlib.suppress(OSError):
        text = os.pread(fd, _HOLDER_BYTES, 0).decode("utf-8", "replace")
        line = "".join(c for c in text.splitlines()[0] if c.isprintable())[:200] if text.strip() else ""
        if line:
            return line
    return "unknown"


def _write_holder(fd: int) -> None:
    """Name this process in the lock file it holds (for the error another waiter gets at its deadline)."""
    first, rest = (sys.argv[0], sys.argv[1:]) if sys.argv else ("", [])
    program = os.path.basename(first)
    if first in ("", "-c", "-m"):  # python -c / -m: name the interpreter
        program = f"{os.path.basename(sys.executable)} {first}"
    note = " ".join([f"pid {os.getpid()}: {program}", *rest]).replace("\n", " ")
    with contextlib.suppress(OSError):
        os.ftruncate(fd, 0)
        os.pwrite(fd, (note[:200] + "\n").encode("utf-8", "replace"), 0)


def hold_lock(path: Path, *, timeout: float, poll_s: float = 0.05, what: str = "the lock") -> int:
    """An exclusive ``flock`` on the private file ``path``, waited for up to ``timeout`` s; its descriptor (closing
    it releases the lock; so does the holder's death). :class:`LockTimeout` at the deadline names the holder."""
    fd = open_private(path)
    deadline = time.monotonic() + max(0.0, timeout)
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if time.monotonic() >= deadline:
                holder = lock_holder(fd)
                os.close(fd)
                raise LockTimeout(f"{what} is still held after {timeout:g} s by {holder} (lock file {path})") from None
            time.sleep(poll_s)
            continue
        _write_holder(fd)
        return fd
