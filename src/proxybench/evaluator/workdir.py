"""The evaluator's state folder: only its user can write it, and nothing in it is reached through a link.

Job folders hold the hidden test seed (``job.json``), the developer's archive and the hidden test
trajectories, so another local account must not be able to plant a link where the evaluator writes
(a ``.lock`` pointing at a root-owned file truncated it) or swap a job folder for one of its own (it
then read every job's files while the jobs still ended ``success``). Hence:

- the folder is the evaluator user's own, mode 700, created so (:func:`open_state_dir`), and every
  folder above it is owned by root or that user and writable by no one else (its own group aside) unless
  sticky (``/tmp``):
  an existing one owned by another user or with a looser mode is refused with the fix in the message;
- it is held open as a directory descriptor; files in it are opened relative to it with ``O_NOFOLLOW``;
- job folders are created exclusively (``mkdir`` fails if anything has that name) and used through
  their own descriptor (:class:`JobDir`), removed with ``rmtree(dir_fd=…)``, which follows no link.

The default place (:func:`default_work_dir`) is ``/var/lib/proxybench-evaluator/<name>`` for root, else
``$XDG_STATE_HOME`` (``~/.local/state``) ``/proxybench-evaluator/<name>``: never under a world-writable
folder such as ``/tmp``, where another user could create the folder first.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import shutil
import stat
from collections.abc import Iterable
from pathlib import Path

__all__ = ["JobDir", "StateDir", "WorkDirError", "default_work_dir", "open_state_dir"]

_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
FOLDER_NAME = "proxybench-evaluator"


class WorkDirError(RuntimeError):
    """The work folder is not safe to use (or cannot be made); the message says why and what to do."""


def default_work_dir(name: str) -> Path:
    """Where evaluator ``name`` keeps its jobs unless told otherwise (see the module's docstring)."""
    if not name or name in (".", "..") or "/" in name or "\x00" in name:
        raise WorkDirError(f"evaluator name {name!r} cannot name a folder: give --work-dir")
    if os.geteuid() == 0:
        return Path("/var/lib") / FOLDER_NAME / name
    state = os.environ.get("XDG_STATE_HOME") or ""
    base = Path(state) if os.path.isabs(state) else Path.home() / ".local" / "state"
    return base / FOLDER_NAME / name


def _owner_name(uid: int) -> str:
    import pwd

    try:
        return f"{pwd.getpwuid(uid).pw_name!r} (uid {uid})"
    except KeyError:
        return f"uid {uid}"


def _check_ancestor(path: str, st: os.stat_result) -> None:
    """A folder above the work folder: root's or ours, and no one else may rename what is in it."""
    me = os.geteuid()
    if st.st_uid not in (0, me):
        raise WorkDirError(f"{path} (above the work folder) belongs to {_owner_name(st.st_uid)}, who could "
                           "replace the work folder: choose a --work-dir under folders of root or of this user")
    others = st.st_mode & 0o002 or (st.st_mode & 0o020 and st.st_gid != os.getegid())  # not: our own group
    if others and not st.st_mode & stat.S_ISVTX:
        raise WorkDirError(f"{path} (above the work folder) is writable by other users (mode "
                           f"{stat.S_IMODE(st.st_mode):04o}), who could replace the work folder: choose another "
                           "--work-dir")


def _check_own(path: str, st: os.stat_result) -> None:
    """The work folder itself: this user's, mode 700 (nothing looser)."""
    if st.st_uid != os.geteuid():
        raise WorkDirError(f"work folder {path} belongs to {_owner_name(st.st_uid)}, not to this evaluator's user "
                           f"{_owner_name(os.geteuid())}: someone else made it; remove it or choose another "
                           "--work-dir")
    if stat.S_IMODE(st.st_mode) & 0o077:
        raise WorkDirError(f"work folder {path} has mode {stat.S_IMODE(st.st_mode):04o}; it must be 0700 (job "
                           f"files hold the hidden test seed): chmod 700 {path}, or choose another --work-dir")


def _trusted_links(path: str, depth: int = 0) -> None:
    """Every link on the way to ``path`` was made by root or this user (another user's link, e.g. one planted
    in /tmp, could point the evaluator at a folder of that user's choosing)."""
    current = "/"
    for part in [p for p in path.split("/") if p]:
        current = os.path.join(current, part)
        st = os.lstat(current)
        if stat.S_ISLNK(st.st_mode):
            if st.st_uid not in (0, os.geteuid()) or depth > 40:
                raise WorkDirError(f"{current} (on the way to the work folder) is a link made by "
                                   f"{_owner_name(st.st_uid)}: choose another --work-dir")
            _trusted_links(os.path.realpath(current), depth + 1)


def open_state_dir(path: str | os.PathLike[str]) -> int:
    """A descriptor of the work folder ``path``, created (mode 700) where missing, checked all the way down.

    Links in the part of the path that exists are resolved first (``/var/lib`` may be one); from then on
    every step is opened with ``O_NOFOLLOW`` relative to the one above, so nothing can be swapped in
    between. Raises :class:`WorkDirError`.
    """
    wanted = os.path.abspath(os.fspath(path))
    existing = wanted
    while not os.path.lexists(existing):
        existing = os.path.dirname(existing)
    _trusted_links(existing)
    real = os.path.join(os.path.realpath(existing), os.path.relpath(wanted, existing))
    parts = [p for p in real.split("/") if p]
    fd = os.open("/", _DIR_FLAGS)
    where = "/"
    try:
        for k, part in enumerate(parts):
            last = k == len(parts) - 1
            _check_ancestor(where, os.fstat(fd))
            with contextlib.suppress(FileExistsError):
                os.mkdir(part, 0o700, dir_fd=fd)
            try:
                nxt = os.open(part, _DIR_FLAGS, dir_fd=fd)
            except OSError as exc:
                what = "a link" if exc.errno == errno.ELOOP else "not a folder" if exc.errno == errno.ENOTDIR else \
                    exc.strerror
                raise WorkDirError(f"cannot use {os.path.join(where, part)} as (part of) the work folder: {what}") \
                    from None
            os.close(fd)
            fd, where = nxt, os.path.join(where, part)
            if last:
                _check_own(where, os.fstat(fd))
        if not parts:
            raise WorkDirError("the work folder cannot be /")
    except BaseException:
        os.close(fd)
        raise
    return fd


def _open_in(dir_fd: int, name: str, flags: int, mode: int = 0o600) -> int:
    return os.open(name, flags | os.O_NOFOLLOW | os.O_CLOEXEC, mode, dir_fd=dir_fd)


def _write(dir_fd: int, name: str, data: bytes | Iterable[bytes]) -> None:
    """A new file ``name`` in ``dir_fd`` (an existing one, or a link, is an error), holding ``data`` (bytes, or
    chunks written as they come: a container image is not held in memory)."""
    fd = _open_in(dir_fd, name, os.O_WRONLY | os.O_CREAT | os.O_EXCL)
    with open(fd, "wb") as f:
        for chunk in [data] if isinstance(data, bytes | bytearray) else data:
            f.write(chunk)


def _read_plain(dir_fd: int, name: str, limit: int | None = None) -> bytes:
    """A regular file's bytes (at most ``limit``), refusing links and anything that is not a plain file."""
    fd = _open_in(dir_fd, name, os.O_RDONLY | os.O_NONBLOCK)
    with open(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            raise OSError(errno.EINVAL, f"{name} is not a regular file")
        return f.read() if limit is None else f.read(limit)


class _Folder:
    """Reads of plain files of a folder held open as ``fd`` (no link is followed)."""

    fd: int

    def read(self, name: str, limit: int | None = None) -> bytes:
        return _read_plain(self.fd, name, limit)

    def exists(self, name: str) -> bool:
        try:
            return stat.S_ISREG(os.stat(name, dir_fd=self.fd, follow_symlinks=False).st_mode)
        except OSError:
            return False

    def tail(self, name: str, lines: int = 15, limit: int = 1 << 20) -> list[str]:
        """The last ``lines`` lines (of the last ``limit`` bytes) of a plain file ([] if there is none)."""
        try:
            fd = _open_in(self.fd, name, os.O_RDONLY | os.O_NONBLOCK)
        except OSError:
            return []
        with open(fd, "rb") as f:
            st = os.fstat(f.fileno())
            if not stat.S_ISREG(st.st_mode):
                return []
            f.seek(max(0, st.st_size - limit))
            data = f.read(limit)
        return data.decode("utf-8", "replace").splitlines()[-lines:]


class JobDir(_Folder):
    """One job's folder, made exclusively in the state folder and used through its descriptor."""

    def __init__(self, parent: StateDir, name: str, fd: int) -> None:
        self.parent, self.name, self.fd = parent, name, fd
        self.path = parent.path / name  # for the worker (a process of the same user) and messages

    def write(self, name: str, data: bytes | Iterable[bytes]) -> None:
        _write(self.fd, name, data)

    def close(self, remove: bool) -> None:
        with contextlib.suppress(OSError):
            os.close(self.fd)
        if remove:
            self.parent.remove(self.name)


class StateDir(_Folder):
    """The evaluator's work folder, open and locked for its lifetime (one evaluator per folder)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(os.path.abspath(os.fspath(path)))
        self.fd = open_state_dir(self.path)
        try:
            self._lock = _open_in(self.fd, ".lock", os.O_RDWR | os.O_CREAT)
        except OSError as exc:
            os.close(self.fd)
            raise WorkDirError(f"cannot open {self.path / '.lock'}: "
                               f"{'a link' if exc.errno == errno.ELOOP else exc.strerror}") from None
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self.close()
            raise WorkDirError(f"work folder {self.path} is in use by another evaluator; give each evaluator its own "
                               "--name or --work-dir") from None

    def fresh_file(self, name: str) -> int:
        """A new, empty file ``name`` for writing (whatever had that name, a link included, is removed first)."""
        with contextlib.suppress(FileNotFoundError):
            os.unlink(name, dir_fd=self.fd)
        return _open_in(self.fd, name, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND)

    def new_job(self, name: str) -> JobDir:
        """A new job folder (mode 700). Something already there under that name (a stale folder, a planted
        link) is removed first, without following it; the folder is then made exclusively."""
        if os.path.lexists(self.path / name):
            self.remove(name)
        os.mkdir(name, 0o700, dir_fd=self.fd)  # FileExistsError if anything got there meanwhile: never reused
        fd = os.open(name, _DIR_FLAGS, dir_fd=self.fd)
        return JobDir(self, name, fd)

    def remove(self, name: str) -> None:
        """Remove an entry of the folder (a folder with its contents; a link itself, never its target)."""
        try:
            st = os.stat(name, dir_fd=self.fd, follow_symlinks=False)
        except FileNotFoundError:
            return
        if stat.S_ISDIR(st.st_mode):
            shutil.rmtree(name, dir_fd=self.fd, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(name, dir_fd=self.fd)

    def entries(self, prefix: str) -> list[str]:
        return sorted(n for n in os.listdir(self.fd) if n.startswith(prefix))

    def close(self) -> None:
        for fd in (getattr(self, "_lock", None), self.fd):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._lock = None
        self.fd = -1
