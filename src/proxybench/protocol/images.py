"""Container images as agent submissions, checked before anything of them is unpacked: an OCI image layout
folder, an OCI archive or a ``docker save`` / ``podman save`` tarball.

This is the package check of images (beside :mod:`~proxybench.protocol.package`), shared by the challenges
server, which checks an uploaded image before storing it, and the evaluator, which checks it again before
unpacking it (:mod:`proxybench.evaluator.images`):

1. the form is told by the content, not the name; compressed archives are refused (their full size would be
   written before any check); the size is bounded;
2. ``skopeo copy`` (containers/image, the library behind podman and buildah) brings any of the three forms into a
   private OCI layout in a staging folder, checking each blob's digest as it copies;
3. proxybench reads that layout (:func:`verify_layout`): the index, manifest and config as bounded JSON, each
   blob's size and SHA-256 against its descriptor, the layer count, the media types, then every layer once as a
   stream (:mod:`~proxybench.protocol.image_layers`: paths, links, whiteouts, members, bytes, time);
4. the image's labels ``org.proxybench.agent.*`` (or a side file) say how it speaks (:func:`image_manifest`).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import shutil
import signal
import stat
import subprocess
import tarfile
import tempfile
import time
from pathlib import Path
from typing import IO, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from proxybench.protocol.image_layers import LAYER_TYPES, ImageError, LayerBudget, SymlinkTracker, scan_layer, sniff
from proxybench.protocol.package import SDK_PROTOCOL, AgentManifest
from proxybench.untrusted import UntrustedInputError, load_yaml

__all__ = ["IMAGE_PROTOCOLS", "KEYS", "LABEL_PREFIX", "MANIFEST_TYPES", "REF", "SIDE_SUFFIX", "CheckedImage",
           "ImageConfig", "ImageError", "ImageLimits", "StagedImage", "blob_path", "check_image", "digest_of_file",
           "image_config", "image_manifest", "image_tools", "is_image_archive", "json_blob", "json_object", "run_tool",
           "stage_image", "tool_env"]

MANIFEST_TYPES = ("application/vnd.oci.image.manifest.v1+json",
                  "application/vnd.docker.distribution.manifest.v2+json")
_MAX_JSON = 1 << 20
#: the reference name of the one image in a staged layout
REF = "img"
LABEL_PREFIX = "org.proxybench.agent."
SIDE_SUFFIX = ".proxybench-agent.yaml"
#: what an image's agent may speak: an AIDO node, or a duckietown-sdk program that drives a virtual DB21J
IMAGE_PROTOCOLS = ("aido-z2", SDK_PROTOCOL)
KEYS = ("name", "protocol", "transport", "start_timeout", "step_timeout", "reflection", "description", "timing")


class ImageLimits(BaseModel):
    """What an image may hold. Sizes in bytes, time in seconds (the whole check or unpack, tools included)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    max_archive_bytes: int = Field(8 << 30, ge=1, description="the archive, or the layout folder's blobs")
    max_layers: int = Field(128, ge=1)
    max_members: int = Field(500_000, ge=1, description="members of all layers together")
    max_bytes: int = Field(16 << 30, ge=1, description="uncompressed bytes of all layers together")
    max_seconds: float = Field(600.0, gt=0)


class ImageConfig(BaseModel):
    """How the image says it starts (its config's ``config`` object, as Docker and OCI write it)."""

    model_config = ConfigDict(frozen=True, extra="ignore", populate_by_name=True)

    entrypoint: list[str] | None = Field(None, alias="Entrypoint")
    cmd: list[str] | None = Field(None, alias="Cmd")
    env: list[str] | None = Field(None, alias="Env")
    working_dir: str = Field("", alias="WorkingDir")
    user: str = Field("", alias="User")
    labels: dict[str, str] | None = Field(None, alias="Labels")

    @property
    def argv(self) -> list[str]:
        return [*(self.entrypoint or []), *(self.cmd or [])]


def image_tools(tools: tuple[str, ...] = ("skopeo", "umoci")) -> str | None:
    """None if ``tools`` are installed (checking needs skopeo, unpacking umoci too), else what to install."""
    missing = [t for t in tools if shutil.which(t) is None]
    return None if not missing else f"{' and '.join(missing)} not installed: apt-get install {' '.join(missing)}"


# -- the source ---------------------------------------------------------------------------------------


def _source(path: Path, limits: ImageLimits) -> tuple[str, int]:
    """(skopeo transport reference, bytes) of an image path, its form told by its content, not its name."""
    try:
        st = path.stat()
    except OSError as exc:
        raise ImageError(f"image {path}: {exc.strerror}") from None
    if stat.S_ISDIR(st.st_mode):
        return f"oci:{path}", _layout_size(path, limits)
    if not stat.S_ISREG(st.st_mode):
        raise ImageError(f"image {path}: not a file or folder")
    if st.st_size > limits.max_archive_bytes:
        raise ImageError(f"image {path}: {st.st_size} bytes; at most {limits.max_archive_bytes} are allowed")
    with open(path, "rb") as f:
        head = f.read(6)
    if head[:2] == b"\x1f\x8b" or head[:4] == b"\x28\xb5\x2f\xfd" or head[:3] == b"BZh" or head == b"\xfd7zXZ\x00":
        raise ImageError(f"image {path}: a compressed archive; give the tar itself (e.g. gunzip it first): "
                         "unpacking it would write its full size before any check")
    names = _archive_names(path, limits)
    if "oci-layout" in names and "index.json" in names:
        return f"oci-archive:{path}", st.st_size
    if "manifest.json" in names:
        return f"docker-archive:{path}", st.st_size
    raise ImageError(f"image {path}: a tar without oci-layout/index.json (OCI) or manifest.json (docker save)")


def _layout_size(path: Path, limits: ImageLimits) -> int:
    """Bytes of a layout folder's blobs; its index, marker and blobs must be plain files (no links, FIFOs or
    devices for skopeo to follow), and not too many of them."""
    for name in ("oci-layout", "index.json"):
        if not (path / name).is_file() or (path / name).is_symlink():
            raise ImageError(f"image {path}: a folder, but not an OCI image layout (no plain file {name})")
    blobs = path / "blobs" / "sha256"
    if not blobs.is_dir() or blobs.is_symlink() or (path / "blobs").is_symlink():
        raise ImageError(f"image {path}: an OCI layout without a blobs/sha256 folder")
    size = 0
    for n, entry in enumerate(os.scandir(blobs)):
        if n > limits.max_layers * 8 + 64:
            raise ImageError(f"image {path}: more than {limits.max_layers * 8 + 64} blobs")
        if not entry.is_file(follow_symlinks=False):
            raise ImageError(f"image {path}: blob {entry.name[:19]} is not a plain file")
        size += entry.stat(follow_symlinks=False).st_size
    return size


def _archive_names(path: Path, limits: ImageLimits) -> set[str]:
    """The top-level names of an image archive, read header by header with a bounded member count."""
    names: set[str] = set()
    try:
        with tarfile.open(path, mode="r|") as tf:
            for n, m in enumerate(tf, 1):
                tf.members.clear()
                if n > limits.max_layers * 8 + 64:
                    raise ImageError(f"image {path}: more than {limits.max_layers * 8 + 64} members in the archive")
                names.add(m.name.removeprefix("./").split("/")[0])
    except tarfile.TarError as exc:
        raise ImageError(f"image {path}: not a tar archive ({exc})") from None
    return names


def digest_of_file(path: Path) -> str:
    sha = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            sha.update(chunk)
    return sha.hexdigest()


# -- the tools ----------------------------------------------------------------------------------------


def run_tool(argv: list[str], deadline: float, what: str, env: dict[str, str]) -> None:
    """Run a tool in a process group of its own, killed whole at the deadline; its failure is the image's."""
    left = deadline - time.monotonic()
    if left <= 0:
        raise ImageError(f"{what}: the image's time limit ran out")
    proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True, env=env)
    try:
        out, _ = proc.communicate(timeout=left)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise ImageError(f"{what}: took longer than the image's time limit") from None
    if proc.returncode != 0:
        lines = out.decode(errors="replace").strip().splitlines()[-2:]
        lines = [m.group(1) if (m := re.search(r'msg="(.*)"', line)) else line for line in lines]  # skopeo's log
        tail = " / ".join(line.strip(" ⨯•") for line in lines)[:600]
        raise ImageError(f"{what} failed: {tail or f'exit status {proc.returncode}'}")


def blob_path(layout: Path, descriptor: Any, what: str) -> Path:
    """The blob file of a descriptor, its size checked (the digest is checked where it is read)."""
    if not isinstance(descriptor, dict):
        raise ImageError(f"{what}: not a descriptor")
    digest, size = descriptor.get("digest"), descriptor.get("size")
    if not (isinstance(digest, str) and digest.startswith("sha256:") and len(digest) == 71
            and all(c in "0123456789abcdef" for c in digest[7:])):
        raise ImageError(f"{what}: digest {str(digest)[:80]!r} is not sha256:<64 hex digits>")
    if not isinstance(size, int) or isinstance(size, bool) or size < 0:
        raise ImageError(f"{what}: size {size!r} is not a byte count")
    path = layout / "blobs" / "sha256" / digest[7:]
    st = path.lstat() if path.exists() or path.is_symlink() else None
    if st is None or not stat.S_ISREG(st.st_mode):
        raise ImageError(f"{what}: blob {digest[:19]} is missing")
    if st.st_size != size:
        raise ImageError(f"{what}: blob {digest[:19]} is {st.st_size} bytes, not the descriptor's {size}")
    return path


def json_blob(layout: Path, descriptor: Any, what: str) -> dict[str, Any]:
    path = blob_path(layout, descriptor, what)
    if path.stat().st_size > _MAX_JSON:
        raise ImageError(f"{what}: larger than {_MAX_JSON} bytes")
    data = path.read_bytes()
    if f"sha256:{hashlib.sha256(data).hexdigest()}" != descriptor["digest"]:
        raise ImageError(f"{what}: its bytes do not hash to the digest {descriptor['digest'][:19]}")
    return json_object(data, what)


def json_object(data: bytes, what: str) -> dict[str, Any]:
    try:
        value = json.loads(data)
    except (ValueError, RecursionError) as exc:
        raise ImageError(f"{what}: not JSON ({str(exc)[:120]})") from None
    if not isinstance(value, dict):
        raise ImageError(f"{what}: not a JSON object")
    return value


def verify_layout(layout: Path, limits: ImageLimits, deadline: float) -> tuple[str, dict[str, Any], list[str]]:
    """(manifest digest, config, compression of each layer) of the staged layout, every byte checked."""
    index_file = layout / "index.json"
    if index_file.stat().st_size > _MAX_JSON:
        raise ImageError("index.json: larger than 1 MiB")
    manifests = json_object(index_file.read_bytes(), "index.json").get("manifests")
    if not isinstance(manifests, list) or len(manifests) != 1:
        raise ImageError("index.json: expected exactly one image manifest")
    descriptor = manifests[0]
    manifest = json_blob(layout, descriptor, "manifest")
    if manifest.get("mediaType", descriptor.get("mediaType")) not in MANIFEST_TYPES:
        raise ImageError(f"manifest: media type {str(manifest.get('mediaType'))[:80]!r} is not an image manifest")
    config = json_blob(layout, manifest.get("config"), "config")
    layers = manifest.get("layers")
    if not isinstance(layers, list) or not layers:
        raise ImageError("manifest: no layers")
    if len(layers) > limits.max_layers:
        raise ImageError(f"manifest: {len(layers)} layers; at most {limits.max_layers} are allowed")
    diff_ids = (config.get("rootfs") or {}).get("diff_ids") if isinstance(config.get("rootfs"), dict) else None
    if not isinstance(diff_ids, list) or len(diff_ids) != len(layers):
        raise ImageError(f"config: rootfs.diff_ids does not list one digest per layer ({len(layers)})")
    budget = LayerBudget(limits.max_members, limits.max_bytes, deadline)
    links = SymlinkTracker()
    compressions = []
    for i, layer in enumerate(layers):
        path = blob_path(layout, layer, f"layer {i}")
        compression = LAYER_TYPES.get(layer.get("mediaType"))
        if compression is None:
            raise ImageError(f"layer {i} ({layer['digest'][:19]}): media type {str(layer.get('mediaType'))[:80]!r} "
                             f"is not one of {', '.join(LAYER_TYPES)}")
        with open(path, "rb") as f:
            if (found := sniff(f.read(4))) != compression:
                raise ImageError(f"layer {i} ({layer['digest'][:19]}): its media type says {compression}, its "
                                 f"bytes are {found}")
            f.seek(0)
            scan_layer(f, index=i, digest=layer["digest"], size=layer["size"], diff_id=str(diff_ids[i]),
                       compression=compression, budget=budget, links=links)
        compressions.append(compression)
    return descriptor["digest"], config, compressions


def image_config(config: dict[str, Any]) -> ImageConfig:
    try:
        return ImageConfig.model_validate(config.get("config") or {})
    except ValidationError as exc:
        first = exc.errors()[0]
        raise ImageError(f"config: field {'.'.join(str(p) for p in first['loc'])!r}: {first['msg']}") from None



# -- staging and checking -----------------------------------------------------------------------------


class StagedImage(BaseModel):
    """An image copied into a private OCI layout and checked byte by byte (:func:`stage_image`)."""

    model_config = ConfigDict(frozen=True)

    layout: Path
    digest: str = Field(description="the manifest's digest, sha256:…")
    config: dict[str, Any] = Field(description="the image's config blob, as JSON")
    compressions: list[str] = Field(description="each layer's compression: none, gzip or zstd")


class CheckedImage(BaseModel):
    """What an image check found: its manifest digest, its config and the agent manifest it speaks by."""

    model_config = ConfigDict(frozen=True)

    digest: str
    config: ImageConfig
    manifest: AgentManifest


def tool_env(staging: Path) -> dict[str, str]:
    """The tools' environment: nothing of the caller's but ``PATH``; home and temporary files in ``staging``."""
    return {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(staging), "TMPDIR": str(staging)}


def stage_image(path: Path, staging: Path, limits: ImageLimits, deadline: float) -> StagedImage:
    """Copy the image at ``path`` into ``staging/layout`` with skopeo and check every byte of it there.
    Nothing is written outside ``staging``; raises :class:`ImageError` naming what is wrong."""
    source, size = _source(path, limits)
    if size > limits.max_archive_bytes:
        raise ImageError(f"image {path}: {size} bytes of blobs; at most {limits.max_archive_bytes} are allowed")
    layout = staging / "layout"
    # an OCI image keeps its layers as they are; a docker archive's plain layers are gzipped (fast, level 1):
    # skopeo 1.9 would label them gzip while leaving them plain
    keep = ["--dest-oci-accept-uncompressed-layers"] if not source.startswith("docker-archive:") else \
        ["--dest-compress", "--dest-compress-format", "gzip", "--dest-compress-level", "1"]
    run_tool(["skopeo", "--insecure-policy", "copy", "--quiet", *keep, source, f"oci:{layout}:{REF}"], deadline,
             f"image {path}: skopeo copy", tool_env(staging))
    try:
        digest, config, compressions = verify_layout(layout, limits, deadline)
    except ImageError as exc:
        raise ImageError(f"image {path}: {exc}") from None
    return StagedImage(layout=layout, digest=digest, config=config, compressions=compressions)


def check_image(path: str | os.PathLike[str], name: str, *, limits: ImageLimits | None = None,
                scratch: str | os.PathLike[str] | None = None) -> CheckedImage:
    """Check the image at ``path`` as an agent called ``name`` without unpacking it (the server's upload check):
    staged in a private folder under ``scratch`` (default: the system's temporary folder), removed afterwards.
    Raises :class:`ImageError` naming what is wrong (with the image, or that this host has no skopeo)."""
    limits = limits or ImageLimits()
    path = Path(path)
    if problem := image_tools(("skopeo",)):
        raise ImageError(f"image {path}: cannot check images here: {problem}")
    with tempfile.TemporaryDirectory(prefix="proxybench-image-", dir=scratch) as staging:
        staged = stage_image(path, Path(staging), limits, time.monotonic() + limits.max_seconds)
    config = image_config(staged.config)
    return CheckedImage(digest=staged.digest, config=config, manifest=image_manifest(name, path, config))


def is_image_archive(f: IO[bytes], *, max_members: int = 1088) -> bool:
    """Whether a seekable file holds a container image archive (a plain tar with ``oci-layout`` and
    ``index.json``, or a ``docker save`` tarball's ``manifest.json``) rather than an agent package (which has a
    ``proxybench-agent.yaml``). Reads tar headers only, at most ``max_members``; leaves ``f`` at its start."""
    names: set[str] = set()
    f.seek(0)
    try:
        with tarfile.open(fileobj=f, mode="r|") as tf:
            for n, m in enumerate(tf, 1):
                tf.members.clear()
                names.add(m.name.removeprefix("./").split("/")[0])
                if n >= max_members:
                    break
    except (tarfile.TarError, OSError, EOFError, ValueError):
        return False
    finally:
        f.seek(0)
    if "proxybench-agent.yaml" in names:
        return False
    return ("oci-layout" in names and "index.json" in names) or "manifest.json" in names


# -- how it speaks ------------------------------------------------------------------------------------


def _side_file(path: Path) -> dict[str, Any]:
    side = path.with_name(path.name + SIDE_SUFFIX)
    if not side.is_file():
        return {}
    try:
        raw = load_yaml(side.read_bytes()[: 64 << 10].decode("utf-8"), max_depth=4, allow_aliases=False)
    except (UnicodeDecodeError, UntrustedInputError, ValueError) as exc:
        raise ImageError(f"{side}: {exc}") from None
    if not isinstance(raw, dict):
        raise ImageError(f"{side}: expected a mapping of {', '.join(KEYS)}")
    return {f"{side.name}: {k}": v for k, v in raw.items()}


def image_manifest(name: str, path: Path, config: ImageConfig) -> AgentManifest:
    """The agent manifest of an image: its labels, then its side file, over the defaults; the command is the
    image's ENTRYPOINT + CMD. Raises :class:`ImageError` naming the label or key at fault."""
    given: dict[str, tuple[str, Any]] = {}  # key → (where it was given, value)
    for label, value in (config.labels or {}).items():
        if label.startswith(LABEL_PREFIX):
            given[label.removeprefix(LABEL_PREFIX)] = (f"label {label}", value)
    for where, value in _side_file(path).items():
        given[where.rsplit(": ", 1)[1]] = (where, value)
    for key, (where, _) in given.items():
        if key not in KEYS:
            raise ImageError(f"image {path}: {where}: unknown key {key!r} (one of {', '.join(KEYS)}; the command "
                             "is the image's ENTRYPOINT and CMD)")
    if not config.argv:
        raise ImageError(f"image {path}: its config has neither Entrypoint nor Cmd: nothing to start")
    values = {k: v for k, (_, v) in given.items()}
    try:
        manifest = AgentManifest.model_validate({"protocol": "aido-z2", **values, "name": name, "command": config.argv})
    except ValidationError as exc:
        first = exc.errors()[0]
        msg = str(first["msg"]).removeprefix("Value error, ")
        # a check of the whole manifest (timing without duckietown-sdk) names its key first in its message
        key = str(first["loc"][0]) if first["loc"] else next((k for k in given if msg.startswith(f"{k}:")), "?")
        raise ImageError(f"image {path}: {given.get(key, (key,))[0]}: {msg.removeprefix(f'{key}: ')}") from None
    if manifest.protocol not in IMAGE_PROTOCOLS:
        raise ImageError(f"image {path}: protocol {manifest.protocol!r} is not one of {', '.join(IMAGE_PROTOCOLS)}")
    return manifest
