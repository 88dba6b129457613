"""Several robots in one Autolab (issue 36 item 3): the Autolab evaluator runs one job per free robot at once, and
never a job on a busy robot. The robots do not yet share a world (each is the ego of its own; docs/autolab.md).

The server and package helpers are test_evaluator's and test_autolab_evaluator's (one short episode).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from proxybench.autolab.lab import Lab

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

from support.dtps import sdk
from support.sandbox import AGENT_USER_GROUP, require_safe_sandbox
from test_autolab_evaluator import BENCH, sdk_package
from test_evaluator import Served, evaluator, served, the_job  # noqa: F401 - served: test_evaluator's fixture

LAB2 = """\
format: proxybench-lab/1
name: two-robots
map: loop_3x3
robots:
  - {name: db1, virtual: true}
  - {name: db2, virtual: true}
watchtowers: {layout: auto}
reset: {mode: teleport}
"""


def _lab(robots: list[dict]) -> Lab:
    return Lab.model_validate({"map": "loop_3x3", "robots": robots, "watchtowers": {"layout": "auto"},
                               "reset": {"mode": "operator"}})


def test_a_robot_is_held_by_one_job_at_a_time_and_every_kind_of_robot_is_offered() -> None:
    from proxybench.evaluator.robots import RobotLeases

    leases = RobotLeases(_lab([{"name": "db1", "virtual": True}, {"name": "cam", "dtps": "10.0.0.2/cam"},
                               {"name": "db2", "virtual": True}]))
    assert leases.robots == ("db1", "cam", "db2") and len(leases) == 3  # a lab's DTPS robot is driven too
    assert [leases.take(), leases.take(), leases.take(), leases.take()] == ["db1", "cam", "db2", None]
    assert leases.busy == ["db1", "cam", "db2"]
    leases.give_back("db1")
    assert leases.busy == ["cam", "db2"] and leases.take() == "db1"
    leases.give_back("db2")
    with pytest.raises(RuntimeError, match="robot 'db2' is not held"):
        leases.give_back("db2")
    leases.close()  # the evaluator's end frees what it still holds
    assert leases.busy == []
    assert RobotLeases(_lab([{"name": "cam", "dtps": "10.0.0.2/cam"}])).robots == ("cam",)


def test_threads_racing_for_robots_never_share_one() -> None:
    from proxybench.evaluator.robots import RobotLeases

    leases = RobotLeases(_lab([{"name": f"db{k}", "virtual": True} for k in range(3)]))
    held: list[str] = []
    clash: list[str] = []
    lock = threading.Lock()

    def use() -> None:
        for _ in range(200):
            name = leases.take()
            if name is None:
                continue
            with lock:
                if name in held:
                    clash.append(name)
                held.append(name)
            with lock:
                held.remove(name)
            leases.give_back(name)

    threads = [threading.Thread(target=use) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert clash == [] and leases.busy == []


HOLDER = """\
import sys
from proxybench.autolab.lab import Lab
from pathlib import Path
from proxybench.evaluator.robots import RobotLeases
lab = Lab.model_validate({"name": sys.argv[1], "map": "loop_3x3", "robots": [{"name": "db1", "virtual": True},
                          {"name": "db2", "virtual": True}], "watchtowers": {"layout": "auto"}})
leases = RobotLeases(lab, None if sys.argv[2] == "-" else Path(sys.argv[2]))
print(",".join(filter(None, [leases.take() for _ in range(int(sys.argv[3]))])), flush=True)
sys.stdin.read()  # hold them until killed
"""


def _holder(lab: str, lock_dir: Path | None, robots: int):
    """Another evaluator process of this user holding ``robots`` of lab ``lab``'s robots (db1, db2) until killed."""
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-c", HOLDER, lab, str(lock_dir or "-"), str(robots)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    held = proc.stdout.readline().strip()
    assert held, "the holder process took no robot"
    return proc, held


def test_a_robot_held_by_another_evaluator_process_is_not_taken_until_its_holder_dies(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    from proxybench.evaluator.robots import RobotLeases

    locks = tmp_path / "locks"
    proc, held = _holder("lab", locks, 1)
    try:
        assert held == "db1"
        leases = RobotLeases(_lab([{"name": "db1", "virtual": True}, {"name": "db2", "virtual": True}]), locks)
        with caplog.at_level("INFO", logger="proxybench.evaluator"):
            assert leases.take() == "db2"  # only the robot the other process left free
            assert leases.take() is None
        assert list(leases.elsewhere) == ["db1"] and f"pid {proc.pid}" in leases.elsewhere["db1"]
        assert f"robot(s) held by another evaluator on this machine: db1 (pid {proc.pid}" in caplog.text
        assert "no robot free: leasing nothing until one is" in caplog.text
    finally:
        proc.kill()  # -9: its lock dies with it, nothing to clean up
        proc.wait()
    caplog.clear()
    with caplog.at_level("INFO", logger="proxybench.evaluator"):
        assert leases.take() == "db1"
    assert "robot(s) db1 free again" in caplog.text and leases.busy == ["db1", "db2"]
    leases.close()


def test_a_link_planted_where_a_robots_lock_goes_is_refused_never_followed(tmp_path: Path) -> None:
    from proxybench.evaluator.robots import RobotLeases
    from proxybench.private import PrivateFileError, make_private_folder

    locks = make_private_folder(tmp_path / "locks")
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (locks / "db1.lock").symlink_to(victim)
    leases = RobotLeases(_lab([{"name": "db1", "virtual": True}]), locks)
    with pytest.raises(PrivateFileError, match=r"db1\.lock: .*refused"):
        leases.take()
    assert victim.read_text() == "precious" and leases.busy == []


def test_a_second_evaluator_with_the_same_lab_leases_nothing_while_another_holds_its_robots(
        served: Served, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:  # noqa: F811
    (sub,) = _submit(served, tmp_path, ["lane"])
    proc, held = _holder("two-robots", None, 2)  # the locks of this user (this test process's folder)
    try:
        assert held == "db1,db2"
        ev = _lab_evaluator(served, tmp_path)
        try:
            with caplog.at_level("INFO", logger="proxybench.evaluator"):
                assert ev.take_one() is None  # no free robot on this machine: the job is not even leased
            assert "robot(s) held by another evaluator on this machine: db1" in caplog.text
            job, results = the_job(served, sub["id"])
            assert job["status"] == "queued" and results == []
            assert "leased" not in [e["kind"] for e in served.admin.get(f"/jobs/{job['id']}")["events"]]
        finally:
            ev.close()
    finally:
        proc.kill()
        proc.wait()


def test_a_worker_job_names_a_robot_of_its_lab() -> None:
    from pydantic import ValidationError

    from support.jobs import worker_job

    lab = _lab([{"name": "db1", "virtual": True}, {"name": "db2", "virtual": True}])
    assert worker_job(autolab=lab, autolab_robot="db2").autolab_robot == "db2"
    with pytest.raises(ValidationError, match="autolab_robot: lab 'lab' has no robot 'db9' \\(it has db1, db2\\)"):
        worker_job(autolab=lab, autolab_robot="db9")
    with pytest.raises(ValidationError, match="autolab_robot: a robot is given but no lab"):
        worker_job(autolab_robot="db1")


def test_the_console_draws_a_bar_per_running_job(monkeypatch: pytest.MonkeyPatch) -> None:
    import io

    from rich.console import Console

    import proxybench.cli.evaluator as cli
    from proxybench.contract import Lease, LeasedBenchmark, LeasedSubmission

    out = io.StringIO()
    monkeypatch.setattr(cli, "console", Console(file=out, force_terminal=True, width=120))
    reporter = cli._reporter()

    def lease(job: int) -> Lease:
        return Lease(job_id=job, lease_id="ab", lease_seconds=5.0,
                     submission=LeasedSubmission(id=job, label=f"lane-{job}", agent="pid"),
                     benchmark=LeasedBenchmark(name="autolab_tiny", version=1, spec_yaml="{}"))

    a, b = lease(1), lease(2)
    reporter.job_started(a)
    reporter.job_started(b)  # a second job while the first runs: one live display, a bar each
    assert len(reporter.tasks) == 2
    reporter.job_progress(a, {"phase": "validation", "done": 1, "total": 2})
    reporter.job_progress(b, {"phase": "test", "done": 0, "total": 3})
    bars = {t.description: (t.completed, t.total) for t in reporter.progress.tasks}
    assert bars == {"job 1: validation episodes": (1, 2), "job 2: test episodes": (0, 3)}
    reporter.job_finished(a, "success", "done")
    assert [t.description for t in reporter.progress.tasks] == ["job 2: test episodes"]
    reporter.job_finished(b, "failed", "crashed")
    assert reporter.progress is None and reporter.tasks == {}
    text = out.getvalue()
    assert "job 1: " in text and "success" in text and "job 2: " in text and "failed" in text


def test_each_robot_is_localised_under_its_own_worlds_ego_tag() -> None:
    from proxybench.domain.apriltags import ROOF_TAG_BASE
    from proxybench.evaluator.autolab import world_tags

    assert world_tags("db2") == {ROOF_TAG_BASE: "db2"}


def _submit(srv: Served, tmp_path: Path, labels: list[str]) -> list[dict]:
    srv.admin.post("/benchmarks", {"yaml": BENCH, "features": ["autolab"], "hidden_split": False})
    archive = tmp_path / "agent.zip"
    archive.write_bytes(sdk_package())
    return [srv.developer.submit_archive(archive, label, benchmark="autolab_tiny") for label in labels]


def _lab_evaluator(srv: Served, tmp_path: Path):
    from proxybench.autolab.lab import load_lab

    tmp_path.mkdir(exist_ok=True)
    (tmp_path / "lab.yaml").write_text(LAB2)
    return evaluator(srv, tmp_path, name="lab", video=False, features=("sim", "autolab"),
                     autolab=load_lab(tmp_path / "lab.yaml"))


def test_with_every_robot_busy_the_evaluator_leases_nothing(served: Served, tmp_path: Path) -> None:  # noqa: F811
    (sub,) = _submit(served, tmp_path, ["lane"])
    ev = _lab_evaluator(served, tmp_path)
    try:
        assert ev.robots.take() == "db1" and ev.robots.take() == "db2"
        assert ev.take_one() is None  # no free robot: the job is not even leased
        job, results = the_job(served, sub["id"])
        assert job["status"] == "queued" and results == []
        assert "leased" not in [e["kind"] for e in served.admin.get(f"/jobs/{job['id']}")["events"]]
    finally:
        ev.close()


def test_without_the_safe_sandbox_an_autolab_runs_one_job_at_a_time(served: Served,  # noqa: F811
                                                                    tmp_path: Path) -> None:
    from proxybench.evaluator.loop import Reporter
    from proxybench.evaluator.sandbox import Isolation

    class Notes(Reporter):
        def __init__(self) -> None:
            self.lines: list[str] = []

        def note(self, text: str) -> None:
            self.lines.append(text)

    for isolation, says in ((Isolation("bwrap", "agent", uid=4242, gid=4242, safe=True), "up to 2 jobs at once"),
                            (Isolation("none", "me", note="unsafe"), "one job at a time: without the safe sandbox")):
        ev = _lab_evaluator(served, tmp_path / isolation.kind)
        ev.isolation, ev.reporter = isolation, Notes()
        assert ev.run(once=True) == 0  # nothing queued
        assert any(says in line for line in ev.reporter.lines), ev.reporter.lines


def test_an_error_in_one_robots_loop_stops_the_evaluator_and_is_raised(served: Served,  # noqa: F811
                                                                      tmp_path: Path) -> None:
    from proxybench.autolab.lab import load_lab
    from proxybench.client import ServerError
    from proxybench.evaluator.loop import Evaluator, EvaluatorConfig
    from proxybench.evaluator.sandbox import Isolation

    (tmp_path / "lab.yaml").write_text(LAB2)
    cfg = EvaluatorConfig(name="lab", work_dir=tmp_path / "work", poll=0.2, features=("sim", "autolab"),
                          autolab=load_lab(tmp_path / "lab.yaml"))
    ev = Evaluator(served.url, "not-a-token", cfg)
    ev.isolation = Isolation("bwrap", "agent", uid=4242, gid=4242, safe=True)  # two loops, whatever this host has
    with pytest.raises(ServerError) as info:
        ev.run()  # not once: only the error ends it
    assert info.value.status == 401 and ev.stop_reason.startswith("a slot failed")
    assert ev.robots.busy == []


@sdk
@AGENT_USER_GROUP
def test_two_robots_evaluate_two_jobs_at_once_in_one_lab(served: Served, tmp_path: Path) -> None:  # noqa: F811
    require_safe_sandbox()
    subs = _submit(served, tmp_path, ["lane-a", "lane-b", "lane-c"])
    ev = _lab_evaluator(served, tmp_path)
    spans: dict[str, tuple[float, float]] = {}
    work = ev._work

    def timed(lease, job, heart, robot=None):  # the span of each job's worker, from the job given to its outcome
        start = time.monotonic()
        try:
            return work(lease, job, heart, robot)
        finally:
            spans[robot] = (start, time.monotonic())

    ev._work = timed
    assert ev.run(once=True) == 2  # one lease attempt per robot: two jobs at once, the third waits for a robot
    assert sorted(spans) == ["db1", "db2"] and ev.robots.busy == []  # each robot given back after its job
    (a0, a1), (b0, b1) = spans["db1"], spans["db2"]
    assert a0 < b1 and b0 < a1, spans  # both workers ran at the same time
    done = {}
    for sub in subs:
        job, results = the_job(served, sub["id"])
        if job["status"] == "queued":
            assert results == []
            continue
        (result,) = results
        assert job["status"] == "success", result["message"]
        report = result["public_report"]
        assert report["measured_by"] == "watchtowers" and report["lab"] == "two-robots"
        assert report["localization_median_error_m"] <= 0.02
        assert result["public_scores"]["survival_time_median"] == 3.0
        done[report["robot"]] = sub["id"]
    assert sorted(done) == ["db1", "db2"]  # one job on each robot, never two on one
    assert len(served.developer.leaderboard("autolab_tiny")["rows"]) == 2
