"""Issue 38 item 3 (trust, round 3): other local users. Per-run files live in a private folder of ours (0700,
checked, no links followed), the DTPS port lock is waited for with a deadline that names its holder, ``--cpus auto``
survives planted files, and nothing a started program forks (``setsid`` daemons) outlives its run.

"Another user" is played by root's ``chown`` to the agent user's id (or ``nobody``), and once by the agent user
itself (``setpriv``), where the tests run as root, as CI does; the subreaper is also shown killing a daemon of the
agent user, the unprivileged user the sandbox runs agents as.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.dtps.link import PortLock, PortLockError
from proxybench.gym.cpus import CpuError, claim_cpu
from proxybench.private import PrivateFileError, hold_lock, lock_holder, open_private, user_folder
from proxybench.protocol import AgentProcess
from proxybench.protocol.transport import Launch
from support.sandbox import AGENT_USER_GROUP, processes_left, require_safe_sandbox

ROOT = os.geteuid() == 0
#: who plays "another local user" (root may chown to anyone)
OTHER_UID = 65534


def _foreign(path: Path) -> None:
    """Make ``path`` another user's (a link itself, not its target)."""
    if not ROOT:
        pytest.skip("playing another user needs root (CI runs these tests as root)")
    os.lchown(path, OTHER_UID, OTHER_UID)


@pytest.fixture
def shared(tmp_path: Path) -> Path:
    """A shared temporary folder like /tmp: everyone may create there (sticky)."""
    base = tmp_path / "shared"
    base.mkdir()
    base.chmod(0o1777)
    return base


# -- the private folder ------------------------------------------------------------------------------------


def test_the_user_folder_is_made_0700_and_ours(shared: Path) -> None:
    folder = user_folder("dtps", base=shared)
    for path in (folder, folder.parent):
        info = path.lstat()
        assert stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid() and stat.S_IMODE(info.st_mode) == 0o700
    assert folder == shared / f"proxybench-{os.getuid()}" / "dtps"
    assert user_folder("dtps", base=shared) == folder  # checked again, still fine


def test_a_link_planted_where_the_user_folder_goes_is_refused_and_not_followed(shared: Path, tmp_path: Path) -> None:
    victim = tmp_path / "victim"
    victim.mkdir()
    (shared / f"proxybench-{os.getuid()}").symlink_to(victim)
    with pytest.raises(PrivateFileError, match="is a symbolic link: refused"):
        user_folder("dtps", base=shared)
    assert list(victim.iterdir()) == []


@pytest.mark.parametrize("planted", ["file", "open folder", "foreign folder"])
def test_a_planted_user_folder_is_refused_naming_it(shared: Path, planted: str) -> None:
    path = shared / f"proxybench-{os.getuid()}"
    if planted == "file":
        path.write_text("junk")
        why = "is not a folder"
    else:
        path.mkdir()
        path.chmod(0o777)
        why = "others may write there"
        if planted == "foreign folder":
            _foreign(path)
            why = f"belongs to user id {OTHER_UID}"
    with pytest.raises(PrivateFileError, match=why) as exc:
        user_folder(base=shared)
    assert str(path) in str(exc.value) and "\n" not in str(exc.value)


@AGENT_USER_GROUP
def test_a_user_folder_planted_by_the_agent_user_itself_is_refused() -> None:
    """The real thing: another account makes the folder first (setpriv to the sandbox's agent user), in a shared
    sticky folder it can reach."""
    if not ROOT:
        pytest.skip("switching to the agent user needs root (CI runs these tests as root)")
    isolation = require_safe_sandbox()
    shared = Path(tempfile.mkdtemp(prefix="proxybench-test-shared-", dir="/tmp"))
    try:
        shared.chmod(0o1777)
        path = shared / f"proxybench-{os.getuid()}"
        subprocess.run(["setpriv", f"--reuid={isolation.uid}", f"--regid={isolation.gid}", "--clear-groups", "mkdir",
                        "-m", "700", str(path)], check=True)
        assert path.stat().st_uid == isolation.uid
        with pytest.raises(PrivateFileError, match=f"belongs to user id {isolation.uid}"):
            user_folder("dtps", base=shared)
    finally:
        shutil.rmtree(shared)


# -- the port lock -----------------------------------------------------------------------------------------


@pytest.mark.parametrize("victim_exists", [False, True])
def test_a_link_at_the_port_lock_is_refused_without_touching_its_target(tmp_path: Path, victim_exists: bool) -> None:
    folder = user_folder("dtps", base=tmp_path)
    victim = tmp_path / "victim.txt"
    if victim_exists:
        victim.write_text("keep me")
    (folder / "port-7501.lock").symlink_to(victim)
    with pytest.raises(PortLockError, match=r"port-7501\.lock: Too many levels of symbolic links: refused"):
        PortLock(7501, folder=folder).acquire(timeout=0.1)
    assert (victim.read_text() == "keep me") if victim_exists else not victim.exists()


def test_a_foreign_file_or_fifo_at_the_port_lock_is_refused(tmp_path: Path) -> None:
    folder = user_folder("dtps", base=tmp_path)
    os.mkfifo(folder / "port-7502.lock")  # never opened for a blocking read: no hang
    with pytest.raises(PortLockError, match="is not a regular file: refused"):
        PortLock(7502, folder=folder).acquire(timeout=0.1)
    (folder / "port-7503.lock").write_text("someone else's")
    _foreign(folder / "port-7503.lock")
    with pytest.raises(PortLockError, match=f"belongs to user id {OTHER_UID}"):
        PortLock(7503, folder=folder).acquire(timeout=0.1)


HOLD = """
import sys, time
from pathlib import Path
from proxybench.private import hold_lock
hold_lock(Path(sys.argv[1]), timeout=5)
print("held", flush=True)
time.sleep(60)
"""


def test_waiting_for_the_port_lock_ends_at_its_deadline_naming_the_holder(tmp_path: Path) -> None:
    folder = user_folder("dtps", base=tmp_path)
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(folder / "port-7504.lock")], stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        lock = PortLock(7504, folder=folder)
        with pytest.raises(PortLockError) as exc:
            lock.acquire(timeout=0.3)
        message = str(exc.value)
        assert f"by pid {holder.pid}: python" in message and "port-7504.lock" in message and "\n" not in message
        assert "after 0.3 s" in message
    finally:
        holder.kill()
        holder.wait()
    lock.acquire(timeout=5)  # the kernel dropped the dead holder's lock
    assert lock.fd is not None and lock_holder(lock.fd).startswith(f"pid {os.getpid()}:")
    lock.release()


def test_garbage_in_a_lock_file_names_nobody(tmp_path: Path) -> None:
    path = user_folder(base=tmp_path) / "x.lock"
    path.write_bytes(b"\x00\x1b[31m" + os.urandom(4000))
    fd = open_private(path)
    assert lock_holder(fd).isprintable() and len(lock_holder(fd)) <= 200
    os.close(fd)
    fd = hold_lock(path, timeout=0.1)  # ours, a regular file: its content does not matter
    os.close(fd)


# -- --cpus auto -------------------------------------------------------------------------------------------


def test_cpus_auto_skips_planted_lock_files(tmp_path: Path) -> None:
    mine = sorted(os.sched_getaffinity(0))
    if len(mine) < 2:
        assert claim_cpu(user_folder("gym-cpus", base=tmp_path)) is None
        return
    folder = user_folder("gym-cpus", base=tmp_path)
    (folder / f"cpu{mine[-1]}.lock").mkdir()  # a folder where a lock file goes
    victim = tmp_path / "victim"
    victim.write_text("keep")
    if len(mine) > 2:
        (folder / f"cpu{mine[-2]}.lock").symlink_to(victim)
    garbage = folder / f"cpu{mine[0]}.lock"
    garbage.write_bytes(os.urandom(300))
    claim = claim_cpu(folder)
    assert claim is not None and claim.cpu not in (mine[-1], *(mine[-2:-1] if len(mine) > 2 else ()))
    assert victim.read_text() == "keep"
    claim.release()


def test_gym_serve_cpus_auto_with_a_planted_lock_folder_is_one_line(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    (tmp_path / f"proxybench-{os.getuid()}").write_text("planted")
    res = CliRunner().invoke(app, ["gym", "serve", "--cpus", "auto", "--path", "/nonexistent"])
    if len(os.sched_getaffinity(0)) < 2:
        return  # one CPU: nothing is claimed, the folder never made
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "--cpus auto:" in res.output and "is not a folder: refused" in res.output
    with pytest.raises(CpuError):
        claim_cpu()


# -- nothing a program forks outlives it --------------------------------------------------------------------


def _with(marker: str) -> list[int]:
    """Process ids whose command line holds ``marker``."""
    out = []
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            try:
                with open(f"/proc/{entry.name}/cmdline", "rb") as f:
                    if marker.encode() in f.read():
                        out.append(int(entry.name))
            except OSError:
                continue
    return out


def _gone(marker: str, timeout: float = 10.0) -> list[int]:
    """:func:`_with` once nothing is left or ``timeout`` has passed (bounded; no speed is asserted)."""
    deadline = time.monotonic() + timeout
    while (left := _with(marker)) and time.monotonic() < deadline:
        time.sleep(0.05)
    return left


def _daemon(seconds: str) -> str:
    """Shell words that double-fork a ``setsid`` sleeper (out of the program's group and session)."""
    return f"(setsid sleep {seconds} </dev/null >/dev/null 2>&1 &)"


def _state(proc: Launch) -> str:
    """The launcher's exit status, its process tree and the program's stderr: what a failure report needs (this
    test failed once in CI, on a machine we cannot see, and said only that)."""
    from proxybench.protocol._subreaper import descendants

    tree = []
    for pid in [proc.proc.pid, *descendants(proc.proc.pid)]:
        with contextlib.suppress(OSError), open(f"/proc/{pid}/cmdline", "rb") as f:
            words = f.read().replace(b"\0", b" ").decode(errors="replace")
            tree.append(f"{pid} {words[:100]}")
    return f"launcher status {proc.proc.poll()}, tree {tree}, stderr {proc.stderr.tail()}"


def _sleep_arg() -> str:
    return f"{3000 + uuid.uuid4().int % 1000}.{uuid.uuid4().int % 10**6:06d}"


def test_a_setsid_daemon_of_a_program_that_ends_is_killed() -> None:
    arg = _sleep_arg()
    proc = Launch(["sh", "-c", f"{_daemon(arg)}; echo forked >&2"], transport="none")
    assert proc.wait_exit(30.0)
    assert proc.terminate() == 0  # the program's own exit status
    assert proc.stderr.finish() == ["forked"]
    assert _gone(f"sleep\0{arg}") == []


@pytest.mark.parametrize("term_first", [True, False])
def test_a_setsid_daemon_of_a_program_that_is_stopped_is_killed(term_first: bool) -> None:
    arg = _sleep_arg()
    proc = Launch(["sh", "-c", f"trap '' TERM; {_daemon(arg)}; echo forked >&2; exec sleep 600"], transport="none")
    deadline = time.monotonic() + 30
    while not _with(f"sleep\0{arg}") and time.monotonic() < deadline:
        time.sleep(0.02)
    assert _with(f"sleep\0{arg}"), f"the daemon never started: {_state(proc)}"
    proc.terminate(0.0, term_first=term_first)
    assert proc.returncode is not None
    assert _gone(f"sleep\0{arg}") == []
    with pytest.raises(ChildProcessError):
        os.waitpid(proc.pid, os.WNOHANG)


def test_a_program_that_cannot_be_executed_is_the_same_oserror() -> None:
    with pytest.raises(FileNotFoundError):
        Launch(["/nonexistent/program"], transport="none")


def test_the_program_pid_is_the_programs_and_its_signal_is_its_exit_code() -> None:
    proc = Launch(["sleep", "600"], transport="none")
    assert proc.pid != proc.proc.pid  # the launcher's child
    os.kill(proc.pid, signal.SIGKILL)
    assert proc.wait_exit(30.0) and proc.terminate() == -signal.SIGKILL


def test_a_node_agent_that_leaves_a_daemon_leaves_no_process_after_the_run() -> None:
    arg = _sleep_arg()
    node = Path(__file__).resolve().parent / "protocol_agents" / "pixel_agent.py"
    cmd = f"{_daemon(arg)}; exec {sys.executable} {node} pixel"
    with AgentProcess(cmd, init_timeout=30) as proc:
        proc.seed(1)
        assert _with(f"sleep\0{arg}"), "the node's daemon is not running"
    assert proc.returncode == 0
    assert _gone(f"sleep\0{arg}") == []


@AGENT_USER_GROUP
def test_a_daemon_of_the_agent_user_is_killed_too() -> None:
    """A program running as the unprivileged agent user (as sandboxed agents do) that double-forks a setsid sleeper:
    the launcher (the caller's user) kills the daemon, and no process of the agent user is left."""
    if not ROOT:
        pytest.skip("switching to the agent user needs root (CI runs these tests as root)")
    isolation = require_safe_sandbox()
    arg = _sleep_arg()
    proc = Launch(["setpriv", f"--reuid={isolation.uid}", f"--regid={isolation.gid}", "--clear-groups", "sh", "-c",
                   f"{_daemon(arg)}; echo forked >&2"], transport="none", cwd="/")
    assert proc.wait_exit(30.0) and proc.terminate() == 0
    assert proc.stderr.finish() == ["forked"]
    assert _gone(f"sleep\0{arg}") == []
    assert processes_left(isolation.uid, 5) == []
