"""The Autolab end to end (issue 36): a duckietown-sdk agent package submitted to the challenges server is leased
by an Autolab evaluator (``--autolab lab.yaml``), driven on the lab's virtual DB21J while simulated watchtowers
record, localised, validated by the DTA's rules and scored from the localised trajectory.

The server is test_evaluator's (uvicorn in a thread, SQLite); the episode is short (one of 3 s, camera at 5 Hz,
watchtowers at 5 Hz) so that the job takes seconds of CPU besides the SDK's start.
"""

from __future__ import annotations

import io
import tempfile
import zipfile
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

from support.dtps import sdk
from support.sandbox import AGENT_USER_GROUP, require_safe_sandbox
from test_evaluator import Served, evaluator, served, the_job  # noqa: F401 - served: test_evaluator's fixture

pytestmark = AGENT_USER_GROUP

LAB = """\
format: proxybench-lab/1
name: test-lab
map: loop_3x3
robots:
  - {name: db1, virtual: true}
watchtowers: {layout: auto}
reset: {mode: teleport}
"""
BENCH = """\
name: autolab_tiny
description: one short episode in a simulated Autolab
map: loop_3x3
episodes: {count: 1, seed: 3}
duration: 3.0
physics_rate: 30.0
frame_rate: 5.0
camera_only: true
metrics: [survival_time, driven_lanedir_consec, deviation_center_line]
scoring:
  - {metric: driven_lanedir_consec_median, higher_is_better: true}
  - {metric: survival_time_median}
"""


def sdk_package() -> bytes:
    """The Autolab demo's built-in agent package: its lane-following SDK agent, lock-step."""
    from proxybench.cli.autolab_demo import agent_package

    with tempfile.TemporaryDirectory() as folder:
        return agent_package(Path(folder)).read_bytes()


@sdk
def test_an_sdk_package_is_measured_by_the_watchtowers_and_scored_from_them(served: Served,  # noqa: F811
                                                                             tmp_path: Path) -> None:
    from proxybench.autolab.lab import load_lab
    from proxybench.tasks.trajectory import Trajectory

    require_safe_sandbox()
    served.admin.post("/benchmarks", {"yaml": BENCH, "features": ["autolab"], "hidden_split": False})
    (tmp_path / "lab.yaml").write_text(LAB)
    archive = tmp_path / "sdk-lane.zip"
    archive.write_bytes(sdk_package())
    sub = served.developer.submit_archive(archive, "sdk-lane", benchmark="autolab_tiny")
    plain = evaluator(served, tmp_path, name="sim-only", video=False)
    assert plain.take_one() is None  # an evaluator without a lab never leases an Autolab job
    lab_ev = evaluator(served, tmp_path, name="lab", video=False, features=("sim", "autolab"),
                       autolab=load_lab(tmp_path / "lab.yaml"))
    status = lab_ev.take_one()
    job, (result,) = the_job(served, sub["id"])
    assert status == job["status"] == "success", result["message"]
    assert "measured by its watchtowers" in result["message"]
    report = result["public_report"]
    assert report["measured_by"] == "watchtowers" and report["domain_kind"] == "autolab/virtual"
    assert report["lab"] == "test-lab" and report["robot"] == "db1" and report["watchtowers"] == 12
    (loc,) = report["localization"]
    assert loc["valid"] and loc["samples"] >= 10, loc
    assert report["localization_median_error_m"] <= 0.02
    scores, robots = result["public_scores"], report["robot_reported_scores"]
    assert scores["driven_lanedir_consec_median"] > 0.2  # it drove along its lane
    assert scores["survival_time_median"] == robots["survival_time_median"] == 3.0  # it ran the whole episode
    # scored from the localised trajectory: close to, but not, the robot's own record
    assert scores["driven_lanedir_consec_median"] == pytest.approx(robots["driven_lanedir_consec_median"], abs=0.1)
    assert scores["driven_lanedir_consec_median"] != robots["driven_lanedir_consec_median"]
    assert report["episodes"][0]["scores"]["driven_lanedir_consec"] == scores["driven_lanedir_consec_median"]
    zipped = next(a for a in result["artifacts"] if a["name"] == "trajectories-validation.zip")
    with zipfile.ZipFile(io.BytesIO(served.admin.http.get(f"/artifacts/{zipped['sha256']}").content)) as zf:
        assert {"episode-0.parquet", "episode-0-track.csv", "episode-0-errors.csv",
                "robot-episode-0.parquet"} <= set(zf.namelist())
        zf.extract("episode-0.parquet", tmp_path)
    traj = Trajectory.load(tmp_path / "episode-0.parquet")
    assert traj.meta["measured_by"] == "watchtowers" and traj.meta["robot"] == "db1"
    assert served.developer.leaderboard("autolab_tiny")["rows"][0]["label"] == "sdk-lane"


@sdk
def test_a_robot_the_watchtowers_never_see_is_tracking_lost_and_goes_back_to_the_queue(
        served: Served, tmp_path: Path) -> None:  # noqa: F811
    from proxybench.autolab.lab import load_lab
    from proxybench.autolab.watchtowers import Layout, Watchtower, write_layout

    require_safe_sandbox()
    served.admin.post("/benchmarks", {"yaml": BENCH, "features": ["autolab"], "hidden_split": False})
    # one watchtower low over the grass inside the loop: it sees the floor, never the road the robot drives on
    write_layout(tmp_path / "towers.yaml", Layout(map="loop_3x3", watchtowers=[
        Watchtower(name="wt01", position=(0.8775, 0.8775, 0.3), yaw=90, pitch=89, frame_rate=5)]))
    (tmp_path / "lab.yaml").write_text(LAB.replace("{layout: auto}", "{layout: towers.yaml}"))
    archive = tmp_path / "sdk-lane.zip"
    archive.write_bytes(sdk_package())
    sub = served.developer.submit_archive(archive, "sdk-lane", benchmark="autolab_tiny")
    lab_ev = evaluator(served, tmp_path, name="lab", video=False, features=("sim", "autolab"),
                       autolab=load_lab(tmp_path / "lab.yaml"))
    assert lab_ev.take_one() == "host-error"
    job, results = the_job(served, sub["id"])
    assert job["status"] == "queued" and results == []  # the lab's fault: another lab may run it
    (event,) = [e for e in served.admin.get(f"/jobs/{job['id']}")["events"] if e["kind"] == "host-error"]
    assert event["message"].startswith("tracking_lost: validation episode 0 is not fit to be scored")
    assert "robot 'db1' never localised" in event["message"]
    assert lab_ev.take_one() is None  # this lab is excluded from the job now
    assert served.developer.leaderboard("autolab_tiny")["rows"] == []


@pytest.mark.parametrize(("change", "words"), [
    (("map: loop_3x3", "map: small_loop"), "is on map 'loop_3x3'; lab 'test-lab' has map 'small_loop'"),
    (("reset: {mode: operator}", "reset: {mode: operator}\nlimits: {max_episode_s: 2}"),
     "episodes of 3 s are longer than lab 'test-lab' runs"),
    (("{layout: auto}", "{streams: [{name: wt1, recorded: rec/wt1, calibration: c.yaml}]}"),
     "watchtower(s) wt1 are recorded folders"),
])
def test_what_an_autolab_evaluator_cannot_run_is_a_host_error_saying_why(tmp_path: Path, change: tuple[str, str],
                                                                         words: str) -> None:
    import yaml

    from proxybench.autolab.lab import load_lab
    from proxybench.evaluator.autolab import _check_lab
    from proxybench.evaluator.outcome import HostFault
    from proxybench.tasks.benchmark import Benchmark

    (tmp_path / "lab.yaml").write_text(LAB.replace("teleport", "operator").replace(*change))
    bench = Benchmark.from_dict(yaml.safe_load(BENCH), origin="autolab_tiny")
    with pytest.raises(HostFault) as info:
        _check_lab(load_lab(tmp_path / "lab.yaml"), bench)
    assert words in str(info.value)
