"""A lab's robot node (``command:``) under the Autolab evaluator (issue 36): the runner steps the node with the job's
agent, the operator places the robot, the lab's DTPS watchtowers measure it, and the job is scored from them only.

The lab is stood in for by the node itself: ``proxybench robot serve --watchtowers towers.yaml --watchtower-port P``
(the simulator behind the robot protocol, whose world's watchtowers are served as DTPS camera topics, stamped from
the episode's first command as a real-time world's cameras would be). Its own record (the pose it reports) is the
truth here, which only the test compares with the localisation; the evaluator keeps it beside the result as
``robot_reported_scores``.
"""

from __future__ import annotations

import io
import shlex
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from proxybench.autolab.lab import load_lab

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

from support.dtps import sdk
from support.real_robot import (
    check_retried_once,
    check_retries_spent,
    drilled,
    run_drilled,
    run_lab_job,
    submit,
    write_lab,
)
from support.sandbox import AGENT_USER_GROUP, agent_uid, processes_left, require_safe_sandbox
from test_evaluator import Served, served  # noqa: F401 - served: a fixture


def _node(tmp_path: Path, port: int) -> str:
    """The stand-in robot node's command (the benchmark's rates, small frames), its towers on ``port``."""
    return shlex.join([sys.executable, "-m", "proxybench", "robot", "serve", "--map", "loop_3x3", "--param",
                       "frame_rate=5", "--param", "physics_rate=30", "--param", "image_width=160", "--param",
                       "image_height=120", "--watchtowers", str(tmp_path / "towers.yaml"), "--watchtower-port",
                       str(port)])


@pytest.fixture
def node_lab(tmp_path: Path) -> Path:
    """lab.yaml of one robot node (the stand-in) and its watchtowers' DTPS streams; the node is the evaluator's to
    start."""
    from proxybench.autolab.watchtowers import auto_layout, write_layout
    from proxybench.domain.maps import load_map
    from proxybench.dtps.cameras import free_port

    layout = auto_layout(load_map("loop_3x3"))
    write_layout(tmp_path / "towers.yaml", layout)
    port = free_port()
    write_lab(tmp_path, port, f"127.0.0.1:{port}", layout)
    text = (tmp_path / "lab.yaml").read_text()
    robot = next(line for line in text.splitlines() if "name: db1" in line)
    (tmp_path / "lab.yaml").write_text(text.replace(robot, f"  - {{name: db1, command: {_node(tmp_path, port)!r}}}"))
    return tmp_path / "lab.yaml"


def _errors(track: Path, truth: Path) -> tuple[np.ndarray, np.ndarray]:
    """Each localised sample's distance to the node's pose at that time, and to its path."""
    import pandas as pd

    from proxybench.tasks.trajectory import Trajectory

    loc = pd.read_csv(track)
    t = Trajectory.load(truth)
    at = np.hypot(loc["x"] - np.interp(loc["t"], t["t"], t["x"]), loc["y"] - np.interp(loc["t"], t["t"], t["y"]))
    path = np.column_stack([t["x"], t["y"]])
    xy = loc[["x", "y"]].to_numpy()
    return at.to_numpy(), np.min(np.linalg.norm(xy[:, None, :] - path[None, :, :], axis=2), axis=1)


def test_a_robot_node_with_a_simulated_layout_is_refused_saying_why(tmp_path: Path) -> None:
    from proxybench.evaluator.autolab_node import check_node_robot
    from proxybench.evaluator.outcome import HostFault

    (tmp_path / "lab.yaml").write_text("format: proxybench-lab/1\nname: l\nmap: loop_3x3\nrobots:\n"
                                       "  - {name: db1, command: python3 bridge.py}\nwatchtowers: {layout: auto}\n"
                                       "reset: {mode: operator}\n")
    with pytest.raises(HostFault, match=r"simulated watchtowers \(layout\) cannot see a robot node's robot"):
        check_node_robot(load_lab(tmp_path / "lab.yaml"))


@sdk
@AGENT_USER_GROUP
def test_an_sdk_package_drives_the_labs_robot_node_and_is_scored_from_the_watchtowers(
        served: Served, tmp_path: Path, node_lab: Path) -> None:  # noqa: F811
    require_safe_sandbox()
    sub = submit(served, tmp_path)
    status, job, (result,) = run_lab_job(served, tmp_path, load_lab(node_lab), sub)
    assert status == job["status"] == "success", result["message"]
    report = result["public_report"]
    assert report["domain_kind"] == "autolab/node" and report["measured_by"] == "watchtowers"
    assert report["robot"] == "db1" and report["watchtowers"] == 12
    assert report["localization_median_error_m"] is None  # the node's word is no truth to the evaluator
    (loc,) = report["localization"]
    assert loc["valid"] and loc["samples"] >= 10, loc
    scores, reported = result["public_scores"], report["robot_reported_scores"]
    assert scores["survival_time_median"] == 3.0 and scores["driven_lanedir_consec_median"] > 0.1
    assert reported["driven_lanedir_consec_median"] > 0.1  # the node's own record, kept beside
    assert scores["driven_lanedir_consec_median"] == pytest.approx(reported["driven_lanedir_consec_median"], abs=0.1)
    zipped = next(a for a in result["artifacts"] if a["name"] == "trajectories-validation.zip")
    with zipfile.ZipFile(io.BytesIO(served.admin.http.get(f"/artifacts/{zipped['sha256']}").content)) as zf:
        assert {"episode-0.parquet", "episode-0-track.csv", "robot-episode-0.parquet"} <= set(zf.namelist())
        zf.extractall(tmp_path / "zip", ["episode-0-track.csv", "robot-episode-0.parquet"])
    uid = agent_uid()
    assert uid is None or processes_left(uid) == []
    at_time, to_path = _errors(tmp_path / "zip" / "episode-0-track.csv", tmp_path / "zip" / "robot-episode-0.parquet")
    assert np.median(to_path) <= 0.02, np.percentile(to_path, [50, 95])
    assert np.median(at_time) <= 0.02, np.percentile(at_time, [50, 95])  # one clock: the node's first command


@AGENT_USER_GROUP
def test_an_aido_node_package_drives_the_labs_robot_node_through_the_runner(
        served: Served, tmp_path: Path, node_lab: Path) -> None:  # noqa: F811
    from test_evaluator import make_package

    require_safe_sandbox()
    sub = submit(served, tmp_path, package=make_package("ok"), name="forward")  # an AIDO node driving straight on
    status, job, (result,) = run_lab_job(served, tmp_path, load_lab(node_lab), sub)
    assert status == job["status"] == "success", result["message"]
    report = result["public_report"]
    (record,) = report["robot_record"]
    (loc,) = report["localization"]
    assert report["domain_kind"] == "autolab/node" and loc["valid"], (record, loc)
    assert result["public_scores"]["survival_time_median"] > 0.5
    uid = agent_uid()
    assert uid is None or processes_left(uid) == []


@sdk
@AGENT_USER_GROUP
def test_an_invalid_run_on_the_robot_node_is_placed_and_run_again_and_the_valid_attempt_scores_the_job(
        served: Served, tmp_path: Path, node_lab: Path) -> None:  # noqa: F811
    require_safe_sandbox()
    status, job, results, asked = run_drilled(served, tmp_path, drilled(node_lab, attempts=1))
    assert status == job["status"] == "success", results
    report = check_retried_once(served, results[0], asked, ".parquet")
    assert report["robot_reported_scores"]["driven_lanedir_consec_median"] > 0.1  # the scored attempt's own record


@sdk
@AGENT_USER_GROUP
def test_a_run_on_the_robot_node_invalid_in_every_attempt_ends_host_error_naming_each(
        served: Served, tmp_path: Path, node_lab: Path) -> None:  # noqa: F811
    require_safe_sandbox()
    check_retries_spent(served, *run_drilled(served, tmp_path, drilled(node_lab), retries=1))
