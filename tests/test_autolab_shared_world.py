"""An Autolab whose virtual robots share one world (issue 36 item 3, ``lab.yaml``'s ``world: shared``): two SDK jobs
at once on one floor, each robot localised under its own roof tag from watchtowers that see both, each scored; the
lab description and the worker's job refuse what a shared world cannot be.

The server and package helpers are test_evaluator's and test_autolab_evaluator's (one short episode).
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

from support.dtps import sdk
from support.sandbox import AGENT_USER_GROUP, require_safe_sandbox
from test_autolab_evaluator import BENCH, sdk_package
from test_evaluator import Served, evaluator, served, the_job  # noqa: F401 - served: test_evaluator's fixture

LAB_SHARED = """\
format: proxybench-lab/1
name: one-floor
map: loop_3x3
robots:
  - {name: db1, virtual: true, roof_tag: 420}
  - {name: db2, virtual: true, roof_tag: 421}
watchtowers: {layout: auto}
reset: {mode: teleport}
world: shared
"""


def test_a_shared_world_needs_simulated_watchtowers_and_a_job_names_it_only_for_such_a_lab() -> None:
    from pydantic import ValidationError

    from proxybench.autolab.lab import Lab
    from proxybench.evaluator.lab_world import WorldAddress, world_spec
    from support.jobs import worker_job

    with pytest.raises(ValidationError, match="world: a shared world's watchtowers are simulated"):
        Lab.model_validate({"map": "loop_3x3", "robots": [{"name": "db1", "virtual": True}], "world": "shared",
                            "watchtowers": {"streams": [{"name": "wt1", "dtps": "10.0.0.3/wt1",
                                                         "calibration": "/x.yaml"}]}})
    with pytest.raises(ValidationError, match=r"watchtowers\.serve must be files"):
        Lab.model_validate({"map": "loop_3x3", "robots": [{"name": "db1", "virtual": True}], "world": "shared",
                            "watchtowers": {"layout": "auto", "serve": "dtps"}})
    lab = Lab.model_validate({"map": "loop_3x3", "robots": [{"name": "db1", "virtual": True, "roof_tag": 420},
                                                            {"name": "db2", "virtual": True}],
                              "watchtowers": {"layout": "auto"}, "world": "shared"})
    spec = world_spec(lab)
    assert spec.robots == ("db1", "db2") and spec.roof_tags == (420, 401) and spec.streams.cameras
    address = WorldAddress(path="/tmp/x.sock", key="00")
    assert worker_job(autolab=lab, autolab_robot="db2", lab_world=address).lab_world == address
    with pytest.raises(ValidationError, match="lab_world: given for a job whose lab"):
        worker_job(autolab=lab.model_copy(update={"world": "own"}), lab_world=address)


def _submit(srv: Served, tmp_path: Path, labels: list[str]) -> list[dict]:
    srv.admin.post("/benchmarks", {"yaml": BENCH, "features": ["autolab"], "hidden_split": False})
    archive = tmp_path / "agent.zip"
    archive.write_bytes(sdk_package())
    return [srv.developer.submit_archive(archive, label, benchmark="autolab_tiny") for label in labels]


@sdk
@AGENT_USER_GROUP
def test_two_sdk_jobs_run_at_once_in_one_shared_world(served: Served, tmp_path: Path) -> None:  # noqa: F811
    """Both jobs' episodes start on the same start pose (one benchmark): the second robot's start waits until the
    first has driven off it, then both drive on one floor, each localised under its own roof tag."""
    from proxybench.autolab.lab import load_lab

    require_safe_sandbox()
    subs = _submit(served, tmp_path, ["lane-a", "lane-b"])
    (tmp_path / "lab.yaml").write_text(LAB_SHARED)
    ev = evaluator(served, tmp_path, name="lab", video=False, features=("sim", "autolab"),
                   autolab=load_lab(tmp_path / "lab.yaml"))
    spans: dict[str, tuple[float, float]] = {}
    work = ev._work

    def timed(lease, job, heart, robot=None):
        start = time.monotonic()
        try:
            return work(lease, job, heart, robot)
        finally:
            spans[robot] = (start, time.monotonic())

    ev._work = timed
    assert ev.run(once=True) == 2
    assert ev.lab_world is None  # the world ended with the evaluator
    (a0, a1), (b0, b1) = spans["db1"], spans["db2"]
    assert a0 < b1 and b0 < a1, spans  # both jobs ran at the same time
    seen = {}
    for sub in subs:
        job, results = the_job(served, sub["id"])
        (result,) = results
        assert job["status"] == "success", result["message"]
        report = result["public_report"]
        assert report["measured_by"] == "watchtowers" and report["lab"] == "one-floor"
        assert report["localization_median_error_m"] <= 0.02
        assert result["public_scores"]["survival_time_median"] == 3.0
        seen[report["robot"]] = report["localization"][0]["robots_localised"]
    assert sorted(seen) == ["db1", "db2"]
    assert all(report_robot in robots for report_robot, robots in seen.items())
    assert ["db1", "db2"] in seen.values(), seen  # the watchtowers saw both robots on the floor during an episode


def test_a_robot_driving_into_a_standing_one_ends_as_a_collision_and_the_standing_ones_run_is_invalid(
        tmp_path: Path) -> None:
    """The collision rule end to end through the world's server and the evaluator's check: robot db1 drives straight
    into db2, which stands still; db1's episode ends as a ``collision`` (scored as the agent's), db2's run is invalid
    (the Autolab evaluator's host error, so it is run again)."""
    import secrets
    import threading

    import numpy as np

    from proxybench.agents.base import Agent
    from proxybench.domain.params import DomainParams
    from proxybench.evaluator.lab_world import contact_invalid
    from proxybench.runner.jobs import JobResult
    from proxybench.runner.lab_world import LabWorldAddress, LabWorldPlant, LabWorldSpec, connect, serve
    from proxybench.runner.robot_episode import run_episode_on_plant
    from proxybench.tasks.trajectory import Termination

    class Constant(Agent):
        privileged = True  # no camera: nothing to render

        def __init__(self, pwm: float, first: threading.Event | None = None) -> None:
            self.pwm, self.first = pwm, first

        def act(self, obs):
            if self.first is not None:  # db2's agent answers its first frame once db1 is on the floor too
                assert self.first.wait(60)
            return np.array([self.pwm, self.pwm])

    address = LabWorldAddress(str(tmp_path / "w.sock"), secrets.token_bytes(16))
    ready, stop = threading.Event(), threading.Event()
    threading.Thread(target=serve, args=(LabWorldSpec("loop_3x3", ("db1", "db2"), (420, 421)), address, ready, stop),
                     daemon=True).start()
    assert ready.wait(120)
    db1_started, db2_started = threading.Event(), threading.Event()
    starts = {"db1": ((1.0, 0.3, 0.0), Constant(0.5), db1_started),
              "db2": ((1.4, 0.3, 0.0), Constant(0.0, db1_started), db2_started)}
    out = {}

    def job(name: str) -> None:
        pose, agent, started = starts[name]
        conn = connect(address, name)
        if name == "db1":
            assert db2_started.wait(60)  # db1 starts behind a robot that is already there
        plant = LabWorldPlant(conn, name, "loop_3x3", DomainParams(frame_rate=10.0))
        begin = plant.begin
        plant.begin = lambda *a: (begin(*a), started.set())[0]
        out[name] = run_episode_on_plant(plant, agent, 1, 3.0, pose=pose, camera=False)
        conn.close()

    threads = [threading.Thread(target=job, args=(n,)) for n in ("db2", "db1")]
    for t in threads:
        t.start()
    for t in threads:
        t.join(300)
    stop.set()
    a, b = out["db1"], out["db2"]
    assert a.termination is Termination.COLLISION and "ran into robot 'db2'" in a.event(Termination.COLLISION).message
    assert b.termination is Termination.TIMEOUT and b.event("robot_contact") is not None
    results = {}
    for name, traj in out.items():
        path = traj.save(tmp_path / f"{name}.parquet")
        results[name] = JobResult("k", "agent", "lab-world", 0, 1, {}, traj.termination, str(path))
    assert contact_invalid(results["db1"]) is None  # at fault: its collision is scored
    why = contact_invalid(results["db2"])
    assert why.startswith("at t = ") and "robot 'db1' ran into this robot" in why and "the run is invalid" in why
