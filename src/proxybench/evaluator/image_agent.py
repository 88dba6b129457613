"""A container image as an agent node: how it starts (its config) and how it speaks (labels or a side file).

The image's config decides how it starts, as ``docker run`` would: ENTRYPOINT then CMD as the command, its
``Env`` (``PATH`` as Docker's default where it sets none, ``HOME=/scratch`` where it sets none: its own home is
read-only here), its ``WorkingDir`` (default ``/``) and its ``User`` (``uid[:gid]`` or names from its own
``/etc/passwd`` and ``/etc/group``; default root) — a user id inside the sandbox's user namespace only, with no
capability; outside it the agent is the unprivileged agent user like every package.

What a package's manifest says beyond its command (``proxybench-agent.yaml``: protocol, transport, timeouts,
reflection) an image says in labels, ``org.proxybench.agent.<key>`` (e.g. ``LABEL
org.proxybench.agent.transport=fifo``), or in a side file beside it, ``<image path>.proxybench-agent.yaml``
holding the same keys (the file wins over the labels). Without either it is an ``aido-z2`` node on stdin/stdout
with the default timeouts, as AIDO's templates are. With ``protocol: duckietown-sdk`` (and ``timing``) it is a
duckietown-sdk program carrying its own SDK, driving a virtual DB21J that it finds at 127.0.0.1:7501.
"""

from __future__ import annotations

import os
import shlex
import stat
import subprocess
import time
from pathlib import Path

from proxybench.evaluator.images import UnpackedImage, cached_images, unpack_image
from proxybench.evaluator.sandbox import Isolation, Limits, SandboxError, confine_image, fifo_root
from proxybench.protocol.images import (
    LABEL_PREFIX,
    SIDE_SUFFIX,
    ImageConfig,
    ImageError,
    ImageLimits,
    image_manifest,
    image_tools,
)
from proxybench.protocol.package import SDK_PROTOCOL, AgentManifest

__all__ = ["LABEL_PREFIX", "SIDE_SUFFIX", "image_env", "image_manifest", "image_spec", "image_user", "images_problem",
           "probe_image"]

DOCKER_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
_MAX_ENV = 1000
_MAX_ID_FILE = 1 << 20


def images_problem(isolation: Isolation) -> str | None:
    """None if container images can run here (skopeo and umoci installed, a bubblewrap sandbox), else why not."""
    if problem := image_tools():
        return problem
    if isolation.kind != "bwrap":
        return f"images run in bubblewrap only: {isolation.problem or isolation.note}"
    return None


def image_env(config: ImageConfig) -> dict[str, str]:
    """The agent's environment: the image's ``Env`` over Docker's ``PATH``, ``HOME=/scratch``, ``TMPDIR=/tmp`` and
    one thread per numeric library (one evaluator, one core)."""
    env = {"PATH": DOCKER_PATH, "HOME": "/scratch", "TMPDIR": "/tmp", "OMP_NUM_THREADS": "1",
           "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    for item in (config.env or [])[:_MAX_ENV]:
        key, sep, value = item.partition("=")
        if not sep or not key or "\x00" in item:
            raise ImageError(f"config: Env entry {item[:80]!r} is not KEY=VALUE")
        env[key] = value
    return env


def _id_file(rootfs: Path, name: str) -> list[list[str]]:
    """The rows of the image's ``/etc/passwd`` or ``/etc/group``, read only where neither ``/etc`` nor the file
    is a symbolic link (the tree is the image's: a link could point at the host's files)."""
    etc, file = rootfs / "etc", rootfs / "etc" / name
    try:
        if not stat.S_ISDIR(etc.lstat().st_mode) or not stat.S_ISREG(file.lstat().st_mode):
            return []
        with open(file, "rb") as f:
            text = f.read(_MAX_ID_FILE).decode("utf-8", "replace")
    except OSError:
        return []
    return [line.split(":") for line in text.splitlines() if line and not line.startswith("#")]


def _lookup(rows: list[list[str]], name: str, column: int) -> int | None:
    for row in rows:
        if len(row) > column and row[0] == name and row[column].isdigit():
            return int(row[column])
    return None


def image_user(image: UnpackedImage) -> tuple[int, int]:
    """(uid, gid) of the image's ``User``: numbers, or names from its own passwd and group files."""
    text = image.config.user.strip()
    if not text:
        return 0, 0
    user, _, group = text.partition(":")
    passwd = _id_file(image.rootfs, "passwd")
    uid = int(user) if user.isdigit() else _lookup(passwd, user, 2)
    if uid is None:
        raise ImageError(f"config: User {text!r}: no user {user!r} in the image's /etc/passwd")
    if not group:
        gid = next((int(r[3]) for r in passwd if len(r) > 3 and r[2] == str(uid) and r[3].isdigit()), uid)
    else:
        gid = int(group) if group.isdigit() else _lookup(_id_file(image.rootfs, "group"), group, 2)
        if gid is None:
            raise ImageError(f"config: User {text!r}: no group {group!r} in the image's /etc/group")
    if uid > 2**31 or gid > 2**31:
        raise ImageError(f"config: User {text!r}: ids must be below 2^31")
    return uid, gid


def _workdir(image: UnpackedImage) -> str:
    """The image's WorkingDir, which must be a folder of the image (Docker would make it; the tree is read-only)."""
    workdir = os.path.normpath("/" + (image.config.working_dir or "/")).replace("//", "/")
    here = image.rootfs / workdir.lstrip("/")
    if ".." in workdir.split("/") or here.is_symlink() or not here.is_dir():
        raise ImageError(f"config: WorkingDir {image.config.working_dir!r} is not a folder of the image")
    return workdir


def image_spec(name: str, path: str | os.PathLike[str], isolation: Isolation, *, limits: Limits | None = None,
               cache: str | os.PathLike[str] | None = None, image_limits: ImageLimits | None = None,
               parent: int | None = -1):
    """The runner's ``AgentSpec`` of the image at ``path``, unpacked (or found) in ``cache``: a node whose command
    runs the image in the sandbox, with the start-up options of its labels or side file. Raises
    :class:`ImageError` (the image's fault) or :class:`~proxybench.evaluator.sandbox.SandboxError` (the host's)."""
    from proxybench.runner.jobs import AgentSpec

    path = Path(path)
    image = unpack_image(path, cache, limits=image_limits)
    manifest = image_manifest(name, path, image.config)
    try:
        env, user, workdir = image_env(image.config), image_user(image), _workdir(image)
    except ImageError as exc:
        raise ImageError(f"image {path}: {exc}") from None
    if manifest.protocol == SDK_PROTOCOL:
        return _sdk_spec(manifest, image, env, user, workdir, isolation, limits or Limits(), parent)
    options = manifest.node_options()
    root = None
    if options.transport == "fifo":
        root = fifo_root(image.rootfs)
        options = manifest.node_options(fifo_dir=str(root))
    argv = confine_image(list(manifest.command), image.rootfs, limits or Limits(), isolation, env=env,
                         workdir=workdir, user=user, parent=parent, fifo_root=root)
    return AgentSpec.node(name, shlex.join(argv), options)


def _sdk_spec(manifest: AgentManifest, image: UnpackedImage, env: dict[str, str], user: tuple[int, int],
              workdir: str, isolation: Isolation, limits: Limits, parent: int | None):
    """The ``AgentSpec`` of a duckietown-sdk image: its program (with the image's own SDK) in the sandbox, and its
    virtual DB21J (the DTPS bridge, which runs in this host's SDK environment) where only the sandbox reaches it,
    as for an SDK package (:func:`~proxybench.evaluator.sandbox.sdk_package_spec`): the safe sandbox joins the
    bridge's network namespace, so the program finds its robot at 127.0.0.1:7501 as on the Duckiematrix."""
    from proxybench.dtps.agent import NETNS_ENV
    from proxybench.dtps.env import DtpsEnvError, sdk_python
    from proxybench.dtps.options import SdkOptions
    from proxybench.runner.jobs import AgentSpec

    try:
        sdk_python()  # the bridge's environment: this host's problem when it is missing
    except DtpsEnvError as exc:
        raise SandboxError(f"duckietown-sdk image {manifest.name!r}: its virtual robot needs this host's SDK "
                           f"environment: {exc}") from None
    own = isolation.uid is not None  # root, switching to the agent user: the bridge's own namespace
    argv = confine_image(list(manifest.command), image.rootfs, limits, isolation, env=env, workdir=workdir,
                         user=user, parent=parent, join_netns_env=NETNS_ENV if own else None, host_net=not own)
    options = SdkOptions(timing=manifest.timing or "realtime", start_timeout=manifest.start_timeout,
                         step_timeout=manifest.step_timeout, own_netns=own)
    return AgentSpec.sdk(manifest.name, shlex.join(argv), options)


#: what :func:`probe_image` starts in an image, the first it has: nothing of the image's agent runs
PROBES = (("usr/bin/true", ["/usr/bin/true"]), ("bin/true", ["/bin/true"]), ("bin/sh", ["/bin/sh", "-c", ":"]),
          ("usr/bin/python3", ["/usr/bin/python3", "-c", "pass"]))


def _file_in_root(rootfs: Path, path: str, hops: int = 16) -> bool:
    """Whether ``path`` is a plain file of the image, its symbolic links (``bin -> usr/bin``, ``python3 ->
    python3.11``) resolved inside the root as the sandbox resolves them, never on this host."""
    parts, done = [p for p in path.split("/") if p], []
    while parts:
        name = parts.pop(0)
        if name in (".", ".."):
            done = done[:-1] if name == ".." else done
            continue
        here = rootfs.joinpath(*done, name)
        if here.is_symlink():
            hops -= 1
            if hops < 0:
                return False
            target = os.readlink(here)
            done = [] if target.startswith("/") else done
            parts = [p for p in target.split("/") if p] + parts
            continue
        done.append(name)
    return stat.S_ISREG(os.lstat(rootfs.joinpath(*done)).st_mode) if os.path.lexists(rootfs.joinpath(*done)) else False


def probe_image(isolation: Isolation, cache: str | os.PathLike[str] | None = None) -> str:
    """Start one cached image (the most recently unpacked that has ``true``, ``sh`` or ``python3``) in the sandbox
    as an agent would start, and say how that went, in one line: the check that images run here, not only that
    their tools are installed. Nothing cached: says so (an image is unpacked on first use)."""
    images = cached_images(cache)
    if not images:
        return "no image cached yet: none started"
    for image in images:
        probe = next((argv for rel, argv in PROBES if _file_in_root(image.rootfs, rel)), None)
        if probe is not None:
            break
    else:
        return f"none of the {len(images)} cached images has true, sh or python3 to start"
    try:
        user = image_user(image)
    except ImageError:
        user = (0, 0)
    t0 = time.perf_counter()
    try:
        argv = confine_image(probe, image.rootfs, Limits(), isolation, env=image_env(image.config), user=user,
                             parent=None)
        done = subprocess.run(argv, capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    except (OSError, subprocess.SubprocessError, SandboxError, ImageError) as exc:
        return f"FAILED to start cached image {image.digest[:19]}: {exc}"
    if done.returncode != 0:
        tail = " / ".join(done.stderr.strip().splitlines()[-3:]) or f"exit status {done.returncode}"
        return f"FAILED: cached image {image.digest[:19]} ({' '.join(probe)}) did not start: {tail}"
    return f"started cached image {image.digest[:19]} ({' '.join(probe)}) in {time.perf_counter() - t0:.2f} s"
