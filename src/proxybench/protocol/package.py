"""Agent packages: an archive (zip or tar[.gz]) holding an agent node and a manifest saying how to start it.

The manifest, ``proxybench-agent.yaml`` at the archive root::

    name: my-agent
    protocol: aido-z2            # the AIDO lane-following agent protocol (docs/protocol.md), or
                                 # duckietown-sdk: a program using duckietown-sdk's DB21J (docs/dtps.md)
    command: [python3, agent.py] # started in the unpacked folder; speaks the protocol on stdin/stdout
    # or, as typed in a shell:  command: cd solution && exec python3 solution.py
    description: optional text
    cwd: solution                # optional: working directory inside the package
    transport: pipe              # optional: pipe | fifo (AIDO's default)
    start_timeout: 60            # optional [s]: start + handshake, and each setup message (at most 600)
    step_timeout: 2              # optional [s]: each observations + get_commands exchange (at most 30)
    reflection: false            # optional: skip describe_protocol (e.g. zuper-nodes on Python >= 3.11)
    timing: lockstep             # optional, duckietown-sdk only: realtime (default) | lockstep

Archives come from strangers, so :func:`check_archive` refuses anything that could write outside the
folder it is unpacked in (absolute paths, ``..``, links, devices) or fail to unpack (a member that is both
a file and a folder, ``a`` then ``a/b``; a file named ``.``; a name component over 255 bytes), naming the
member at fault. The cheap checks come first and are bounded before anything is decompressed: a zip's
member count and central-directory size are read from its end record; a tar is read as a stream, one
header at a time, with extension headers (pax, GNU long names) size-limited, so an archive of millions
of empty headers is refused after ``max_members`` of them. Then the manifest (at most ``max_manifest``
bytes, YAML without aliases, bounded nesting), then every member's data is read once, bounded by
``max_unpacked`` bytes and ``max_seconds``, so a bad CRC, a truncated stream or an encrypted member is a
:class:`PackageError` here, not a crash later. The server runs it on upload, the evaluator again before
it runs the agent, which unpacks it with :func:`proxybench.protocol.unpack.extract_archive`.
"""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
import os
import posixpath
import stat
import struct
import tarfile
import time
import zipfile
import zlib
from typing import IO, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from proxybench.untrusted import UntrustedInputError, load_yaml

__all__ = ["MANIFEST_NAME", "AgentManifest", "ArchiveLimits", "PackageError", "check_archive"]

MANIFEST_NAME = "proxybench-agent.yaml"
PROTOCOLS = ("aido-z2", "duckietown-sdk")
SDK_PROTOCOL = "duckietown-sdk"
SHELL = "/bin/sh"
#: the shell snippet that runs "$@" in the folder "$1" (what ``cwd`` adds in front of the command)
_CD = 'cd -- "$1" && shift && exec "$@"'
_ZIP_METHODS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate", zipfile.ZIP_BZIP2: "bzip2",
                zipfile.ZIP_LZMA: "lzma"}
CHUNK = 1 << 20
_MAX_NAME = 1024  # characters in a member's path
_MAX_COMPONENT = 255  # bytes of one name in a path (the file systems' limit)
_MAX_EXTENSION_HEADER = 1 << 20  # bytes of one pax / GNU long-name header
_MAX_EXTENSION_CHAIN = 8  # extension headers in a row before a member


class PackageError(ValueError):
    """An agent archive that is refused; the message names the member or field at fault."""


class ArchiveLimits(BaseModel):
    """What an agent archive may hold. Sizes in bytes, time in seconds."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    max_members: int = Field(10_000, ge=1)
    max_unpacked: int = Field(512 << 20, ge=1, description="sum of the members' sizes")
    max_manifest: int = Field(64 << 10, ge=1)
    max_seconds: float = Field(60.0, gt=0, description="reading every member once may take this long")


class AgentManifest(BaseModel):
    """A package's manifest. ``command`` is always an argv list here: a string in the file (shell syntax, as
    typed in a shell) becomes ``["/bin/sh", "-c", string]``, and ``cwd`` (a folder inside the package) a
    ``cd`` in front, so whatever runs the argv from the package folder honours both. The start-up options
    (``transport``, timeouts, ``reflection``) are those of :class:`~proxybench.protocol.options.NodeOptions`,
    with caps so that a package cannot hold an evaluator for long."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = Field(min_length=1, max_length=64)
    protocol: str = Field(description=f"one of {', '.join(PROTOCOLS)}")
    command: list[str] = Field(min_length=1, max_length=256, description="argv, or a string as typed in a shell; "
                                                                         "run in the unpacked folder (or cwd)")
    description: str = Field("", max_length=10_000)
    cwd: str | None = Field(None, min_length=1, max_length=1024,
                            description="working directory, a folder inside the package")
    transport: Literal["pipe", "fifo"] = Field("pipe", description="pipe (stdin/stdout) or fifo (AIDO's default)")
    start_timeout: float = Field(30.0, gt=0.0, le=600.0, allow_inf_nan=False, description="[s], at most 600")
    step_timeout: float = Field(5.0, gt=0.0, le=30.0, allow_inf_nan=False, description="[s], at most 30")
    reflection: bool = Field(True, description="ask describe_protocol (a node failing it is restarted without)")
    timing: Literal["realtime", "lockstep"] | None = Field(None, description="duckietown-sdk: realtime | lockstep")

    @field_validator("command", mode="before")
    @classmethod
    def _shell_string(cls, cmd: Any) -> Any:
        if isinstance(cmd, str):
            if not cmd.strip():
                raise ValueError("empty command")
            return [SHELL, "-c", cmd]
        return cmd

    @field_validator("name", "command", "description", "cwd")
    @classmethod
    def _no_nul(cls, v: Any) -> Any:
        for s in [v] if isinstance(v, str) else (v or []):
            if isinstance(s, str) and "\x00" in s:
                raise ValueError("contains a NUL character")
        return v

    @field_validator("cwd")
    @classmethod
    def _inside(cls, cwd: str | None) -> str | None:
        if cwd is None:
            return None
        norm = posixpath.normpath(cwd.replace("\\", "/"))
        if cwd.startswith(("/", "\\")) or norm == ".." or norm.startswith("../"):
            raise ValueError(f"{cwd!r} leaves the package folder (give a folder inside it)")
        return norm

    @model_validator(mode="after")
    def _options_of_its_protocol(self) -> AgentManifest:
        if self.protocol == SDK_PROTOCOL and self.transport != "pipe":
            raise ValueError("transport: a duckietown-sdk program talks DTPS over the network, not AIDO's pipes or "
                             "FIFOs; leave transport out")
        if self.protocol != SDK_PROTOCOL and self.timing is not None:
            raise ValueError(f"timing: only for protocol {SDK_PROTOCOL} (this is {self.protocol})")
        return self

    @model_validator(mode="after")
    def _in_cwd(self) -> AgentManifest:
        if self.cwd is not None and self.cwd != "." and self.command[:3] != [SHELL, "-c", _CD]:
            object.__setattr__(self, "command", [SHELL, "-c", _CD, "cd", self.cwd, *self.command])
        return self

    def node_options(self, **overrides: Any):
        """The :class:`~proxybench.protocol.options.NodeOptions` to start the package's node with."""
        from proxybench.protocol.options import NodeOptions

        return NodeOptions(transport=self.transport, start_timeout=self.start_timeout,
                           step_timeout=self.step_timeout, reflection=self.reflection, **overrides)


# -- the checks ----------------------------------------------------------------------------------------


class _Budget:
    """Bytes read and time spent so far; raises PackageError when either runs out."""

    def __init__(self, limits: ArchiveLimits) -> None:
        self.limits = limits
        self.deadline = time.monotonic() + limits.max_seconds
        self.read = 0

    def spend(self, n: int, where: str) -> None:
        self.read += n
        if self.read > self.limits.max_unpacked:
            raise PackageError(f"{where}: unpacks to more than {self.limits.max_unpacked} bytes")
        if time.monotonic() > self.deadline:
            raise PackageError(f"{where}: checking the archive took longer than {self.limits.max_seconds:g} s")


def member_path(name: str) -> str:
    if len(name) > _MAX_NAME:
        raise PackageError(f"member {name[:80]!r}…: path longer than {_MAX_NAME} characters")
    if "\x00" in name:
        raise PackageError(f"member {name!r}: path contains a NUL character")
    norm = posixpath.normpath(name.replace("\\", "/"))
    if name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":") or norm == ".." or norm.startswith("../"):
        raise PackageError(f"member {name!r}: path leaves the package folder")
    if any(len(part.encode("utf-8", "surrogateescape")) > _MAX_COMPONENT for part in norm.split("/")):
        raise PackageError(f"member {name[:80]!r}: a name in its path is longer than {_MAX_COMPONENT} bytes")
    return norm


def _parse_manifest(raw_bytes: bytes, limits: ArchiveLimits) -> AgentManifest:
    if len(raw_bytes) > limits.max_manifest:
        raise PackageError(f"{MANIFEST_NAME}: larger than {limits.max_manifest} bytes")
    try:
        raw = load_yaml(raw_bytes.decode("utf-8"), max_depth=16, allow_aliases=False)
    except UnicodeDecodeError as exc:
        raise PackageError(f"{MANIFEST_NAME}: not UTF-8 text (byte {exc.start})") from None
    except UntrustedInputError as exc:
        raise PackageError(f"{MANIFEST_NAME}: {exc}") from None
    except yaml.YAMLError as exc:
        raise PackageError(f"{MANIFEST_NAME}: not valid YAML ({getattr(exc, 'problem', None) or exc})") from None
    if not isinstance(raw, dict):
        raise PackageError(f"{MANIFEST_NAME}: expected a mapping with name, protocol, command")
    try:
        manifest = AgentManifest.model_validate(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        field = ".".join(str(p) for p in first["loc"]) or "(root)"
        raise PackageError(f"{MANIFEST_NAME}: field {field!r}: {first['msg']}") from None
    if manifest.protocol not in PROTOCOLS:
        raise PackageError(f"{MANIFEST_NAME}: field 'protocol': {manifest.protocol!r} is not one of "
                           f"{', '.join(PROTOCOLS)}")
    return manifest


class _Members:
    """Names seen so far: duplicates are refused (which of two manifests would count?), and so is a path that is
    a file in one member and a folder in another (``a``, then ``a/b``): it could not be unpacked."""

    def __init__(self, limits: ArchiveLimits) -> None:
        self.limits = limits
        self.names: set[str] = set()
        self.files: set[str] = set()
        self.folders: set[str] = set()
        self.declared = 0

    def add(self, name: str, size: int, is_dir: bool) -> str:
        norm = member_path(name)
        if len(self.names) >= self.limits.max_members:
            raise PackageError(f"more than {self.limits.max_members} members")
        if not is_dir and norm in self.names:
            raise PackageError(f"member {name!r} appears twice")
        if not is_dir and norm == ".":
            raise PackageError(f"member {name!r}: a file must have a name")
        parents = [p for p in _parents(norm)]
        clash = next((p for p in parents if p in self.files), None) or \
            (norm if (norm in self.files if is_dir else norm in self.folders) else None)
        if clash is not None:
            raise PackageError(f"member {name!r}: {clash!r} is both a file and a folder in this archive")
        self.folders.update(parents)
        (self.folders if is_dir else self.files).add(norm)
        self.names.add(norm)
        self.declared += max(0, size)
        if self.declared > self.limits.max_unpacked:
            raise PackageError(f"member {name!r}: the members add up to more than {self.limits.max_unpacked} bytes")
        return norm


def _parents(norm: str) -> list[str]:
    """``a/b/c`` → ``a``, ``a/b``."""
    parts = norm.split("/")[:-1]
    return ["/".join(parts[: k + 1]) for k in range(len(parts))]


# -- zip -----------------------------------------------------------------------------------------------

_EOCD = struct.Struct("<4s4H2LH")
_ZIP64_LOCATOR = struct.Struct("<4sLQL")
_ZIP64_EOCD = struct.Struct("<4sQ2H2L4Q")


def _zip_directory(f: IO[bytes], size: int) -> tuple[int, int]:
    """(members, central-directory bytes) from the end record(s), before zipfile parses anything."""
    tail_len = min(size, _EOCD.size + 0xFFFF)
    f.seek(size - tail_len)
    tail = f.read(tail_len)
    at = tail.rfind(b"PK\x05\x06")
    if at < 0 or at + _EOCD.size > len(tail):
        raise PackageError("not a zip archive (no end-of-central-directory record)")
    _, _, _, _, entries, cd_size, _, _ = _EOCD.unpack_from(tail, at)
    if entries == 0xFFFF or cd_size == 0xFFFFFFFF:  # zip64: the counts are in the zip64 end record
        loc = at - _ZIP64_LOCATOR.size
        if loc < 0 or tail[loc:loc + 4] != b"PK\x06\x07":
            raise PackageError("damaged zip64 archive (no zip64 end-record locator)")
        offset = _ZIP64_LOCATOR.unpack_from(tail, loc)[2]
        if offset + _ZIP64_EOCD.size > size:
            raise PackageError("damaged zip64 archive (end record out of range)")
        f.seek(offset)
        rec = f.read(_ZIP64_EOCD.size)
        if rec[:4] != b"PK\x06\x06":
            raise PackageError("damaged zip64 archive (bad zip64 end record)")
        fields = _ZIP64_EOCD.unpack(rec)
        entries, cd_size = fields[7], fields[8]
    return entries, cd_size


def _check_zip(f: IO[bytes], size: int, limits: ArchiveLimits) -> AgentManifest:
    entries, cd_size = _zip_directory(f, size)
    if entries > limits.max_members:
        raise PackageError(f"{entries} members; at most {limits.max_members} are allowed")
    if cd_size > limits.max_members * (46 + _MAX_NAME + 256) or cd_size > size:
        raise PackageError(f"central directory of {cd_size} bytes: too large for {entries} members")
    budget = _Budget(limits)
    members = _Members(limits)
    manifest: AgentManifest | None = None
    f.seek(0)
    with zipfile.ZipFile(f) as zf:
        infos = zf.infolist()
        for info in infos:
            members.add(info.filename, info.file_size, info.is_dir())
            if stat.S_ISLNK(info.external_attr >> 16):
                raise PackageError(f"member {info.filename!r}: symbolic links are not allowed")
            if info.flag_bits & 0x1:
                raise PackageError(f"member {info.filename!r}: encrypted members are not allowed")
            if info.compress_type not in _ZIP_METHODS:
                raise PackageError(f"member {info.filename!r}: compression method {info.compress_type} is not "
                                   f"supported ({', '.join(_ZIP_METHODS.values())})")
        entry = next((i for i in infos if not i.is_dir() and member_path(i.filename) == MANIFEST_NAME), None)
        if entry is None:
            raise PackageError(f"no {MANIFEST_NAME} at the archive root")
        if entry.file_size > limits.max_manifest:
            raise PackageError(f"{MANIFEST_NAME}: {entry.file_size} bytes; at most {limits.max_manifest} are allowed")
        for info in [entry, *(i for i in infos if i is not entry)]:  # the manifest first: its errors are clearest
            if info.is_dir():
                continue
            data = _read_zip_member(zf, info, budget)
            if info is entry:
                manifest = _parse_manifest(data, limits)
    assert manifest is not None
    return manifest


def _read_zip_member(zf: zipfile.ZipFile, info: zipfile.ZipInfo, budget: _Budget) -> bytes:
    """Read a member through (the CRC is checked at its end); keeps the bytes only of a manifest-sized one."""
    keep = info.file_size <= budget.limits.max_manifest
    out = bytearray()
    got = 0
    try:
        with zf.open(info) as m:
            while chunk := m.read(CHUNK):
                got += len(chunk)
                budget.spend(len(chunk), f"member {info.filename!r}")
                if got > info.file_size:
                    raise PackageError(f"member {info.filename!r}: more data than its declared {info.file_size} bytes")
                if keep:
                    out += chunk
    except PackageError:
        raise
    except (zipfile.BadZipFile, zlib.error, lzma.LZMAError, EOFError, OSError, RuntimeError, ValueError,
            NotImplementedError, struct.error) as exc:
        raise PackageError(f"member {info.filename!r}: damaged ({exc})") from None
    if got != info.file_size:
        raise PackageError(f"member {info.filename!r}: {got} bytes, not the declared {info.file_size}")
    return bytes(out)


# -- tar -----------------------------------------------------------------------------------------------


class _BoundedStream(io.RawIOBase):
    """The decompressed tar stream, metered: every byte counts against the budget (and the clock)."""

    def __init__(self, inner: IO[bytes], budget: _Budget) -> None:
        self.inner, self.budget = inner, budget

    def readable(self) -> bool:
        return True

    def readinto(self, buf) -> int:  # type: ignore[no-untyped-def]
        data = self.inner.read(len(buf))
        n = len(data)
        buf[:n] = data
        self.budget.spend(n, "tar stream")
        return n


class BoundedTarInfo(tarfile.TarInfo):
    """Refuses oversized or endless chains of extension headers *before* tarfile reads them into memory."""

    def _proc_member(self, tf):  # type: ignore[no-untyped-def]
        if self.type in (tarfile.GNUTYPE_LONGNAME, tarfile.GNUTYPE_LONGLINK, tarfile.XHDTYPE, tarfile.XGLTYPE,
                         tarfile.SOLARIS_XHDTYPE):
            if self.size > _MAX_EXTENSION_HEADER:
                raise PackageError(f"an extension header of {self.size} bytes (at most {_MAX_EXTENSION_HEADER})")
            tf._pb_chain = getattr(tf, "_pb_chain", 0) + 1
            if tf._pb_chain > _MAX_EXTENSION_CHAIN:
                raise PackageError(f"more than {_MAX_EXTENSION_CHAIN} extension headers in a row")
        elif self.type == tarfile.GNUTYPE_SPARSE:
            raise PackageError(f"member {self.name!r}: sparse files are not allowed")
        else:
            tf._pb_chain = 0
        return super()._proc_member(tf)


def _decompressed(f: IO[bytes]) -> IO[bytes]:
    head = f.read(6)
    f.seek(0)
    if head[:2] == b"\x1f\x8b":
        return gzip.GzipFile(fileobj=f, mode="rb")  # type: ignore[return-value]
    if head[:3] == b"BZh":
        return bz2.BZ2File(f, mode="rb")  # type: ignore[return-value]
    if head == b"\xfd7zXZ\x00":
        return lzma.LZMAFile(f, mode="rb")  # type: ignore[return-value]
    return f


def _check_tar(f: IO[bytes], limits: ArchiveLimits) -> AgentManifest:
    budget = _Budget(ArchiveLimits(max_members=limits.max_members, max_manifest=limits.max_manifest,
                                   max_seconds=limits.max_seconds,
                                   # headers count too: two 512-byte blocks per member at most, plus padding
                                   max_unpacked=limits.max_unpacked + limits.max_members * 1024 + (1 << 20)))
    members = _Members(limits)
    manifest: AgentManifest | None = None
    stream = io.BufferedReader(_BoundedStream(_decompressed(f), budget), CHUNK)
    try:
        with tarfile.open(fileobj=stream, mode="r|", tarinfo=BoundedTarInfo) as tf:
            while (m := tf.next()) is not None:
                norm = members.add(m.name, m.size, m.isdir())
                tf.members.clear()  # a stream is read once: keep no list of every member seen
                if m.issym() or m.islnk():
                    raise PackageError(f"member {m.name!r}: links are not allowed")
                if not (m.isfile() or m.isdir()):
                    raise PackageError(f"member {m.name!r}: only files and folders are allowed")
                if m.isfile() and norm == MANIFEST_NAME:
                    if m.size > limits.max_manifest:
                        raise PackageError(f"{MANIFEST_NAME}: {m.size} bytes; at most {limits.max_manifest} "
                                           "are allowed")
                    member = tf.extractfile(m)
                    assert member is not None
                    manifest = _parse_manifest(member.read(), limits)
    except PackageError:
        raise
    except (tarfile.TarError, zlib.error, lzma.LZMAError, EOFError, OSError, ValueError, struct.error) as exc:
        raise PackageError(f"not a readable zip or tar archive ({exc})") from None
    if not members.names:
        raise PackageError("not a zip or tar archive, or an empty one")
    if manifest is None:
        raise PackageError(f"no {MANIFEST_NAME} at the archive root")
    return manifest


# -- entry points --------------------------------------------------------------------------------------


def open_source(data: bytes | str | os.PathLike[str] | IO[bytes]) -> tuple[IO[bytes], int, bool]:
    """(seekable binary file, size, whether we opened it)."""
    if isinstance(data, bytes | bytearray | memoryview):
        return io.BytesIO(data), len(data), True
    if isinstance(data, str | os.PathLike):
        f = open(data, "rb")  # noqa: SIM115 - closed by the caller
        return f, os.fstat(f.fileno()).st_size, True
    data.seek(0, os.SEEK_END)
    size = data.tell()
    data.seek(0)
    return data, size, False


def check_archive(data: bytes | str | os.PathLike[str] | IO[bytes], *, limits: ArchiveLimits | None = None,
                  **overrides: Any) -> AgentManifest:
    """Validate an agent archive (bytes, a path or a seekable binary file) and return its manifest.

    Raises :class:`PackageError` saying what is wrong. ``overrides`` replace single limits
    (``max_members=…``, ``max_unpacked=…``, ``max_manifest=…``, ``max_seconds=…``).
    """
    limits = limits or ArchiveLimits()
    if overrides:
        limits = limits.model_copy(update=overrides)
    f, size, opened = open_source(data)
    try:
        if size == 0:
            raise PackageError("the archive is empty")
        head = f.read(4)
        f.seek(0)
        if head in (b"PK\x03\x04", b"PK\x05\x06") or zipfile.is_zipfile(f):
            f.seek(0)
            return _check_zip(f, size, limits)
        f.seek(0)
        return _check_tar(f, limits)
    except PackageError:
        raise
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, struct.error) as exc:
        raise PackageError(f"not a readable zip or tar archive ({exc})") from None
    finally:
        if opened:
            f.close()
