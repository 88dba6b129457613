"""The sandbox an agent package runs in: a dedicated unprivileged user inside bubblewrap.

Submissions are code from strangers, so an evaluator never runs one with its own rights. The agent node
is started through ``_confine.py`` (see there for each step), which ends in ``bwrap`` running the
manifest's command

- as the **agent user** (default ``proxybench-agent``, made by ``proxybench sandbox setup``), never as
  the evaluator's user or root: the evaluator must run as root to switch to it;
- in new user, PID, network, IPC, UTS and cgroup namespaces, with no capabilities, ``no_new_privs``, no
  further user namespaces, and the kernel killing it with the job's worker;
- seeing only ``/usr``, the runtime (this Python, its packages and proxybench, read-only at their own
  paths, even when they sit in a folder the agent user cannot enter) and its package (read-only at
  ``/agent``, the working directory), with bounded tmpfs for ``/scratch`` (``$HOME``), ``/tmp`` and
  ``/dev/shm``;
- under CPU, address-space, file-size and process limits, with a clean environment;
- with the FIFO transport (``transport: fifo`` in its manifest): its own FIFO folder, made by the
  evaluator beside the package (mode 700), read-only at ``/fifo``, and ``AIDONODE_DATA_IN`` /
  ``AIDONODE_DATA_OUT`` pointing there (:func:`package_spec`).

Where this cannot be done (no bubblewrap, no user namespaces, no agent user, an evaluator that is not
root) agent packages are refused with a message naming the fix (:attr:`Isolation.problem`), unless the
developer's flag ``dev_unsafe`` allows agents to run as the evaluator's own user; every report of such a
job says so. ``python`` / ``python3`` as the command's program mean the evaluator's own interpreter.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
import pwd
import shlex
import shutil
import stat
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from proxybench.protocol.package import SDK_PROTOCOL, AgentManifest, PackageError
from proxybench.protocol.unpack import extract_archive

__all__ = [
    "AGENT_USER", "ArchiveMismatch", "Isolation", "Limits", "SandboxError", "agent_command", "confine", "confine_image",
    "detect_isolation", "fifo_root", "package_spec", "prepare_agent", "probe", "runtime_paths", "sdk_package_spec",
]

log = logging.getLogger("proxybench.evaluator")

AGENT_USER = "proxybench-agent"
_SHIM = Path(__file__).with_name("_confine.py")
SETUP_HINT = "run `proxybench sandbox setup` as root"


class SandboxError(RuntimeError):
    """This host cannot sandbox the agent as asked (not the submission's fault)."""


class ArchiveMismatch(RuntimeError):
    """The archive bytes here do not hash to the submitted hash: damaged on the way, not the developer's fault."""


@dataclass(frozen=True)
class Limits:
    """Resource limits of one agent sandbox. ``cpu_seconds`` [s of CPU time per process]; ``memory_bytes``
    [address space per process]; ``file_bytes`` [largest file]; ``processes``: threads/processes the agent
    may add to those its user already runs; ``scratch_bytes`` [/scratch]; ``tmp_bytes`` [/tmp and /dev/shm,
    each]."""

    cpu_seconds: int = 600
    memory_bytes: int = 4 << 30
    file_bytes: int = 256 << 20
    processes: int = 256
    scratch_bytes: int = 256 << 20
    tmp_bytes: int = 64 << 20


@dataclass(frozen=True)
class Isolation:
    """How agent packages run on this host.

    ``kind``: ``bwrap`` (namespaces), ``none`` (developer's unsafe mode without bubblewrap) or
    ``unavailable`` (agent packages are refused: :attr:`problem` says why and what to do). ``uid`` /
    ``gid``: the agent user the sandbox switches to (None: the evaluator's own user). ``safe``: agents run
    as the dedicated unprivileged user in bubblewrap. ``runtime``: folders the agent sees read-only;
    ``pythonpath``: where it imports proxybench from.
    """

    kind: str
    user: str
    uid: int | None = None
    gid: int | None = None
    safe: bool = False
    note: str = ""
    problem: str = ""
    bwrap: str | None = None
    runtime: tuple[str, ...] = ()
    pythonpath: str = ""

    @property
    def usable(self) -> bool:
        return self.kind != "unavailable"

    @property
    def blocks_network(self) -> bool:
        return self.kind == "bwrap"

    def report(self) -> dict[str, Any]:
        """What every job report says about the sandbox."""
        return {"kind": self.kind, "user": self.user, "safe": self.safe, "note": self.note or self.problem}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Isolation:
        return cls(**{**data, "runtime": tuple(data.get("runtime", ()))})


def runtime_paths() -> tuple[tuple[str, ...], str]:
    """(folders the agent's Python needs, PYTHONPATH): this interpreter's prefixes and the proxybench package.

    Only these are shown to the agent, never the folders around them (a repository checkout may hold a
    server's database beside ``src/``). ``/usr`` is always visible and not listed.
    """
    import proxybench

    package = Path(proxybench.__file__).resolve().parent
    wanted = [os.path.abspath(p) for p in (sys.prefix, sys.exec_prefix, sys.base_prefix, sys.base_exec_prefix)]
    interpreter = os.path.realpath(sys.executable)
    if not any(_under(interpreter, w) for w in wanted):
        wanted.append(os.path.dirname(interpreter))
    roots: list[str] = []
    for path in sorted(set(wanted), key=len):
        if not _under(path, "/usr") and not any(_under(path, r) for r in roots) and os.path.isdir(path):
            roots.append(path)
    if any(_under(str(package), r) or _under(str(package), "/usr") for r in roots):
        return tuple(roots), ""
    return (*roots, str(package)), str(package.parent)


def _under(path: str, root: str) -> bool:
    return path == root or path.startswith(root.rstrip("/") + "/")


def _agent_ids(agent_user: str) -> tuple[int, int] | str:
    """(uid, gid) of the agent user, or why it cannot be used."""
    try:
        pw = pwd.getpwnam(agent_user)
    except KeyError:
        return (f"the agent user {agent_user!r} does not exist: {SETUP_HINT} (it runs `useradd --system "
                f"--user-group --no-create-home --shell /usr/sbin/nologin {agent_user}`)")
    if pw.pw_uid == 0 or pw.pw_gid == 0:
        return f"the agent user {agent_user!r} is root (uid or gid 0): agents must run as an unprivileged user"
    if pw.pw_uid == os.geteuid():
        return f"the agent user {agent_user!r} is the evaluator's own user: give agents a user of their own"
    return pw.pw_uid, pw.pw_gid


def _whoami() -> str:
    try:
        return pwd.getpwuid(os.geteuid()).pw_name
    except KeyError:
        return f"uid {os.geteuid()}"


def probe(isolation: Isolation) -> str | None:
    """Run ``python3 -c 'import proxybench.protocol'`` through the whole chain; None if it works, else why not."""
    code = "import os, proxybench.protocol; open(os.path.join(os.environ['HOME'], 'w'), 'w').write('ok')"
    with tempfile.TemporaryDirectory(prefix="proxybench-probe-") as folder:
        os.chmod(folder, 0o755)  # a package folder, as prepare_agent leaves it
        try:
            argv = confine(["python3", "-c", code], folder, Limits(), isolation, parent=None)
            done = subprocess.run(argv, capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
        except (OSError, subprocess.SubprocessError, SandboxError) as exc:
            return str(exc)
    if done.returncode == 0:
        return None
    tail = " / ".join(done.stderr.strip().splitlines()[-3:]) or f"exit status {done.returncode}"
    if "namespace" in tail or "Operation not permitted" in tail:
        tail += (" (the kernel refuses unprivileged user namespaces? allow them: sysctl "
                 "kernel.unprivileged_userns_clone=1 and user.max_user_namespaces>0, or the AppArmor "
                 "restriction kernel.apparmor_restrict_unprivileged_userns=0)")
    return f"the sandbox does not start here: {tail}"


@functools.cache
def detect_isolation(agent_user: str = AGENT_USER, dev_unsafe: bool = False) -> Isolation:
    """How this host runs agent packages, probed once by starting Python in the sandbox.

    The safe way (root evaluator, agent user, working bubblewrap) or, when it is impossible: with
    ``dev_unsafe``, bubblewrap as the evaluator's own user, else no isolation at all (both reported as
    unsafe); without it ``kind == "unavailable"`` and :attr:`Isolation.problem` says what to do.
    """
    runtime, pythonpath = runtime_paths()
    bwrap = shutil.which("bwrap")
    common = {"runtime": runtime, "pythonpath": pythonpath}
    if os.geteuid() != 0:
        problem = (f"this evaluator runs as {_whoami()!r}, not root, so it cannot start agents as the unprivileged "
                   f"user {agent_user!r}: run it as root (it drops to {agent_user!r} for agents only; {SETUP_HINT} "
                   "first)")
    elif isinstance(ids := _agent_ids(agent_user), str):
        problem = ids
    elif bwrap is None:
        problem = "bubblewrap is not installed: apt-get install bubblewrap (Debian/Ubuntu), dnf install bubblewrap"
    else:
        safe = Isolation("bwrap", agent_user, ids[0], ids[1], True, f"bubblewrap as user {agent_user!r}: no network, "
                         "no other processes, read-only runtime and package, bounded scratch", bwrap=bwrap, **common)
        problem = probe(safe)
        if problem is None:
            return safe
    if not dev_unsafe:
        return Isolation("unavailable", agent_user, problem=f"agent packages cannot run safely here: {problem}",
                         **common)
    me = _whoami()
    log.warning("UNSAFE developer mode: %s; agents run as %r", problem, me)
    if bwrap is not None:
        same = Isolation("bwrap", me, safe=False, bwrap=bwrap, note=f"UNSAFE developer mode: agents run as the "
                         f"evaluator's user {me!r} in bubblewrap (no network, read-only view); {problem}", **common)
        if probe(same) is None:
            return same
    return Isolation("none", me, note=f"UNSAFE developer mode: agents run as the evaluator's user {me!r} with no "
                     f"isolation at all (network, files, processes); {problem}", **common)


def _tasks_of(uid: int) -> int:
    """Threads the user ``uid`` runs now (what RLIMIT_NPROC counts)."""
    n = 0
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/status") as f:
                status = f.read()
        except OSError:
            continue
        fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
        if fields.get("Uid", "").split()[:1] == [str(uid)]:
            n += int(fields.get("Threads", "1").strip() or 1)
    return n


def _agent_env(isolation: Isolation, folder: str) -> dict[str, str]:
    home, tmp = ("/scratch", "/tmp") if isolation.kind == "bwrap" else (folder, os.path.join(folder, ".tmp"))
    path = os.pathsep.join(dict.fromkeys([os.path.dirname(os.path.abspath(sys.executable)), "/usr/local/bin",
                                          "/usr/bin", "/bin"]))
    env = {"PATH": path, "HOME": home, "TMPDIR": tmp, "USER": "agent", "LOGNAME": "agent", "LANG": "C.UTF-8",
           "PYTHONUNBUFFERED": "1", "PYTHONDONTWRITEBYTECODE": "1", "MPLCONFIGDIR": f"{home}/.matplotlib",
           "NUMBA_CACHE_DIR": f"{home}/.numba"}
    if isolation.pythonpath:
        env["PYTHONPATH"] = isolation.pythonpath
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        env[var] = "1"  # one evaluator, one core: the agent should not start a thread per core
    return env


def confine(argv: list[str], folder: str | Path, limits: Limits, isolation: Isolation, *,
            extra_env: dict[str, str] | None = None, parent: int | None = -1,
            fifo_root: str | Path | None = None, python: str | None = None, extra_runtime: tuple[str, ...] = (),
            join_netns_env: str | None = None, host_net: bool = False) -> list[str]:
    """The command line that runs ``argv`` (from the package ``folder``) inside the sandbox.

    ``python`` / ``python3`` as ``argv[0]`` become ``python`` (default: this interpreter). ``parent``: the
    process that will start it (default: this one); the shim exits if it is already gone. ``fifo_root``: for
    the FIFO transport, the folder in which the caller makes each start's FIFO folder (the ``fifo_dir`` of its
    node options, see :func:`fifo_root`); the shim shows the agent that one folder. ``extra_runtime``: more
    folders the agent sees read-only (the SDK environment). ``join_netns_env``: the variable in which the
    starter names the network namespace the sandbox joins (a duckietown-sdk package's virtual robot);
    ``host_net``: keep the host's network (the developer's unsafe mode). Raises :class:`SandboxError` when
    ``isolation`` cannot run agents.
    """
    if not isolation.usable:
        raise SandboxError(isolation.problem)
    folder = str(Path(folder).resolve())
    argv = list(argv)
    if argv and argv[0] in ("python", "python3"):
        argv[0] = python or os.path.abspath(sys.executable)
    if isolation.kind == "none":
        Path(folder, ".tmp").mkdir(exist_ok=True)
    shim = _shim(folder, limits, isolation)
    if isolation.kind == "bwrap":
        shim += ["--bwrap", str(isolation.bwrap)]
        for path in (*isolation.runtime, *extra_runtime):
            shim += ["--runtime", path]
        if join_netns_env is not None:
            shim += ["--join-netns-env", join_netns_env]
        elif host_net:
            shim += ["--host-net"]
    shim += _shim_tail(isolation, parent, fifo_root, {**_agent_env(isolation, folder), **(extra_env or {})})
    return [*shim, "--", *argv]


def _shim(folder: str, limits: Limits, isolation: Isolation) -> list[str]:
    """The shim's command line up to its limits: what every sandbox shares."""
    uid = isolation.uid if isolation.uid is not None else os.getuid()
    return [sys.executable, "-I", "-S", str(_SHIM), "--package", folder, "--cpu", str(limits.cpu_seconds),
            "--memory", str(limits.memory_bytes), "--fsize", str(limits.file_bytes), "--core", "0",
            "--nproc", str(_tasks_of(uid) + limits.processes), "--scratch", str(limits.scratch_bytes),
            "--tmp", str(limits.tmp_bytes)]


def _shim_tail(isolation: Isolation, parent: int | None, fifo_root: str | Path | None,
               env: dict[str, str]) -> list[str]:
    """The shim's user switch, parent check, FIFO root and the agent's environment."""
    tail: list[str] = []
    if isolation.uid is not None:
        tail += ["--uid", str(isolation.uid), "--gid", str(isolation.gid)]
    if parent is not None:
        tail += ["--parent", str(os.getpid() if parent == -1 else parent)]
    if fifo_root is not None:
        tail += ["--fifo-root", str(Path(fifo_root).resolve())]
    for key, value in env.items():
        tail += ["--env", f"{key}={value}"]
    return tail


def confine_image(argv: list[str], rootfs: str | Path, limits: Limits, isolation: Isolation, *,
                  env: dict[str, str], workdir: str = "/", user: tuple[int, int] = (0, 0), parent: int | None = -1,
                  fifo_root: str | Path | None = None, join_netns_env: str | None = None,
                  host_net: bool = False) -> list[str]:
    """The command line that runs ``argv`` in a container image's root file system (``rootfs``, shown read-only as
    ``/``), with the image's environment ``env``, working directory and user (ids inside the sandbox's user
    namespace; outside it the agent runs as the agent user all the same). ``join_netns_env`` and ``host_net`` as
    for :func:`confine` (a duckietown-sdk image's virtual robot). Images need bubblewrap: raises
    :class:`SandboxError` where this host cannot run them."""
    if not isolation.usable:
        raise SandboxError(isolation.problem)
    if isolation.kind != "bwrap":
        raise SandboxError(f"container images run in bubblewrap only, and this host has none ({isolation.note})")
    shim = _shim(str(Path(rootfs).resolve()), limits, isolation)
    shim += ["--bwrap", str(isolation.bwrap), "--rootfs", "--chdir", workdir, "--inside-uid", str(user[0]),
             "--inside-gid", str(user[1])]
    if join_netns_env is not None:
        shim += ["--join-netns-env", join_netns_env]
    elif host_net:
        shim += ["--host-net"]
    return [*shim, *_shim_tail(isolation, parent, fifo_root, env), "--", *argv]


def prepare_agent(archive: bytes, sha256: str, dest: Path, *, max_bytes: int | None = None) -> AgentManifest:
    """Check an agent archive against its expected hash and :func:`check_archive`, unpack it into ``dest``.

    The files are left readable (not writable) by every user and lose any set-id bits, so the agent
    user can read its package through the read-only view. Raises :class:`PackageError` naming what is
    wrong (the submission's fault), or :class:`ArchiveMismatch`.
    """
    got = hashlib.sha256(archive).hexdigest()
    if got != sha256:
        raise ArchiveMismatch(f"archive hash is {got}, not the submitted {sha256}: refusing to run it")
    if max_bytes is not None and len(archive) > max_bytes:
        raise PackageError(f"archive is {len(archive)} bytes; this evaluator accepts at most {max_bytes}")
    manifest = extract_archive(archive, dest)
    for path in [dest, *dest.rglob("*")]:
        st = path.lstat()
        if stat.S_ISDIR(st.st_mode):
            path.chmod(0o755)
        elif stat.S_ISREG(st.st_mode):
            path.chmod(0o755 if st.st_mode & 0o111 else 0o644)
    return manifest


def agent_command(manifest: AgentManifest, folder: Path, limits: Limits, isolation: Isolation, *,
                  fifo_root: str | Path | None = None, parent: int | None = -1) -> str:
    """The sandboxed command (one string, as ``AgentSpec.command`` takes it) of an unpacked package."""
    return shlex.join(confine(list(manifest.command), folder, limits, isolation, parent=parent, fifo_root=fifo_root))


def fifo_root(folder: str | Path) -> Path:
    """Where the FIFO folders of the package unpacked in ``folder`` are made: beside it, never inside (the agent
    sees its package), mode 700, so that no one but the evaluator's user reaches them except through the
    sandbox's view of one of them."""
    root = Path(folder).resolve()
    root = root.with_name(root.name + ".fifos")
    try:
        root.mkdir(mode=0o700, exist_ok=True)
        st = root.lstat()
        if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.geteuid():
            raise SandboxError(f"{root} is not a folder of the evaluator's user: cannot make the agent's FIFOs there")
        root.chmod(0o700)
    except OSError as exc:
        raise SandboxError(f"cannot make the FIFO folder {root}: {exc.strerror}") from None
    return root


def package_spec(manifest: AgentManifest, folder: str | Path, limits: Limits, isolation: Isolation, *,
                 parent: int | None = -1):
    """The runner's ``AgentSpec`` of a package unpacked in ``folder``: its sandboxed command and the start-up
    options of its manifest. With ``transport: fifo`` the FIFOs are made in :func:`fifo_root` (the
    options' ``fifo_dir``), one folder per start, shown to the agent read-only at ``/fifo``. A duckietown-sdk
    package: :func:`sdk_package_spec`."""
    from proxybench.runner.jobs import AgentSpec

    if manifest.protocol == SDK_PROTOCOL:
        return sdk_package_spec(manifest, folder, limits, isolation, parent=parent)

    options = manifest.node_options()
    root = None
    if options.transport == "fifo":
        root = fifo_root(folder)
        options = manifest.node_options(fifo_dir=str(root))
    command = agent_command(manifest, Path(folder), limits, isolation, fifo_root=root, parent=parent)
    return AgentSpec.node(manifest.name, command, options)


def sdk_package_spec(manifest: AgentManifest, folder: str | Path, limits: Limits, isolation: Isolation, *,
                     parent: int | None = -1):
    """The ``AgentSpec`` of a duckietown-sdk package: its program in the sandbox with the SDK environment (read-only,
    first on ``PATH``; ``python3`` is its interpreter), and its virtual robot (the DTPS bridge) where only the
    sandbox reaches it. Safe sandbox (root): the bridge makes a network namespace of its own, drops to
    ``nobody`` and serves there; the sandbox joins that namespace instead of an empty one, so the agent finds
    the robot at 127.0.0.1:7501 as on the Duckiematrix, reaches nothing else, and cannot see or signal the
    bridge or write to its pipes (another user, in another PID namespace). Developer's unsafe modes: the
    agent shares the host's network with the bridge (reported as unsafe like the rest of those modes)."""
    from proxybench.dtps.agent import NETNS_ENV
    from proxybench.dtps.env import DtpsEnvError, env_path, sdk_python
    from proxybench.dtps.options import SdkOptions
    from proxybench.runner.jobs import AgentSpec

    try:
        python = str(sdk_python())
    except DtpsEnvError as exc:
        raise SandboxError(f"duckietown-sdk package {manifest.name!r}: {exc}") from None
    env_dir = str(env_path())
    own = isolation.kind == "bwrap" and isolation.uid is not None  # root, switching to the agent user
    default_path = _agent_env(isolation, str(folder))["PATH"]
    command = confine(list(manifest.command), folder, limits, isolation, parent=parent, python=python,
                      extra_runtime=(env_dir,), extra_env={"PATH": f"{env_dir}/bin{os.pathsep}{default_path}"},
                      join_netns_env=NETNS_ENV if own else None, host_net=not own)
    options = SdkOptions(timing=manifest.timing or "realtime", start_timeout=manifest.start_timeout,
                         step_timeout=manifest.step_timeout, own_netns=own)
    return AgentSpec.sdk(manifest.name, shlex.join(command), options)
