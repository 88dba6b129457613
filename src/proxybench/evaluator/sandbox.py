"""The sandbox an agent package runs in: its own folder, resource limits, no network, no root.

Submissions are code from strangers, so an evaluator never runs one unconfined. The agent node is started
through a chain of wrappers, each doing one thing, ending in an ``exec`` of the manifest's command:

1. network isolation, detected once per evaluator (:func:`detect_isolation`): ``bwrap`` (new network,
   IPC and PID namespaces, the whole file system read-only except the agent's folder, a private
   ``/tmp``) where it works, else ``unshare`` into a new network namespace (with ``--map-root-user``
   when not root), else none, with a warning in the log;
2. ``_confine.py``: working directory, ``RLIMIT_CPU`` / ``AS`` / ``FSIZE`` / ``NPROC`` / ``CORE``, the
   unprivileged user ``nobody`` when the evaluator runs as root (and ``nobody`` can run this Python),
   ``no_new_privs``, death with its parent, and a clean environment (no tokens or settings of the
   evaluator leak into the agent).

A network namespace holds only a loopback device that is down, so the agent can reach nothing, not even
the evaluator's own host. ``python`` / ``python3`` as the command's program mean the evaluator's own
interpreter (the one proxybench is installed in), since there are no container images here.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import logging
import os
import pwd
import shlex
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from proxybench.agents.package import AgentManifest, PackageError, extract_archive

__all__ = [
    "ISOLATIONS", "ArchiveMismatch", "Isolation", "Limits", "SandboxError", "agent_command", "confine",
    "detect_isolation", "prepare_agent",
]

log = logging.getLogger("proxybench.evaluator")

ISOLATIONS = ("auto", "bwrap", "unshare", "none")
_SHIM = Path(__file__).with_name("_confine.py")
_NOBODY = 65534


class SandboxError(RuntimeError):
    """This host cannot sandbox the agent as asked (not the submission's fault)."""


class ArchiveMismatch(RuntimeError):
    """The archive bytes here do not hash to the submitted hash: damaged on the way, not the developer's fault."""


@dataclass(frozen=True)
class Limits:
    """Resource limits of one agent process. ``cpu_seconds`` [s of CPU time], sizes [bytes];
    ``processes``: threads/processes the agent may add to those its user already runs."""

    cpu_seconds: int = 600
    memory_bytes: int = 4 << 30
    file_bytes: int = 256 << 20
    processes: int = 256


@dataclass(frozen=True)
class Isolation:
    """How agents are cut off: ``kind`` is ``bwrap``, ``unshare`` or ``none`` (network); ``drop_root``: a root
    evaluator runs agents as ``nobody`` (off when ``nobody`` cannot run this Python, e.g. it lives in /root)."""

    kind: str
    prefix: tuple[str, ...] = ()
    note: str = ""
    drop_root: bool = True

    @property
    def blocks_network(self) -> bool:
        return self.kind != "none"


def _bwrap_prefix(folder: str) -> tuple[str, ...]:
    caps = ("--cap-add", "CAP_SETUID", "--cap-add", "CAP_SETGID") if os.geteuid() == 0 else ()  # to drop root
    return ("bwrap", "--die-with-parent", "--unshare-net", "--unshare-ipc", "--unshare-pid", *caps,
            "--ro-bind", "/", "/", "--dev", "/dev", "--proc", "/proc", "--tmpfs", "/tmp", "--bind", folder, folder,
            "--")


def _candidates(prefer: str) -> list[Isolation]:
    out = []
    if prefer in ("auto", "bwrap") and shutil.which("bwrap"):
        out.append(Isolation("bwrap", (), "bubblewrap: no network, read-only file system but the agent folder"))
    if prefer in ("auto", "unshare") and shutil.which("unshare"):
        prefix = ("unshare", "--net") if os.geteuid() == 0 else ("unshare", "--net", "--map-root-user")
        out.append(Isolation("unshare", (*prefix, "--"), f"{' '.join(prefix)}: a network namespace, no devices"))
    return out


def _works(isolation: Isolation) -> bool:
    """Whether the whole chain (isolation, limits, user switch) runs this Python here."""
    with tempfile.TemporaryDirectory(prefix="proxybench-probe-") as folder:
        os.chmod(folder, 0o755)
        try:
            argv = confine(["python3", "-c", "pass"], folder, Limits(), isolation)
            return subprocess.run(argv, capture_output=True, timeout=30).returncode == 0
        except (OSError, subprocess.SubprocessError, SandboxError):
            return False


def _working(candidate: Isolation) -> Isolation | None:
    """The candidate as it works here: as ``nobody`` if possible, else keeping the evaluator's user."""
    if os.geteuid() == 0 and _works(candidate):
        return candidate
    kept = dataclasses.replace(candidate, drop_root=False)
    if _works(kept):
        if os.geteuid() == 0:
            log.warning("user 'nobody' cannot run %s here: agents run as root (inside %s)", sys.executable,
                        candidate.kind)
            return dataclasses.replace(kept, note=kept.note + "; agents run as root (nobody cannot run Python)")
        return kept
    return None


@functools.cache
def detect_isolation(prefer: str = "auto") -> Isolation:
    """The network isolation that works on this host, probed once by running ``true`` through it.

    ``prefer``: ``auto`` (bwrap, then unshare, then none) or one kind; ``none`` when nothing works.
    """
    if prefer not in ISOLATIONS:
        raise ValueError(f"sandbox must be one of {', '.join(ISOLATIONS)}, got {prefer!r}")
    for candidate in _candidates(prefer):
        found = _working(candidate)
        if found is not None:
            return found
        log.warning("%s is installed but does not work here (user namespaces refused?)", candidate.kind)
    note = ("network isolation switched off (--sandbox none)" if prefer == "none"
            else "no working bwrap or unshare: agents CAN reach the network")
    return _working(Isolation("none", (), note)) or Isolation("none", (), note, drop_root=False)


def _drop_to() -> tuple[int, int] | None:
    """(uid, gid) of ``nobody`` when this evaluator runs as root, else None (nothing to drop)."""
    if os.geteuid() != 0:
        return None
    try:
        pw = pwd.getpwnam("nobody")
        return pw.pw_uid, pw.pw_gid
    except KeyError:
        return _NOBODY, _NOBODY


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


def _agent_env(folder: str) -> dict[str, str]:
    tmp = os.path.join(folder, ".tmp")
    env = {"PATH": os.environ.get("PATH", "/usr/local/bin:/usr/bin:/bin"), "HOME": folder, "TMPDIR": tmp,
           "LANG": "C.UTF-8", "PYTHONUNBUFFERED": "1", "PYTHONDONTWRITEBYTECODE": "1",
           "MPLCONFIGDIR": os.path.join(tmp, "mpl")}
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        env[var] = "1"  # one evaluator, one core: the agent should not start a thread per core
    return env


def confine(argv: list[str], folder: str | Path, limits: Limits, isolation: Isolation, *,
            extra_env: dict[str, str] | None = None) -> list[str]:
    """The command line that runs ``argv`` in ``folder`` inside the sandbox.

    ``python`` / ``python3`` as ``argv[0]`` become this interpreter. ``folder`` must exist; when the
    evaluator is root and ``isolation.drop_root``, it is handed to ``nobody`` (who then runs the agent).
    """
    folder = str(Path(folder).resolve())
    argv = list(argv)
    if argv and argv[0] in ("python", "python3"):
        argv[0] = sys.executable
    owner = _drop_to() if isolation.drop_root else None
    tmp = Path(folder, ".tmp")
    tmp.mkdir(exist_ok=True)
    if owner is not None:
        for parent in Path(folder).parents:
            if not parent.stat().st_mode & 0o001:
                raise SandboxError(f"{parent} is not searchable by other users, so the unprivileged agent user "
                                   f"cannot reach {folder}; choose a work dir under /tmp or chmod o+x {parent}")
        for path in [Path(folder), *Path(folder).rglob("*")]:
            os.chown(path, *owner, follow_symlinks=False)
    nproc = _tasks_of(owner[0] if owner else os.getuid()) + limits.processes
    shim = [sys.executable, "-I", "-S", str(_SHIM), "--cwd", folder, "--cpu", str(limits.cpu_seconds),
            "--memory", str(limits.memory_bytes), "--fsize", str(limits.file_bytes), "--nproc", str(nproc),
            "--core", "0"]
    if owner is not None:
        shim += ["--uid", str(owner[0]), "--gid", str(owner[1])]
    if isolation.kind != "bwrap":
        shim += ["--parent", str(os.getpid())]  # unshare execs: the shim's parent is this process
    for key, value in {**_agent_env(folder), **(extra_env or {})}.items():
        shim += ["--env", f"{key}={value}"]
    prefix = list(_bwrap_prefix(folder)) if isolation.kind == "bwrap" else list(isolation.prefix)
    return [*prefix, *shim, "--", *argv]


def prepare_agent(archive: bytes, sha256: str, dest: Path, *, max_bytes: int | None = None) -> AgentManifest:
    """Check an agent archive against its expected hash and :func:`check_archive`, unpack it into ``dest``.

    Raises :class:`PackageError` naming what is wrong (the submission's fault), or
    :class:`ArchiveMismatch`.
    """
    got = hashlib.sha256(archive).hexdigest()
    if got != sha256:
        raise ArchiveMismatch(f"archive hash is {got}, not the submitted {sha256}: refusing to run it")
    if max_bytes is not None and len(archive) > max_bytes:
        raise PackageError(f"archive is {len(archive)} bytes; this evaluator accepts at most {max_bytes}")
    return extract_archive(archive, dest)


def agent_command(manifest: AgentManifest, folder: Path, limits: Limits, isolation: Isolation) -> str:
    """The sandboxed command (one string, as ``AgentSpec.command`` takes it) of an unpacked package."""
    return shlex.join(confine(list(manifest.command), folder, limits, isolation))
