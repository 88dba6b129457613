"""A lab's own DTPS robot under the Autolab evaluator (issue 36): the operator places it, the sandboxed SDK agent
drives it through a relay that reaches that robot only, the lab's DTPS watchtowers measure it, and an operator's
intervention ends the job as the lab's fault.

A real lab is stood in for by a process the test starts (``proxybench dtps serve --watchtowers``): a virtual DB21J
on a port of 127.0.0.1 whose world's watchtowers are served as DTPS camera topics, stamped by the wall clock. The
evaluator treats it as foreign: its scores come from the localised trajectory; the stand-in's truth (its own
trajectory file) is read by the test only.
"""

from __future__ import annotations

import contextlib
import csv
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from proxybench.autolab.lab import load_lab
from proxybench.autolab.operator import OperatorDesk, OperatorError, OperatorTimeout, confirm_ready, intervene
from support.real_robot import LAB, answer, operator_places, run_lab_job, submit, write_lab


def _lab(tmp_path: Path, text: str = LAB.replace("PORT", "7599").replace("streams: []", "streams: [{name: wt1, "
                                                 "dtps: 127.0.0.1:7600/wt1, calibration: c.yaml}]")):
    (tmp_path / "lab.yaml").write_text(text)
    return load_lab(tmp_path / "lab.yaml")


# -- the operator's desk ---------------------------------------------------------------------------------------

def test_a_placement_waits_for_the_operator_and_a_stale_confirmation_never_counts(tmp_path: Path) -> None:
    lab = _lab(tmp_path)
    desk = OperatorDesk.of(lab, "db1")
    assert desk.folder == tmp_path / "real-lab.operator" / "db1"  # beside lab.yaml, by default
    with pytest.raises(OperatorError, match="no evaluator is waiting for robot 'db1'"):
        confirm_ready(lab, "db1")
    (desk.folder / "ready-0123456789abcdef").write_text("{}")  # an answer to an earlier request
    with pytest.raises(OperatorTimeout, match=r"operator-timeout: no one confirmed robot 'db1' placed .*at x=1"):
        desk.place("at x=1", 0.3)
    asked = answer(confirm_ready, desk.folder / "waiting.json", lab, "db1")
    desk.place("at x=2", 600)
    asked.join()
    assert not list(desk.folder.iterdir())  # the request and its answer are gone


def test_an_intervention_lands_on_the_running_episode_only(tmp_path: Path) -> None:
    lab = _lab(tmp_path)
    desk = OperatorDesk.of(lab, "db1")
    with pytest.raises(OperatorError, match="robot 'db1' runs no episode now"):
        intervene(lab, "db1", "too late")
    nonce = desk.open_episode("validation episode 0")
    assert desk.intervention(nonce) is None
    assert intervene(lab, "db1", "it fell\noff the\x1b table") == "validation episode 0"
    assert desk.intervention(nonce) == "it fell off the? table"  # one printable line
    desk.close_episode()
    with pytest.raises(OperatorError, match="runs no episode now"):
        intervene(lab, "db1", "after the end")
    with pytest.raises(KeyError, match="has no robot 'db9'"):
        intervene(lab, "db9", "no such robot")


def test_the_operator_commands_say_what_they_did(tmp_path: Path) -> None:
    lab = _lab(tmp_path)
    run = [sys.executable, "-m", "proxybench", "autolab"]
    done = subprocess.run([*run, "ready", str(tmp_path / "lab.yaml"), "db1"], capture_output=True, text=True)
    assert done.returncode == 1 and "no evaluator is waiting for robot 'db1'" in done.stderr + done.stdout
    desk = OperatorDesk.of(lab, "db1")
    desk.open_episode("validation episode 2")
    done = subprocess.run([*run, "intervene", str(tmp_path / "lab.yaml"), "db1", "--reason", "stuck"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "validation episode 2" in done.stdout
    assert desk.intervention(desk.folder.joinpath("episode.json").read_text().split('"nonce": "')[1][:16]) == "stuck"


# -- what a DTPS robot's job needs -------------------------------------------------------------------------------

def test_a_dtps_robot_needs_the_labs_own_cameras_and_an_sdk_agent(tmp_path: Path) -> None:
    from proxybench.evaluator.autolab_dtps import check_dtps_robot
    from proxybench.evaluator.outcome import HostFault
    from proxybench.runner.jobs import AgentSpec

    sdk = AgentSpec.sdk("mine", "python3 agent.py")
    lab = _lab(tmp_path, LAB.replace("PORT", "7599").replace("streams: []", "layout: auto"))
    with pytest.raises(HostFault, match=r"simulated watchtowers \(layout\) cannot see a DTPS robot"):
        check_dtps_robot(lab, sdk)
    lab = _lab(tmp_path)
    with pytest.raises(HostFault, match="runs duckietown-sdk agents only; agent 'node' is an AIDO node"):
        check_dtps_robot(lab, AgentSpec.node("node", "python3 node.py"))
    check_dtps_robot(lab, sdk)


def test_the_watchtowers_clock_starts_at_the_robots_first_command(tmp_path: Path) -> None:
    from proxybench.evaluator.autolab_real import rebase_streams

    tower = tmp_path / "wt1"
    tower.mkdir()
    with open(tower / "timestamps.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "t", "stamp", "received"])
        for k in range(4):
            (tower / f"{k:06d}.jpg").write_bytes(b"x")
            w.writerow([k, 0.2 * k, 1000.0 + 0.2 * k, 1000.1 + 0.2 * k])
    assert rebase_streams(tmp_path, 1000.3) == 2  # frames before the first command are dropped
    with open(tower / "timestamps.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["frame"] for r in rows] == ["2", "3"]
    assert [float(r["t"]) for r in rows] == pytest.approx([0.1, 0.3])
    assert sorted(p.name for p in tower.glob("*.jpg")) == ["000002.jpg", "000003.jpg"]


# -- the relay ----------------------------------------------------------------------------------------------------

@pytest.mark.skipif(os.geteuid() != 0 or shutil.which("nsenter") is None, reason="needs root and nsenter")
def test_the_relay_gives_a_namespace_the_robot_and_nothing_else() -> None:
    from proxybench.dtps.relay import RobotRelay

    robot, other = socket.socket(), socket.socket()
    for s in (robot, other):
        s.bind(("127.0.0.1", 0))
        s.listen()

    def echo() -> None:
        conn, _ = robot.accept()
        conn.sendall(b"robot:" + conn.recv(100))
        conn.close()
    threading.Thread(target=echo, daemon=True).start()
    code = f"""
import socket
s = socket.create_connection(("127.0.0.1", 7501), timeout=20); s.sendall(b"hello"); print(s.recv(100).decode())
for port in ({other.getsockname()[1]}, {robot.getsockname()[1]}):
    try:
        socket.create_connection(("127.0.0.1", port), timeout=5)
        print("reached", port)
    except OSError:
        print("unreachable")
"""
    with RobotRelay("127.0.0.1", robot.getsockname()[1]) as relay:
        assert relay.netns is not None and relay.netns.endswith("/ns/net")
        done = subprocess.run(["nsenter", f"--net={relay.netns}", sys.executable, "-c", code], capture_output=True,
                              text=True, timeout=120)
    assert done.stdout.split() == ["robot:hello", "unreachable", "unreachable"], done.stderr
    assert not relay.alive


# -- end to end: a stand-in lab in processes of its own ------------------------------------------------------------

def _stand_in(tmp_path: Path, port: int) -> tuple[subprocess.Popen, str]:
    """``proxybench dtps serve --watchtowers`` on ``port``; (its process, the watchtowers' HOST:PORT)."""
    proc = subprocess.Popen([sys.executable, "-m", "proxybench", "dtps", "serve", "--map", "loop_3x3", "--port",
                             str(port), "--watchtowers", str(tmp_path / "towers.yaml"), "--frame-rate", "5",
                             "--width", "160", "--height", "120", "--out", str(tmp_path / "truth"),
                             "--episode-seconds", "600", "--seconds", "900"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    towers = None
    for line in proc.stdout:
        if line.startswith("serving ") and "watchtowers at " in line:
            towers = line.split(" at ")[1].strip().removesuffix("/NAME")
        if line.startswith("serving a SIMULATED DB21J"):
            break
    assert towers is not None, "the stand-in did not start"
    threading.Thread(target=proc.stdout.read, daemon=True).start()  # drain it
    return proc, towers


def _path_errors(track: Path, truth: Path) -> np.ndarray:
    """Each localised sample's distance to the stand-in's true path (its poses at every physics step)."""
    import pandas as pd

    from proxybench.tasks.trajectory import Trajectory

    xy = pd.read_csv(track)[["x", "y"]].to_numpy()
    t = Trajectory.load(truth)
    path = np.column_stack([t["x"], t["y"]])
    return np.min(np.linalg.norm(xy[:, None, :] - path[None, :, :], axis=2), axis=1)


@pytest.fixture
def real_lab(tmp_path: Path):
    """The stand-in lab's robot and watchtowers, and the lab.yaml that describes them (a foreign robot)."""
    from proxybench.autolab.watchtowers import auto_layout, write_layout
    from proxybench.domain.maps import load_map
    from proxybench.dtps.cameras import free_port

    layout = auto_layout(load_map("loop_3x3"))
    write_layout(tmp_path / "towers.yaml", layout)
    port = free_port()
    proc, towers = _stand_in(tmp_path, port)
    try:
        write_lab(tmp_path, port, towers, layout)
        yield proc
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

from support.dtps import sdk  # noqa: E402
from support.real_robot import (  # noqa: E402
    check_retried_once,
    check_retries_spent,
    drilled,
    lab_evaluator,
    run_drilled,
)
from support.sandbox import AGENT_USER_GROUP, agent_uid, processes_left, require_safe_sandbox  # noqa: E402
from test_autolab_evaluator import BENCH  # noqa: E402
from test_evaluator import Served, served, the_job  # noqa: E402, F401 - served: a fixture


@sdk
@AGENT_USER_GROUP
def test_an_sdk_package_drives_the_labs_dtps_robot_placed_by_the_operator_and_is_scored_from_the_watchtowers(
        served: Served, tmp_path: Path, real_lab: subprocess.Popen) -> None:  # noqa: F811
    import io
    import zipfile

    require_safe_sandbox()
    sub = submit(served, tmp_path)  # the SDK package's timing is for simulation; a foreign robot keeps its own clock
    status, job, (result,) = run_lab_job(served, tmp_path, load_lab(tmp_path / "lab.yaml"), sub)
    assert status == job["status"] == "success", result["message"]
    report = result["public_report"]
    assert report["domain_kind"] == "autolab/dtps" and report["measured_by"] == "watchtowers"
    assert report["robot"] == "db1" and report["watchtowers"] == 12
    assert report["localization_median_error_m"] is None  # a foreign robot: the evaluator knows no truth
    (loc,) = report["localization"]
    assert loc["valid"] and loc["samples"] >= 10, loc
    (record,) = report["robot_record"]
    assert record["commands"] >= 5  # the agent's commands, heard on the robot's own topics
    scores = result["public_scores"]
    assert scores["survival_time_median"] == 3.0 and scores["driven_lanedir_consec_median"] > 0.1
    zipped = next(a for a in result["artifacts"] if a["name"] == "trajectories-validation.zip")
    with zipfile.ZipFile(io.BytesIO(served.admin.http.get(f"/artifacts/{zipped['sha256']}").content)) as zf:
        assert {"episode-0.parquet", "episode-0-track.csv", "robot-episode-0.csv"} <= set(zf.namelist())
        zf.extract("episode-0-track.csv", tmp_path)
    uid = agent_uid()
    assert uid is None or processes_left(uid) == []
    os.killpg(real_lab.pid, signal.SIGTERM)  # the stand-in saves its episode: the truth, for this check only
    real_lab.wait(120)
    errors = _path_errors(tmp_path / "episode-0-track.csv", tmp_path / "truth" / "episode-0.parquet")
    assert np.median(errors) <= 0.02, np.percentile(errors, [50, 95])


@sdk
@AGENT_USER_GROUP
def test_an_operators_intervention_ends_the_episode_and_the_job_as_the_labs_fault(
        served: Served, tmp_path: Path, real_lab: subprocess.Popen) -> None:  # noqa: F811
    require_safe_sandbox()
    sub = submit(served, tmp_path)
    lab = load_lab(tmp_path / "lab.yaml")
    desk = lab.operator.folder / "db1"
    stepped_in = answer(intervene, desk / "episode.json", lab, "db1", "the robot ran into a cable")
    status, job, results = run_lab_job(served, tmp_path, lab, sub)
    stepped_in.join(timeout=60)
    assert status == "host-error"
    assert job["status"] == "queued" and results == []  # the lab's fault: nothing stored, the job runs again
    (event,) = [e for e in served.admin.get(f"/jobs/{job['id']}")["events"] if e["kind"] == "host-error"]
    assert event["message"] == ("manual_intervention: the operator intervened on robot 'db1' of lab 'real-lab' in "
                                "validation episode 0: the robot ran into a cable")
    uid = agent_uid()
    assert uid is None or processes_left(uid) == []
    assert not (desk / "episode.json").exists()  # no later intervention can land on another episode


@sdk
@AGENT_USER_GROUP
def test_a_dtps_robot_that_drops_off_mid_episode_is_a_robot_failure_with_nothing_stored(
        served: Served, tmp_path: Path, real_lab: subprocess.Popen) -> None:  # noqa: F811
    from proxybench.dtps.observer import RobotObserver
    from proxybench.dtps.robot_options import parse_address

    require_safe_sandbox()
    sub = submit(served, tmp_path, bench=BENCH.replace("duration: 3.0", "duration: 60.0"))
    lab = load_lab(tmp_path / "lab.yaml")
    placed = operator_places(lab)
    lab_ev = lab_evaluator(served, tmp_path, lab)
    outcome: list[str | None] = []
    driving = threading.Thread(target=lambda: outcome.append(lab_ev.take_one()), daemon=True)
    driving.start()
    with_us = RobotObserver(parse_address(lab.robots[0].dtps))  # the test hears the agent drive the robot
    try:
        while not with_us.heard.commands and driving.is_alive():
            with_us.pump(time.monotonic() + 0.2)
    finally:
        os.killpg(real_lab.pid, signal.SIGKILL)  # the robot (and the lab's stand-in watchtowers) drop off DTPS
        real_lab.wait(60)
        with contextlib.suppress(Exception):
            with_us.close()
    driving.join(timeout=600)
    placed.join(timeout=60)
    assert outcome == ["host-error"]
    job, results = the_job(served, sub["id"])
    assert job["status"] == "queued" and results == []  # the lab's fault: nothing stored, the job runs again
    (event,) = [e for e in served.admin.get(f"/jobs/{job['id']}")["events"] if e["kind"] == "host-error"]
    assert event["message"].startswith("robot_failure: robot 'db1' of lab 'real-lab' failed in validation episode "
                                       "0: its DTPS server 127.0.0.1:"), event["message"]
    uid = agent_uid()
    assert uid is None or processes_left(uid) == []


# -- an invalid run run again, as the benchmark says (invalid_retries) ---------------------------------------------

def test_a_drill_on_a_labs_own_streams_names_them(tmp_path: Path) -> None:
    from proxybench.autolab.lab import LabError

    text = LAB.replace("PORT", "7599").replace("streams: []", "streams: [{name: wt1, dtps: 127.0.0.1:7600/wt1, "
                                               "calibration: c.yaml}]")
    assert _lab(tmp_path, text + "drills: {streams_stop_s: 1.5, streams_stop_attempts: 1}\n").drills.stops_streams(1)
    with pytest.raises(LabError, match=r"drills.streams_stop: no watchtower 'wt9' in watchtowers.streams"):
        _lab(tmp_path, text + "drills: {streams_stop_s: 1.5, streams_stop: [wt9]}\n")


@sdk
@AGENT_USER_GROUP
def test_an_invalid_run_on_the_dtps_robot_is_placed_and_run_again_and_the_valid_attempt_scores_the_job(
        served: Served, tmp_path: Path, real_lab: subprocess.Popen) -> None:  # noqa: F811
    require_safe_sandbox()
    status, job, results, asked = run_drilled(served, tmp_path, drilled(tmp_path / "lab.yaml", attempts=1))
    assert status == job["status"] == "success", results
    check_retried_once(served, results[0], asked, ".csv")
    uid = agent_uid()
    assert uid is None or processes_left(uid) == []


@sdk
@AGENT_USER_GROUP
def test_a_run_on_the_dtps_robot_invalid_in_every_attempt_ends_host_error_naming_each(
        served: Served, tmp_path: Path, real_lab: subprocess.Popen) -> None:  # noqa: F811
    require_safe_sandbox()
    check_retries_spent(served, *run_drilled(served, tmp_path, drilled(tmp_path / "lab.yaml"), retries=1))
    uid = agent_uid()
    assert uid is None or processes_left(uid) == []
