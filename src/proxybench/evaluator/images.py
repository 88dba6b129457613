"""Container images as agents, unpacked once into a root file system cached by their manifest's digest.

The checks come first and are the package check's (:mod:`proxybench.protocol.images`, which the challenges server
runs on an upload too): skopeo brings the image (an OCI image layout folder, an OCI archive or a ``docker save`` /
``podman save`` tarball) into a private OCI layout in a staging folder inside the cache, and every byte of it is
checked there, before a file of the root file system exists. Then:

1. zstd layers, which umoci 0.4 cannot read, are recompressed to gzip by ``skopeo`` (their bytes already bounded);
2. ``umoci raw unpack --rootless`` applies the layers in order with whiteouts, resolving every path inside the
   root (``filepath-securejoin``), as a second line of defence behind the checks;
3. the tree is made read-only for everyone but its owner (no set-id bits, no group/other write), the mount points
   the sandbox needs (``/proc``, ``/dev``, ``/tmp``, ``/scratch``, ``/fifo``) are made empty folders, and the
   staging folder is renamed to ``rootfs/<digest>`` with the image's config beside it (``<digest>.json``).

A failure at any step removes the staging folder: nothing is written outside the cache and nothing already
cached is touched. Episodes share the cached tree; the sandbox shows it read-only as ``/``.
"""

from __future__ import annotations

import fcntl
import os
import secrets
import shutil
import stat
import time
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict

from proxybench.protocol.images import (
    MANIFEST_TYPES,
    REF,
    ImageConfig,
    ImageError,
    ImageLimits,
    blob_path,
    digest_of_file,
    image_config,
    image_tools,
    json_blob,
    json_object,
    run_tool,
    stage_image,
    tool_env,
)

__all__ = ["ImageConfig", "ImageError", "ImageLimits", "UnpackedImage", "cached_images", "default_cache",
           "image_tools", "unpack_image"]

#: folders the sandbox mounts over; each must be an empty folder of the root file system
MOUNT_POINTS = ("proc", "dev", "tmp", "scratch", "fifo")
_MAX_JSON = 1 << 20


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


# -- the cache ----------------------------------------------------------------------------------------


def _cached(cache: Path, digest: str) -> UnpackedImage | None:
    meta = cache / "rootfs" / f"{digest[7:]}.json"
    if not meta.is_file() or not (cache / "rootfs" / digest[7:]).is_dir():
        return None
    return UnpackedImage.model_validate_json(meta.read_bytes())


def cached_images(cache: str | os.PathLike[str] | None = None) -> list[UnpackedImage]:
    """The images unpacked in ``cache`` (default :func:`default_cache`), the most recently unpacked first; a record
    that does not read is left out (it is the cache's, not an image)."""
    folder = Path(cache) if cache is not None else default_cache()
    found = []
    for meta in sorted((folder / "rootfs").glob("*.json"), key=lambda p: p.stat().st_mtime, reverse=True):
        try:
            image = UnpackedImage.model_validate_json(meta.read_bytes())
        except (OSError, ValueError):
            continue
        if image.rootfs.is_dir():
            found.append(image)
    return found


def _known_digest(path: Path, cache: Path) -> tuple[str | None, str | None]:
    """(manifest digest already cached for this source, the archive's SHA-256 to remember it by). An archive is
    known by its own SHA-256 from an earlier unpack; a layout folder by its index's manifest digest, once its
    manifest, config and layer blobs are found to hash to what they claim (naming a cached image's digest is not
    enough: the folder must hold that image's bytes)."""
    if path.is_dir():
        try:
            manifests = json_object((path / "index.json").read_bytes()[:_MAX_JSON], "index.json").get("manifests")
            if isinstance(manifests, list) and len(manifests) == 1 and \
                    manifests[0].get("mediaType") in MANIFEST_TYPES and _blobs_hold(path, manifests[0]):
                return manifests[0]["digest"], None
        except (OSError, ImageError, AttributeError, KeyError, TypeError):
            pass
        return None, None
    sha = digest_of_file(path)
    known = cache / "sources" / sha
    return (known.read_text().strip() if known.is_file() else None), sha


def _blobs_hold(layout: Path, descriptor: dict[str, Any]) -> bool:
    """Whether the layout's blobs of this manifest (itself, its config, its layers) hash to their digests."""
    manifest = json_blob(layout, descriptor, "manifest")
    for d in [manifest["config"], *manifest["layers"]]:
        if f"sha256:{digest_of_file(blob_path(layout, d, 'blob'))}" != d["digest"]:
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
    staged = stage_image(path, staging, limits, deadline)
    if hit := _cached(cache, staged.digest):
        return hit
    layout = staged.layout
    if "zstd" in staged.compressions:  # umoci 0.4 reads plain and gzip layers only
        gz = staging / "gzip"
        run_tool(["skopeo", "--insecure-policy", "copy", "--quiet", "--dest-compress", "--dest-compress-format",
                  "gzip", "--dest-compress-level", "1", f"oci:{layout}:{REF}", f"oci:{gz}:{REF}"], deadline,
                 f"image {path}: recompressing its zstd layers", tool_env(staging))
        layout = gz
    rootfs = staging / "rootfs"
    run_tool(["umoci", "raw", "unpack", "--rootless", "--image", f"{layout}:{REF}", str(rootfs)], deadline,
             f"image {path}: umoci raw unpack", tool_env(staging))
    _finish_tree(rootfs)
    image = UnpackedImage(digest=staged.digest, rootfs=cache / "rootfs" / staged.digest[7:],
                          config=image_config(staged.config))
    meta = staging / "image.json"
    meta.write_text(image.model_dump_json())
    os.rename(rootfs, image.rootfs)
    os.rename(meta, cache / "rootfs" / f"{staged.digest[7:]}.json")
    return image
