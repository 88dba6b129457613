"""Container images as agents: an OCI image layout folder, an OCI archive or a ``docker save`` / ``podman save``
tarball, unpacked once into a root file system cached by its manifest's digest.

The field's tools do the work they are made for, and proxybench checks what they are handed first:

1. ``skopeo copy`` (containers/image, the library behind podman and buildah) brings any of the three forms into a
   private OCI layout in a staging folder inside the cache, keeping the layers' compression (a docker archive's
   plain layers stay plain, ``--dest-oci-accept-uncompressed-layers``), so it writes no more than the image's
   own size, which is bounded before it starts;
2. proxybench reads that layout (:func:`_verify_layout`): the index, manifest and config as bounded JSON, each
   blob's size and SHA-256 against its descriptor, the layer count, the media types, then every layer once as a
   stream (:mod:`~proxybench.evaluator.image_layers`: paths, links, whiteouts, members, bytes, time), all before
   a file of the root file system exists;
3. zstd layers, which umoci 0.4 cannot read, are recompressed to gzip by ``skopeo`` (their bytes already bounded);
4. ``umoci raw unpack --rootless`` applies the layers in order with whiteouts, resolving every path inside the
   root (``filepath-securejoin``), as a second line of defence behind step 2;
5. the tree is made read-only for everyone but its owner (no set-id bits, no group/other write), the mount points
   the sandbox needs (``/proc``, ``/dev``, ``/tmp``, ``/scratch``, ``/fifo``) are made empty folders, and the
   staging folder is renamed to ``rootfs/<digest>`` with the image's config beside it (``<digest>.json``).

A failure at any step removes the staging folder: nothing is written outside the cache and nothing already
cached is touched. Episodes share the cached tree; the sandbox shows it read-only as ``/``.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import re
import secrets
import shutil
import signal
import stat
import subprocess
import tarfile
import time
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from proxybench.evaluator.image_layers import LAYER_TYPES, ImageError, LayerBudget, SymlinkTracker, scan_layer, sniff

__all__ = ["ImageConfig", "ImageError", "ImageLimits", "UnpackedImage", "default_cache", "image_tools",
           "unpack_image"]

MANIFEST_TYPES = ("application/vnd.oci.image.manifest.v1+json",
                  "application/vnd.docker.distribution.manifest.v2+json")
#: folders the sandbox mounts over; each must be an empty folder of the root file system
MOUNT_POINTS = ("proc", "dev", "tmp", "scratch", "fifo")
_MAX_JSON = 1 << 20
_REF = "img"


class ImageLimits(BaseModel):
    """What an image may hold. Sizes in bytes, time in seconds (the whole unpack, tools included)."""

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


class UnpackedImage(BaseModel):
    """An image in the cache: its manifest digest, root file system and config."""

    model_config = ConfigDict(frozen=True)

    digest: str
    rootfs: Path
    config: ImageConfig


def default_cache() -> Path:
    """``$PROXYBENCH_IMAGE_CACHE``, else ``$XDG_CACHE_HOME/proxybench/images`` (``~/.cache``)."""
    if env := os.environ.get("PROXYBENCH_IMAGE_CACHE"):
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base, "proxybench", "images")


def image_tools() -> str | None:
    """None if skopeo and umoci are installed, else what to install."""
    missing = [t for t in ("skopeo", "umoci") if shutil.which(t) is None]
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


def _digest_of_file(path: Path) -> str:
    sha = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            sha.update(chunk)
    return sha.hexdigest()


# -- the tools ----------------------------------------------------------------------------------------


def _tool(argv: list[str], deadline: float, what: str, env: dict[str, str]) -> None:
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


def _blob(layout: Path, descriptor: Any, what: str) -> Path:
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


def _json_blob(layout: Path, descriptor: Any, what: str) -> dict[str, Any]:
    path = _blob(layout, descriptor, what)
    if path.stat().st_size > _MAX_JSON:
        raise ImageError(f"{what}: larger than {_MAX_JSON} bytes")
    data = path.read_bytes()
    if f"sha256:{hashlib.sha256(data).hexdigest()}" != descriptor["digest"]:
        raise ImageError(f"{what}: its bytes do not hash to the digest {descriptor['digest'][:19]}")
    return _json(data, what)


def _json(data: bytes, what: str) -> dict[str, Any]:
    try:
        value = json.loads(data)
    except (ValueError, RecursionError) as exc:
        raise ImageError(f"{what}: not JSON ({str(exc)[:120]})") from None
    if not isinstance(value, dict):
        raise ImageError(f"{what}: not a JSON object")
    return value


def _verify_layout(layout: Path, limits: ImageLimits, deadline: float) -> tuple[str, dict[str, Any], list[str]]:
    """(manifest digest, config, compression of each layer) of the staged layout, every byte checked."""
    index_file = layout / "index.json"
    if index_file.stat().st_size > _MAX_JSON:
        raise ImageError("index.json: larger than 1 MiB")
    manifests = _json(index_file.read_bytes(), "index.json").get("manifests")
    if not isinstance(manifests, list) or len(manifests) != 1:
        raise ImageError("index.json: expected exactly one image manifest")
    descriptor = manifests[0]
    manifest = _json_blob(layout, descriptor, "manifest")
    if manifest.get("mediaType", descriptor.get("mediaType")) not in MANIFEST_TYPES:
        raise ImageError(f"manifest: media type {str(manifest.get('mediaType'))[:80]!r} is not an image manifest")
    config = _json_blob(layout, manifest.get("config"), "config")
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
        path = _blob(layout, layer, f"layer {i}")
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


def _image_config(config: dict[str, Any]) -> ImageConfig:
    try:
        return ImageConfig.model_validate(config.get("config") or {})
    except ValidationError as exc:
        first = exc.errors()[0]
        raise ImageError(f"config: field {'.'.join(str(p) for p in first['loc'])!r}: {first['msg']}") from None


# -- the cache ----------------------------------------------------------------------------------------


def _cached(cache: Path, digest: str) -> UnpackedImage | None:
    meta = cache / "rootfs" / f"{digest[7:]}.json"
    if not meta.is_file() or not (cache / "rootfs" / digest[7:]).is_dir():
        return None
    return UnpackedImage.model_validate_json(meta.read_bytes())


def _known_digest(path: Path, cache: Path) -> tuple[str | None, str | None]:
    """(manifest digest already cached for this source, the archive's SHA-256 to remember it by). An archive is
    known by its own SHA-256 from an earlier unpack; a layout folder by its index's manifest digest, once its
    manifest, config and layer blobs are found to hash to what they claim (naming a cached image's digest is not
    enough: the folder must hold that image's bytes)."""
    if path.is_dir():
        try:
            manifests = _json((path / "index.json").read_bytes()[:_MAX_JSON], "index.json").get("manifests")
            if isinstance(manifests, list) and len(manifests) == 1 and \
                    manifests[0].get("mediaType") in MANIFEST_TYPES and _blobs_hold(path, manifests[0]):
                return manifests[0]["digest"], None
        except (OSError, ImageError, AttributeError, KeyError, TypeError):
            pass
        return None, None
    sha = _digest_of_file(path)
    known = cache / "sources" / sha
    return (known.read_text().strip() if known.is_file() else None), sha


def _blobs_hold(layout: Path, descriptor: dict[str, Any]) -> bool:
    """Whether the layout's blobs of this manifest (itself, its config, its layers) hash to their digests."""
    manifest = _json_blob(layout, descriptor, "manifest")
    for d in [manifest["config"], *manifest["layers"]]:
        if f"sha256:{_digest_of_file(_blob(layout, d, 'blob'))}" != d["digest"]:
            return False
    return True


def _finish_tree(rootfs: Path) -> None:
    """Read-only for all but the owner, no set-id bits; the sandbox's mount points as empty folders."""
    for folder, dirs, files in os.walk(rootfs):
        os.chmod(folder, 0o755)
        for name in files + [d for d in dirs if os.path.islink(os.path.join(folder, d))]:
            p = os.path.join(folder, name)
            st = os.lstat(p)
            if stat.S_ISREG(st.st_mode):
                os.chmod(p, 0o755 if st.st_mode & 0o111 else 0o644)
            elif not stat.S_ISLNK(st.st_mode):
                os.chmod(p, 0o644)
    for name in MOUNT_POINTS:
        p = rootfs / name
        if p.is_symlink() or (p.exists() and not p.is_dir()):
            p.unlink()
        p.mkdir(mode=0o755, exist_ok=True)


def unpack_image(path: str | os.PathLike[str], cache: str | os.PathLike[str] | None = None, *,
                 limits: ImageLimits | None = None) -> UnpackedImage:
    """The image at ``path`` unpacked in ``cache`` (default :func:`default_cache`), from the cache when it is
    there. Raises :class:`ImageError` naming what is wrong with the image (the module docstring's steps)."""
    limits = limits or ImageLimits()
    path, cache = Path(path), Path(cache) if cache is not None else default_cache()
    if problem := image_tools():
        raise ImageError(f"image {path}: cannot unpack images here: {problem}")
    if not path.is_dir() and not path.is_file():
        raise ImageError(f"image {path}: no such file or folder")
    for sub in ("rootfs", "sources", "staging"):
        (cache / sub).mkdir(parents=True, exist_ok=True, mode=0o755)
    with open(cache / ".lock", "a+") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one unpack at a time; the second finds the first's result
        known, sha = _known_digest(path, cache)
        if known and (hit := _cached(cache, known)):
            return hit
        staging = cache / "staging" / secrets.token_hex(8)
        staging.mkdir(mode=0o700)
        try:
            image = _unpack(path, staging, cache, limits)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        if sha is not None:
            (cache / "sources" / sha).write_text(image.digest + "\n")
        return image


def _unpack(path: Path, staging: Path, cache: Path, limits: ImageLimits) -> UnpackedImage:
    deadline = time.monotonic() + limits.max_seconds
    source, size = _source(path, limits)
    if size > limits.max_archive_bytes:
        raise ImageError(f"image {path}: {size} bytes of blobs; at most {limits.max_archive_bytes} are allowed")
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(staging), "TMPDIR": str(staging)}
    layout = staging / "layout"
    # an OCI image keeps its layers as they are; a docker archive's plain layers are gzipped (fast, level 1):
    # skopeo 1.9 would label them gzip while leaving them plain
    keep = ["--dest-oci-accept-uncompressed-layers"] if not source.startswith("docker-archive:") else \
        ["--dest-compress", "--dest-compress-format", "gzip", "--dest-compress-level", "1"]
    _tool(["skopeo", "--insecure-policy", "copy", "--quiet", *keep, source, f"oci:{layout}:{_REF}"], deadline,
          f"image {path}: skopeo copy", env)
    try:
        digest, config, compressions = _verify_layout(layout, limits, deadline)
    except ImageError as exc:
        raise ImageError(f"image {path}: {exc}") from None
    if hit := _cached(cache, digest):
        return hit
    if "zstd" in compressions:  # umoci 0.4 reads plain and gzip layers only
        gz = staging / "gzip"
        _tool(["skopeo", "--insecure-policy", "copy", "--quiet", "--dest-compress", "--dest-compress-format", "gzip",
               "--dest-compress-level", "1", f"oci:{layout}:{_REF}", f"oci:{gz}:{_REF}"], deadline,
              f"image {path}: recompressing its zstd layers", env)
        layout = gz
    rootfs = staging / "rootfs"
    _tool(["umoci", "raw", "unpack", "--rootless", "--image", f"{layout}:{_REF}", str(rootfs)], deadline,
          f"image {path}: umoci raw unpack", env)
    _finish_tree(rootfs)
    image = UnpackedImage(digest=digest, rootfs=cache / "rootfs" / digest[7:], config=_image_config(config))
    meta = staging / "image.json"
    meta.write_text(image.model_dump_json())
    os.rename(rootfs, image.rootfs)
    os.rename(meta, cache / "rootfs" / f"{digest[7:]}.json")
    return image
