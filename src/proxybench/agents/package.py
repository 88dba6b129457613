"""Agent packages: an archive (zip or tar[.gz]) holding an agent node and a manifest saying how to start it.

The manifest, ``proxybench-agent.yaml`` at the archive root::

    name: my-agent
    protocol: aido-z2            # the AIDO lane-following agent protocol (docs/protocol.md)
    command: [python3, agent.py] # started in the unpacked folder; speaks the protocol on stdin/stdout
    # or, as typed in a shell:  command: cd solution && exec python3 solution.py
    description: optional text
    cwd: solution                # optional: working directory inside the package
    transport: pipe              # optional: pipe | fifo (AIDO's default)
    start_timeout: 60            # optional [s]: start + handshake, and each setup message (at most 600)
    step_timeout: 2              # optional [s]: each observations + get_commands exchange (at most 30)
    reflection: false            # optional: skip describe_protocol (e.g. zuper-nodes on Python >= 3.11)

Archives come from strangers, so :func:`check_archive` refuses anything that could write outside the
folder it is unpacked in (absolute paths, ``..``, links, devices) or blow up on unpacking (too many
members, too many bytes), naming the member at fault. The server runs it on upload, the evaluator again
before it runs the agent.
"""

from __future__ import annotations

import io
import posixpath
import stat
import tarfile
import zipfile
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

__all__ = ["MANIFEST_NAME", "AgentManifest", "PackageError", "check_archive", "extract_archive"]

MANIFEST_NAME = "proxybench-agent.yaml"
PROTOCOLS = ("aido-z2",)
SHELL = "/bin/sh"
#: the shell snippet that runs "$@" in the folder "$1" (what ``cwd`` adds in front of the command)
_CD = 'cd -- "$1" && shift && exec "$@"'


class PackageError(ValueError):
    """An agent archive that is refused; the message names the member or field at fault."""


class AgentManifest(BaseModel):
    """A package's manifest. ``command`` is always an argv list here: a string in the file (shell syntax, as
    typed in a shell) becomes ``["/bin/sh", "-c", string]``, and ``cwd`` (a folder inside the package) a
    ``cd`` in front, so whatever runs the argv from the package folder honours both. The start-up options
    (``transport``, timeouts, ``reflection``) are those of :class:`~proxybench.protocol.options.NodeOptions`,
    with caps so that a package cannot hold an evaluator for long."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = Field(min_length=1, max_length=64)
    protocol: str = Field(description=f"one of {', '.join(PROTOCOLS)}")
    command: list[str] = Field(min_length=1, description="argv, or a string as typed in a shell; run in the "
                                                         "unpacked folder (or cwd)")
    description: str = ""
    cwd: str | None = Field(None, min_length=1, description="working directory, a folder inside the package")
    transport: Literal["pipe", "fifo"] = Field("pipe", description="pipe (stdin/stdout) or fifo (AIDO's default)")
    start_timeout: float = Field(30.0, gt=0.0, le=600.0, allow_inf_nan=False, description="[s], at most 600")
    step_timeout: float = Field(5.0, gt=0.0, le=30.0, allow_inf_nan=False, description="[s], at most 30")
    reflection: bool = Field(True, description="ask describe_protocol (a node failing it is restarted without)")

    @field_validator("command", mode="before")
    @classmethod
    def _shell_string(cls, cmd: Any) -> Any:
        if isinstance(cmd, str):
            if not cmd.strip():
                raise ValueError("empty command")
            return [SHELL, "-c", cmd]
        return cmd

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
    def _in_cwd(self) -> AgentManifest:
        if self.cwd is not None and self.cwd != "." and self.command[:3] != [SHELL, "-c", _CD]:
            object.__setattr__(self, "command", [SHELL, "-c", _CD, "cd", self.cwd, *self.command])
        return self

    def node_options(self, **overrides: Any):
        """The :class:`~proxybench.protocol.options.NodeOptions` to start the package's node with."""
        from proxybench.protocol.options import NodeOptions

        return NodeOptions(transport=self.transport, start_timeout=self.start_timeout,
                           step_timeout=self.step_timeout, reflection=self.reflection, **overrides)


def _check_name(name: str) -> str:
    norm = posixpath.normpath(name.replace("\\", "/"))
    if name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":") or norm == ".." or norm.startswith("../"):
        raise PackageError(f"member {name!r}: path leaves the package folder")
    return norm


def _members(data: bytes) -> list[tuple[str, int, bool]]:
    """(name, size, is_dir) of every member, refusing links and special files."""
    if zipfile.is_zipfile(io.BytesIO(data)):
        out = []
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            for info in zf.infolist():
                mode = info.external_attr >> 16
                if stat.S_ISLNK(mode):
                    raise PackageError(f"member {info.filename!r}: symbolic links are not allowed")
                out.append((info.filename, info.file_size, info.is_dir()))
        return out
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:*") as tf:
            out = []
            for m in tf.getmembers():
                if m.issym() or m.islnk():
                    raise PackageError(f"member {m.name!r}: links are not allowed")
                if not (m.isfile() or m.isdir()):
                    raise PackageError(f"member {m.name!r}: only files and folders are allowed")
                out.append((m.name, m.size, m.isdir()))
            return out
    except tarfile.TarError as exc:
        raise PackageError(f"not a zip or tar archive ({exc})") from None


def _read_member(data: bytes, name: str) -> bytes:
    if zipfile.is_zipfile(io.BytesIO(data)):
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            return zf.read(name)
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:*") as tf:
        f = tf.extractfile(name)
        assert f is not None
        return f.read()


def check_archive(data: bytes, *, max_members: int = 10_000, max_unpacked: int = 512 << 20) -> AgentManifest:
    """Validate an agent archive (bytes) and return its manifest; :class:`PackageError` says what is wrong."""
    members = _members(data)
    if len(members) > max_members:
        raise PackageError(f"{len(members)} members; at most {max_members} are allowed")
    total = 0
    manifest_member = None
    for name, size, is_dir in members:
        norm = _check_name(name)
        total += size
        if not is_dir and norm == MANIFEST_NAME:
            manifest_member = name
    if total > max_unpacked:
        raise PackageError(f"unpacks to {total} bytes; at most {max_unpacked} are allowed")
    if manifest_member is None:
        raise PackageError(f"no {MANIFEST_NAME} at the archive root")
    try:
        raw = yaml.safe_load(_read_member(data, manifest_member))
    except yaml.YAMLError as exc:
        raise PackageError(f"{MANIFEST_NAME}: not valid YAML ({getattr(exc, 'problem', exc)})") from None
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


def extract_archive(data: bytes, dest: Path, **limits: int) -> AgentManifest:
    """Check, then unpack into ``dest`` (created; must be empty). Returns the manifest."""
    manifest = check_archive(data, **limits)
    dest.mkdir(parents=True, exist_ok=True)
    if any(dest.iterdir()):
        raise PackageError(f"{dest}: unpack folder is not empty")
    root = dest.resolve()
    if zipfile.is_zipfile(io.BytesIO(data)):
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            for info in zf.infolist():
                target = (root / _check_name(info.filename)).resolve()
                if not target.is_relative_to(root):
                    raise PackageError(f"member {info.filename!r}: path leaves the package folder")
                if info.is_dir():
                    target.mkdir(parents=True, exist_ok=True)
                    continue
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(zf.read(info))
                if (info.external_attr >> 16) & 0o111:
                    target.chmod(0o755)
    else:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r:*") as tf:
            tf.extractall(root, filter="data")  # the stdlib's own refusal of links out, devices, absolute paths
    return manifest
