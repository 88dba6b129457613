"""Container images for tests, built without a registry.

- :func:`oci_layout` writes an OCI image layout by hand from layer tars made here (hostile layers, small images);
- :func:`base_rootfs` is a minimal Debian root file system with its own Python 3 and cbor2 (mmdebstrap's
  ``extract`` variant: the packages' files, no maintainer scripts), cached under
  ``~/.cache/proxybench/test-images/<recipe digest>`` so it is built once per machine (~15 s, ~50 MB);
- :func:`agent_image` packs that root file system and an agent script into an OCI layout with umoci, its
  ENTRYPOINT running the script with the image's own ``/usr/bin/python3``.
"""

from __future__ import annotations

import fcntl
import gzip
import hashlib
import io
import json
import os
import shutil
import subprocess
import tarfile
from pathlib import Path

import pytest

__all__ = ["agent_image", "base_rootfs", "member", "oci_layout", "require_image_tools", "tar_layer"]

SUITE, MIRROR = "bookworm", "http://deb.debian.org/debian"
PACKAGES = ("python3-minimal", "python3-cbor2")
EXCLUDES = ("/usr/share/man/*", "/usr/share/doc/*", "/usr/share/locale/*", "/usr/share/info/*")
RECIPE = json.dumps({"suite": SUITE, "variant": "extract", "packages": PACKAGES, "excludes": EXCLUDES})
CACHE = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "proxybench" / "test-images"


def require_image_tools() -> None:
    """Skip (or fail where CI requires the sandbox) without skopeo, umoci and mmdebstrap."""
    missing = [t for t in ("skopeo", "umoci", "mmdebstrap") if shutil.which(t) is None]
    if missing:
        msg = f"image tools missing: {', '.join(missing)} (apt-get install {' '.join(missing)})"
        if os.environ.get("PROXYBENCH_REQUIRE_SANDBOX"):
            pytest.fail(msg)
        pytest.skip(msg)


def tar_layer(members: list[tuple[tarfile.TarInfo, bytes]]) -> bytes:
    """A plain tar layer from (header, data) pairs."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w", format=tarfile.PAX_FORMAT) as tf:
        for info, data in members:
            info.size = len(data) if info.isreg() else 0
            tf.addfile(info, io.BytesIO(data) if info.isreg() else None)
    return buf.getvalue()


def _compress(raw: bytes, compression: str) -> bytes:
    if compression == "gzip":
        return gzip.compress(raw, mtime=0)
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdCompressor().compress(raw)
    return raw


def member(name: str, kind: bytes = tarfile.REGTYPE, data: bytes = b"", linkname: str = "",
           mode: int = 0o644) -> tuple[tarfile.TarInfo, bytes]:
    info = tarfile.TarInfo(name)
    info.type, info.linkname, info.mode = kind, linkname, mode
    return info, data


_MEDIA = {"none": "application/vnd.oci.image.layer.v1.tar", "gzip": "application/vnd.oci.image.layer.v1.tar+gzip",
          "zstd": "application/vnd.oci.image.layer.v1.tar+zstd"}


def _put(layout: Path, data: bytes) -> str:
    digest = hashlib.sha256(data).hexdigest()
    (layout / "blobs" / "sha256" / digest).write_bytes(data)
    return f"sha256:{digest}"


def oci_layout(layout: Path, plain: list[bytes], config: dict | None = None, *, compression: str = "gzip",
               diff_ids: list[str] | None = None) -> Path:
    """An OCI image layout of the tar layers ``plain`` (stored with ``compression``) and the image ``config``."""
    (layout / "blobs" / "sha256").mkdir(parents=True)
    (layout / "oci-layout").write_text('{"imageLayoutVersion": "1.0.0"}')
    layers = [_compress(p, compression) for p in plain]
    image_config = {"architecture": "amd64", "os": "linux", "config": config or {},
                    "rootfs": {"type": "layers",
                               "diff_ids": diff_ids or [f"sha256:{hashlib.sha256(p).hexdigest()}" for p in plain]}}
    config_bytes = json.dumps(image_config).encode()
    config_descriptor = {"mediaType": "application/vnd.oci.image.config.v1+json",
                         "digest": _put(layout, config_bytes), "size": len(config_bytes)}
    manifest = {"schemaVersion": 2, "mediaType": "application/vnd.oci.image.manifest.v1+json",
                "config": config_descriptor,
                "layers": [{"mediaType": _MEDIA[compression], "digest": _put(layout, b), "size": len(b)}
                           for b in layers]}
    manifest_bytes = json.dumps(manifest).encode()
    index = {"schemaVersion": 2, "manifests": [{"mediaType": manifest["mediaType"], "size": len(manifest_bytes),
                                                "digest": _put(layout, manifest_bytes),
                                                "annotations": {"org.opencontainers.image.ref.name": "latest"}}]}
    (layout / "index.json").write_text(json.dumps(index))
    return layout


def base_rootfs(packages: tuple[str, ...] = PACKAGES) -> Path:
    """The cached minimal Debian root file system (a tar) holding ``packages``, built by mmdebstrap on first use."""
    require_image_tools()
    recipe = RECIPE if packages == PACKAGES else \
        json.dumps({"suite": SUITE, "variant": "extract", "packages": packages, "excludes": EXCLUDES})
    folder = CACHE / hashlib.sha256(recipe.encode()).hexdigest()[:16]
    folder.mkdir(parents=True, exist_ok=True)
    tar = folder / "rootfs.tar"
    with open(folder / ".lock", "a+") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not tar.is_file():
            part = folder / "rootfs.tar.part"
            cmd = ["mmdebstrap", "--variant=extract", "--mode=root", "--format=tar", "--quiet",
                   f"--include={','.join(packages)}",
                   *(f"--dpkgopt=path-exclude={e}" for e in EXCLUDES), SUITE, str(part), MIRROR]
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
            if done.returncode != 0:
                tail = done.stderr.strip().splitlines()[-3:]
                if any("Could not resolve" in line or "Failed to fetch" in line for line in done.stderr.splitlines()):
                    pytest.skip(f"mmdebstrap cannot reach the Debian mirror {MIRROR}: {' / '.join(tail)}")
                raise RuntimeError(f"mmdebstrap failed: {' / '.join(tail)}")
            part.rename(tar)
    return tar


def agent_image(dest: Path, script: Path, *, args: tuple[str, ...] = (), labels: dict[str, str] | None = None,
                env: dict[str, str] | None = None, workdir: str | None = None, user: str | None = None,
                files: dict[str, bytes] | None = None, at: str = "opt/agent", packages: tuple[str, ...] = PACKAGES,
                trees: dict[str, tuple[Path, tuple[str, ...]]] | None = None) -> Path:
    """An OCI layout at ``dest``: the base root file system of ``packages`` (``/dev`` left out) plus ``script`` at
    ``/AT/agent.py`` (and ``files`` beside it), its ENTRYPOINT ``/usr/bin/python3 /AT/agent.py ARGS``; ``trees``:
    folders copied in, ``{path in the image: (folder, names to leave out)}`` (an SDK's site-packages)."""
    rootfs = dest.parent / f"{dest.name}.rootfs"
    rootfs.mkdir()
    subprocess.run(["tar", "-xf", str(base_rootfs(packages)), "-C", str(rootfs), "--exclude=./dev/*"], check=True)
    for where, (folder, leave_out) in (trees or {}).items():
        shutil.copytree(folder, rootfs / where, symlinks=True, ignore=shutil.ignore_patterns(*leave_out))
    (rootfs / at).mkdir(parents=True)
    shutil.copy(script, rootfs / at / "agent.py")
    for name, data in (files or {}).items():
        (rootfs / at / name).write_bytes(data)

    def umoci(*argv: str) -> None:
        subprocess.run(["umoci", *argv], check=True, capture_output=True)

    umoci("init", "--layout", str(dest))
    umoci("new", "--image", f"{dest}:latest")
    umoci("insert", "--rootless", "--image", f"{dest}:latest", str(rootfs), "/")
    shutil.rmtree(rootfs)
    config = ["--config.entrypoint", "/usr/bin/python3", "--config.entrypoint", f"/{at}/agent.py"]
    for a in args:
        config += ["--config.entrypoint", a]
    for k, v in (labels or {}).items():
        config += ["--config.label", f"{k}={v}"]
    for k, v in (env or {}).items():
        config += ["--config.env", f"{k}={v}"]
    if workdir:
        config += ["--config.workingdir", workdir]
    if user:
        config += ["--config.user", user]
    umoci("config", "--image", f"{dest}:latest", *config)
    umoci("gc", "--layout", str(dest))
    return dest
