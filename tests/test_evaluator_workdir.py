"""The evaluator's work folder is its user's alone: another local account can neither own it, loosen it,
plant links in it nor swap a job folder for one of its own (issue 23: a planted ``.lock`` link truncated a
root-owned file; swapped job folders leaked the hidden test seed of every job)."""

from __future__ import annotations

import os
import pwd
import stat
import tempfile
import threading
import time
from pathlib import Path

import pytest

from proxybench.evaluator import Evaluator, EvaluatorConfig
from support.sandbox import AGENT_USER_GROUP

pytestmark = [pytest.mark.skipif(os.geteuid() != 0, reason="planting another user's files needs root"),
              AGENT_USER_GROUP]  # an evaluator probes the sandbox as the agent user when it starts
OTHER = pwd.getpwnam("nobody")


def _evaluator(work: Path) -> Evaluator:
    return Evaluator("http://127.0.0.1:9", "pbt_unused", EvaluatorConfig(name="e", work_dir=work))


def _private(path: Path) -> Path:
    path.mkdir(mode=0o700)
    path.chmod(0o700)
    return path


def test_the_default_work_folder_is_not_under_a_world_writable_folder(monkeypatch, tmp_path: Path) -> None:
    from proxybench.evaluator.workdir import default_work_dir

    assert default_work_dir("lab-1") == Path("/var/lib/proxybench-evaluator/lab-1")  # root
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("XDG_STATE_HOME", raising=False)
    assert default_work_dir("lab-1") == tmp_path / ".local/state/proxybench-evaluator/lab-1"
    assert not str(default_work_dir("lab-1")).startswith(tempfile.gettempdir() + "/proxybench")


def test_a_new_work_folder_is_made_private(tmp_path: Path) -> None:
    ev = _evaluator(tmp_path / "a" / "work")
    try:
        assert stat.S_IMODE((tmp_path / "a" / "work").stat().st_mode) == 0o700
        assert stat.S_IMODE((tmp_path / "a").stat().st_mode) == 0o700
    finally:
        ev.close()


@pytest.mark.parametrize(("setup", "says"), [
    ("other owner", "belongs to 'nobody'"),
    ("mode 755", "has mode 0755; it must be 0700"),
    ("folder above of another user", "above the work folder) belongs to 'nobody'"),
    ("folder above writable by all", "above the work folder) is writable by other users"),
    ("link of another user on the way", "is a link made by 'nobody'"),
])
def test_an_unsafe_work_folder_is_refused(tmp_path: Path, setup: str, says: str) -> None:
    work = tmp_path / "work"
    if setup == "other owner":
        _private(work)
        os.chown(work, OTHER.pw_uid, OTHER.pw_gid)
    elif setup == "mode 755":
        work.mkdir()
        work.chmod(0o755)
    elif setup == "folder above of another user":
        above = tmp_path / "shared"
        above.mkdir()
        os.chown(above, OTHER.pw_uid, OTHER.pw_gid)
        work = above / "work"
    elif setup == "folder above writable by all":
        above = tmp_path / "shared"
        above.mkdir()
        above.chmod(0o777)  # no sticky bit: anyone may rename what is in it
        work = above / "work"
    else:  # a sticky /tmp-like folder where another user made the path a link to a folder of theirs
        sticky = tmp_path / "tmp"
        sticky.mkdir()
        sticky.chmod(0o1777)
        theirs = _private(tmp_path / "theirs")
        os.chown(theirs, OTHER.pw_uid, OTHER.pw_gid)
        (sticky / "proxybench-evaluator").symlink_to(theirs)
        os.lchown(sticky / "proxybench-evaluator", OTHER.pw_uid, OTHER.pw_gid)
        work = sticky / "proxybench-evaluator" / "e"
    with pytest.raises(RuntimeError) as info:
        _evaluator(work).close()
    assert says in str(info.value), str(info.value)


def test_a_planted_lock_link_truncates_nothing(tmp_path: Path) -> None:
    victim = tmp_path / "root-owned.conf"
    victim.write_text("precious\n")
    work = _private(tmp_path / "work")
    (work / ".lock").symlink_to(victim)
    with pytest.raises(RuntimeError, match="a link"):
        _evaluator(work).close()
    assert victim.read_text() == "precious\n"


def test_a_planted_spare_log_link_is_replaced_not_followed(tmp_path: Path) -> None:
    victim = tmp_path / "victim.log"
    victim.write_text("precious\n")
    work = _private(tmp_path / "work")
    (work / "spare-worker.log").symlink_to(victim)
    ev = _evaluator(work)
    worker = ev._new_worker()
    try:
        assert os.readlink(f"/proc/{worker.proc.pid}/fd/1") == str(work / "spare-worker.log")
        assert not (work / "spare-worker.log").is_symlink()
    finally:
        worker.kill()
        ev.close()
    assert victim.read_text() == "precious\n"


def test_a_job_folder_swapped_for_a_link_is_never_used(tmp_path: Path) -> None:
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    work = _private(tmp_path / "work")
    ev = _evaluator(work)
    try:
        (work / "job-7-abcdef12").symlink_to(theirs)  # planted before the job: a stale name is never reused
        job = ev.work.new_job("job-7-abcdef12")
        job.write("job.json", b'{"test_seed": 1}')
        assert not job.path.is_symlink() and stat.S_IMODE(job.path.stat().st_mode) == 0o700
        assert list(theirs.iterdir()) == []
        # swapped after it was made (only this user could, but even so): the descriptor keeps to the real one
        job.path.rename(work / "moved")
        (work / "job-7-abcdef12").symlink_to(theirs)
        job.write("evaluator.log", b"log")
        assert list(theirs.iterdir()) == [] and (work / "moved" / "evaluator.log").read_bytes() == b"log"
        with pytest.raises(OSError):
            job.write("job.json", b"again")  # files are made exclusively, never overwritten through a link
        job.close(remove=True)
        assert theirs.is_dir() and list(theirs.iterdir()) == []  # the link was removed, never followed
    finally:
        ev.close()


def _reading_its_job(worker) -> bool:
    """Whether the spare worker waits on stdin for its job: past its ``PR_SET_PDEATHSIG``, its imports done."""
    try:
        with open(f"/proc/{worker.proc.pid}/wchan") as f:
            return "pipe" in f.read()
    except OSError:
        return False


def test_a_spare_worker_outlives_the_slot_thread_that_asked_for_it(tmp_path: Path) -> None:
    """An Autolab's robots run one slot thread each and share the spare worker, so the slot that made it may end
    while another slot's job runs in it. A worker dies with the *thread* that forked it (``PR_SET_PDEATHSIG``): a
    job was killed that way (-9, no outcome) in CI. Workers are forked by the evaluator's own spawner thread."""
    ev = _evaluator(_private(tmp_path / "work"))
    made = []

    def slot() -> None:
        made.append(ev._new_worker())
        deadline = time.monotonic() + 120  # a bound, not a speed: a busy machine imports slowly
        while not _reading_its_job(made[0]) and made[0].proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)

    thread = threading.Thread(target=slot)
    thread.start()
    thread.join()
    (worker,) = made
    try:
        assert _reading_its_job(worker), "the spare never got to wait for its job"
        while os.path.exists(f"/proc/self/task/{thread.native_id}"):  # the thread's end is when the kernel acts
            time.sleep(0.01)
        worker.proc.stdin.close()  # no job: a live spare then exits 0; one its thread's end killed has -9
        assert worker.proc.wait(timeout=60) == 0
    finally:
        worker.kill()
        ev.close()
