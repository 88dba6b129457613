"""Helpers for input from strangers: YAML with bounded depth, text that any database can store, finite numbers,
files read within limits, and paths written in a file that stay in that file's folder.

Used by the agent-package checks (:mod:`proxybench.protocol.package`), the server and the evaluator's upload
contract (:mod:`proxybench.contract`), so both sides refuse and clean the same things.

>>> clean_text("stderr\\x00tail\\ud800")
'stderr\\ufffdtail\\ufffd'
>>> load_yaml("a: [1, [2, [3]]]", max_depth=3)
Traceback (most recent call last):
...
proxybench.untrusted.UntrustedInputError: line 1, column 9: nested deeper than 3 levels
>>> find_non_finite({"a": [1.0, {"b": float("inf")}]})
'a.1.b'
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import re
import stat
from collections import Counter
from collections.abc import Hashable, Iterable, Mapping
from pathlib import Path, PurePosixPath
from typing import Any

import yaml

__all__ = ["UntrustedInputError", "clean_text", "clean_tree", "compose_yaml", "find_non_finite", "inside", "load_yaml",
           "load_yaml_file", "nesting_depth", "path_component", "problems", "read_bytes_file", "read_text_file",
           "repeated", "short_repr", "write_file_under"]

# NUL (PostgreSQL text cannot hold it) and lone surrogates (not encodable as UTF-8)
_UNSTORABLE = re.compile("[\x00\ud800-\udfff]")


class UntrustedInputError(ValueError):
    """Input refused; the message says where (line and column, or the field path) and why."""


def clean_text(text: str) -> str:
    """``text`` with NUL bytes and lone surrogates replaced by U+FFFD: storable in SQLite and PostgreSQL alike,
    and still showing where something was."""
    return _UNSTORABLE.sub("\ufffd", text) if _UNSTORABLE.search(text) else text


def clean_tree(value: Any) -> Any:
    """:func:`clean_text` on every string (keys included) of a JSON-like tree; other values unchanged."""
    if isinstance(value, str):
        return clean_text(value)
    if isinstance(value, Mapping):
        return {clean_tree(k) if isinstance(k, str) else k: clean_tree(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [clean_tree(v) for v in value]
    return value


def find_non_finite(value: Any, path: str = "") -> str | None:
    """The dotted path of the first NaN or ±inf in a JSON-like tree, or None (JSON cannot carry them)."""
    if isinstance(value, float):
        return None if math.isfinite(value) else (path or "(root)")
    if isinstance(value, Mapping):
        items = value.items()
    elif isinstance(value, list | tuple):
        items = enumerate(value)
    else:
        return None
    for k, v in items:
        found = find_non_finite(v, f"{path}.{k}" if path else str(k))
        if found is not None:
            return found
    return None


def short_repr(value: Any, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters, safe for any value a stranger sends: an integer of
    thousands of digits (whose ``repr`` raises ``ValueError`` past Python's 4,300-digit limit, and takes
    quadratic time below it) is described by its size instead.

    >>> short_repr(10 ** 20000)
    'an integer of about 20001 digits'
    >>> short_repr("x" * 100, 10)
    "'xxxxxxxx…"
    """
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 128:
        if value.bit_length() < 4000:  # str() is exact and quick up to ~1,200 digits
            size = f"{len(str(abs(value)))} digits"
        else:
            size = f"about {int(value.bit_length() * math.log10(2)) + 1} digits"
        return f"{'a negative' if value < 0 else 'an'} integer of {size}"
    try:
        text = repr(value)
    except Exception as exc:  # a hostile __repr__ or a limit of the interpreter: say what it is
        return f"a {type(value).__name__} ({type(exc).__name__} on repr)"
    return text if len(text) <= limit else text[:limit - 1] + "…"


def repeated(values: Iterable[Hashable]) -> list:
    """The values given more than once, each once and sorted: a message can name every duplicate at once.

    >>> repeated(["b", "a", "b", "c", "a", "b"])
    ['a', 'b']
    """
    return sorted(v for v, n in Counter(values).items() if n > 1)


def nesting_depth(value: Any) -> int:
    """How deeply a JSON-like tree nests (a scalar: 0, ``[1]``: 1), walked without recursion.

    >>> nesting_depth({"a": [1, {"b": []}]})
    3
    """
    deepest, stack = 0, [(value, 0)]
    while stack:
        node, depth = stack.pop()
        deepest = max(deepest, depth)
        if isinstance(node, Mapping):
            stack.extend((v, depth + 1) for v in node.values())
        elif isinstance(node, list | tuple):
            stack.extend((v, depth + 1) for v in node)
    return deepest


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader with a nesting limit (deep nesting otherwise ends in a RecursionError) and,
    optionally, no aliases (an alias bomb expands to billions of nodes in whoever walks the result)."""

    max_depth = 64
    allow_aliases = True

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):  # type: ignore[no-untyped-def]
        if not self.allow_aliases and self.check_event(yaml.AliasEvent):
            mark = self.peek_event().start_mark
            raise UntrustedInputError(f"line {mark.line + 1}, column {mark.column + 1}: aliases (*name) are not "
                                      "allowed here")
        self._depth += 1
        if self._depth > self.max_depth:
            mark = self.peek_event().start_mark
            raise UntrustedInputError(f"line {mark.line + 1}, column {mark.column + 1}: nested deeper than "
                                      f"{self.max_depth} levels")
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def compose_yaml(text: str, *, max_depth: int = 64, allow_aliases: bool = True) -> Any:
    """The YAML node tree of ``text`` (what ``yaml.compose`` gives: marks for every node), with the limits of
    :func:`load_yaml`."""
    loader_cls = type("Loader", (_BoundedLoader,), {"max_depth": max_depth, "allow_aliases": allow_aliases})
    loader = loader_cls(text)
    try:
        return loader.get_single_node()
    except RecursionError:
        raise UntrustedInputError(f"nested too deeply (more than {max_depth} levels)") from None
    finally:
        loader.dispose()


def load_yaml(text: str, *, max_depth: int = 64, allow_aliases: bool = True) -> Any:
    """``yaml.safe_load`` that cannot recurse without bound. Raises :class:`UntrustedInputError` for too deep
    or (``allow_aliases=False``) aliased documents and ``yaml.YAMLError`` for invalid YAML."""
    loader_cls = type("Loader", (_BoundedLoader,), {"max_depth": max_depth, "allow_aliases": allow_aliases})
    loader = loader_cls(text)
    try:
        return loader.get_single_data()
    except RecursionError:  # a construction path we did not bound: still a refusal, never a crash
        raise UntrustedInputError(f"nested too deeply (more than {max_depth} levels)") from None
    finally:
        loader.dispose()


def read_bytes_file(path: str | os.PathLike[str], *, max_bytes: int = 1 << 20, follow_links: bool = True) -> bytes:
    """A file's bytes: a regular file (not a folder, a FIFO, a device or, with ``follow_links=False``, a link),
    at most ``max_bytes``. Opened without blocking (a FIFO answers at once and is refused by ``fstat``, never
    read). Raises :class:`UntrustedInputError` naming the file and what is wrong."""
    flags = os.O_RDONLY | os.O_CLOEXEC | os.O_NONBLOCK | (0 if follow_links else os.O_NOFOLLOW)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        why = "a link (links are not followed here)" if exc.errno == errno.ELOOP else exc.strerror
        raise UntrustedInputError(f"{path}: cannot read ({why})") from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise UntrustedInputError(f"{path}: " + ("is a folder, not a file" if stat.S_ISDIR(st.st_mode) else
                                                 "not a regular file"))
    with open(fd, "rb") as f:
        if st.st_size > max_bytes:
            raise UntrustedInputError(f"{path}: {st.st_size} bytes; at most {max_bytes} are read")
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise UntrustedInputError(f"{path}: more than {max_bytes} bytes")
    return data


def read_text_file(path: str | os.PathLike[str], *, max_bytes: int = 1 << 20, follow_links: bool = True) -> str:
    """A file's text (:func:`read_bytes_file`, then UTF-8). Raises :class:`UntrustedInputError` naming the file
    and what is wrong."""
    data = read_bytes_file(path, max_bytes=max_bytes, follow_links=follow_links)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UntrustedInputError(f"{path}: not UTF-8 text (byte {exc.start})") from None


def load_yaml_file(path: str | os.PathLike[str], *, max_bytes: int = 1 << 20, max_depth: int = 32,
                   allow_aliases: bool = True, follow_links: bool = True) -> Any:
    """:func:`load_yaml` of a file read by :func:`read_text_file`; every refusal is an
    :class:`UntrustedInputError` naming the file (and line and column where YAML says)."""
    import yaml

    text = read_text_file(path, max_bytes=max_bytes, follow_links=follow_links)
    try:
        return load_yaml(text, max_depth=max_depth, allow_aliases=allow_aliases)
    except UntrustedInputError as exc:
        raise UntrustedInputError(f"{path}: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f":{mark.line + 1}:{mark.column + 1}" if mark is not None else ""
        raise UntrustedInputError(f"{path}{at}: not valid YAML ({getattr(exc, 'problem', None) or exc})") from None


def inside(root: str | os.PathLike[str], written: str, *, field: str) -> Path:
    """The path ``written`` in a file of the folder ``root`` (its ``field``), as a path inside ``root``.

    It must be relative (no ``/…``, no ``~``), never leave ``root`` (no ``..``), and pass through no link
    below ``root``: a file from another lab cannot make proxybench read the user's files. Whether the path
    exists is the caller's to check. Raises :class:`UntrustedInputError` naming the field.

    >>> inside("/data/lab", "runs/a.csv", field="trajectories").as_posix().endswith("lab/runs/a.csv")
    True
    >>> inside("/data/lab", "../secret", field="map")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    proxybench.untrusted.UntrustedInputError: map: '../secret' leaves the folder /data/lab (paths in the file ...
    """
    base = Path(os.path.realpath(root))
    if not written or "\x00" in written or "\\" in written:
        raise UntrustedInputError(f"{field}: {written!r} is not a path inside the folder {base}")
    rel = PurePosixPath(written)
    if rel.is_absolute() or written.startswith("~"):
        raise UntrustedInputError(f"{field}: {written!r} is not relative to the folder {base} (absolute paths and ~ "
                                  "are not accepted in the file: put the file inside that folder)")
    if ".." in rel.parts:
        raise UntrustedInputError(f"{field}: {written!r} leaves the folder {base} (paths in the file stay inside it)")
    current = base
    for part in rel.parts:
        current = current / part
        if current.is_symlink():
            raise UntrustedInputError(f"{field}: {written!r}: {current} is a link (links are not followed)")
    return current


def path_component(value: object, *, field: str, max_len: int = 128) -> str:
    """``value`` if it can be one file or folder name (a name from a stranger's file that becomes one): a
    non-empty string of at most ``max_len`` characters, without ``/``, ``\\``, NUL or control characters, not
    ``.`` or ``..``, not starting with ``~`` or ``-``. Raises :class:`UntrustedInputError` naming ``field``.

    >>> path_component("wt01", field="robots.400")
    'wt01'
    >>> path_component("../x", field="agent")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    proxybench.untrusted.UntrustedInputError: agent: '../x' is not a single file name (no '/', ...
    """
    if not isinstance(value, str):
        raise UntrustedInputError(f"{field}: {short_repr(value)} is not a name (a string)")
    bad = (not value or len(value) > max_len or value in (".", "..") or value[0] in "~-" or value != value.strip()
           or any(c in "/\\" or ord(c) < 32 or ord(c) == 127 for c in value))
    if bad:
        raise UntrustedInputError(f"{field}: {short_repr(value)} is not a single file name (no '/', '\\', NUL or "
                                  f"control characters, not '.' or '..')")
    return value


def _open_folder(parent: int, name: str, *, create: bool) -> int:
    """The folder ``name`` of the folder open as ``parent`` (created when missing and ``create``), never a link."""
    flags = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
    try:
        return os.open(name, flags, dir_fd=parent)
    except FileNotFoundError:
        if not create:
            raise
    with contextlib.suppress(FileExistsError):
        os.mkdir(name, 0o777, dir_fd=parent)
    return os.open(name, flags, dir_fd=parent)


def write_file_under(root: str | os.PathLike[str], relative: str, data: bytes | str, *, mode: int = 0o666) -> Path:
    """Write ``data`` to ``root/relative`` atomically (a temporary file, then a rename), staying inside ``root``
    whatever is there: every part of ``relative`` is checked by :func:`path_component`, every folder below
    ``root`` is opened relative to its parent without following links (created when missing), and the file is
    created with ``O_EXCL | O_NOFOLLOW``: a link planted in ``root`` makes this fail, never write elsewhere.
    ``root`` itself is the caller's (made if missing). Returns the path written."""
    parts = PurePosixPath(relative).parts
    if not parts or PurePosixPath(relative).is_absolute():
        raise UntrustedInputError(f"{relative!r}: not a path relative to {root}")
    for part in parts:
        path_component(part, field=str(relative), max_len=255)
    base = Path(root)
    base.mkdir(parents=True, exist_ok=True)
    payload = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    fds = [os.open(base, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)]
    try:
        for part in parts[:-1]:
            try:
                fds.append(_open_folder(fds[-1], part, create=True))
            except OSError as exc:
                why = "a link or not a folder" if exc.errno in (errno.ELOOP, errno.ENOTDIR) else exc.strerror
                raise UntrustedInputError(f"{base.joinpath(*parts)}: cannot write: {part!r} is {why}") from None
        name = parts[-1]
        tmp = f".{name}.{os.getpid()}.{os.urandom(4).hex()}.tmp"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, mode, dir_fd=fds[-1])
        try:
            with open(fd, "wb", closefd=True) as fh:
                fh.write(payload)
            os.replace(tmp, name, src_dir_fd=fds[-1], dst_dir_fd=fds[-1])
        except BaseException as exc:
            with contextlib.suppress(OSError):
                os.unlink(tmp, dir_fd=fds[-1])
            if isinstance(exc, OSError):  # e.g. a folder where the file goes
                raise UntrustedInputError(f"{base.joinpath(*parts)}: cannot write ({exc.strerror})") from None
            raise
    finally:
        for fd in fds:
            os.close(fd)
    return base.joinpath(*parts)


def problems(exc: Any, prefix: str = "") -> str:
    """A pydantic ``ValidationError`` as ``prefix.field: message`` parts joined by "; " (``prefix: message``
    for a check of the whole model, whose message names its fields itself), without pydantic's
    "Value error, " prefix: one way of naming the field at fault wherever input is validated."""
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in (prefix, *err["loc"]) if p != "")
        msg = err["msg"].removeprefix("Value error, ")
        parts.append(f"{loc}: {msg}" if loc else msg)
    return "; ".join(parts)
