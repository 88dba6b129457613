"""Every way a robot node can misbehave ends in one RobotFailure with its reason, fast, process reaped."""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from proxybench.agents import make_agent
from proxybench.domain.maps import load_map
from proxybench.protocol import ROBOT_REASONS, ProtocolUsageError, RemoteRobot, RobotFailure, RobotProcess
from proxybench.runner.robot_episode import RobotLacksGroundTruth, run_episode_on_robot

HERE = Path(__file__).resolve().parent
MISBEHAVE = [sys.executable, str(HERE / "protocol_agents" / "misbehave_robot.py")]
STEP_TIMEOUT = 0.5
INIT_TIMEOUT = 1.0
MARGIN = 2.0  # process start, kill and reap, slow CI


def provoke(mode: str, trigger: str = "step", **kwargs) -> tuple[RobotFailure, float, RemoteRobot | None]:
    """Drive the misbehaving robot through two frames of an episode; (failure, seconds taken, robot if built)."""
    kwargs = {"init_timeout": INIT_TIMEOUT, "step_timeout": STEP_TIMEOUT, **kwargs}
    robot = None
    t0 = time.monotonic()
    try:
        robot = RemoteRobot([*MISBEHAVE, mode, trigger], **kwargs)
        run_episode_on_robot(robot, make_agent("straight"), 1, 2 / 15, map_="loop_3x3")
    except RobotFailure as failure:
        return failure, time.monotonic() - t0, robot
    pytest.fail(f"mode {mode!r} did not fail")


def assert_reaped(failure: RobotFailure) -> None:
    assert failure.pid is not None and failure.exit_code is not None
    with pytest.raises(ChildProcessError):
        os.waitpid(failure.pid, os.WNOHANG)  # already reaped: no longer our child


CASES = [
    ("crash", "step", "exited"),
    ("crash", "capabilities", "exited"),
    ("exit0", "get_robot_observations", "exited"),
    ("garbage", "step", "garbage"),
    ("text", "set_robot_commands", "garbage"),
    ("not-a-map", "get_sim_state", "not-a-map"),
    ("truncated", "step", "truncated"),
    ("bad-message", "seed", "bad-message"),
    ("unknown-topic", "step", "unknown-topic"),
    ("two-commands", "get_robot_state", "unknown-topic"),  # `commands` is an agent's output, not a robot's
    ("aborted", "set_map", "aborted"),
    ("no-commands", "get_robot_state", "out-of-order"),  # understood, over: the robot_state is missing
    ("no-understood", "get_robot_state", "out-of-order"),
    ("bad-data", "get_robot_observations", "bad-data"),
    ("nan-state", "get_robot_state", "bad-data"),
    ("bad-lane-pose", "get_robot_observations", "bad-data"),
    ("wrong-robot", "get_robot_state", "bad-data"),
    ("incompatible", "wrapper.describe_protocol", "incompatible"),
    ("stdout-flood", "step", "stdout-flood"),
    ("stderr-flood", "step", "stderr-flood"),
]


@pytest.mark.parametrize(("mode", "trigger", "reason"), CASES, ids=[f"{m}@{t}" for m, t, _ in CASES])
def test_misbehaviour_is_classified(mode, trigger, reason):
    failure, took, _ = provoke(mode, trigger, max_reply_bytes=1 << 20, max_stderr_bytes=256 << 10)
    assert failure.reason == reason, failure
    assert reason in ROBOT_REASONS
    assert took < MARGIN, f"took {took:.2f} s"
    assert_reaped(failure)


@pytest.mark.parametrize(("trigger", "reason"), [("step", "step-timeout"), ("get_robot_state", "step-timeout"),
                                                 ("capabilities", "init-timeout"), ("set_map", "init-timeout")])
def test_a_hanging_robot_times_out(trigger, reason):
    failure, took, _ = provoke("hang", trigger)
    assert failure.reason == reason
    limit = INIT_TIMEOUT if reason == "init-timeout" else STEP_TIMEOUT
    assert limit <= took < limit + MARGIN
    assert_reaped(failure)


def test_crash_reports_exit_code_and_stderr_and_restarts():
    failure, _, robot = provoke("crash", "get_robot_state")
    assert failure.exit_code == 3 and failure.stderr_tail[-1] == "boom: something broke"
    assert "exit code 3" in str(failure)
    with pytest.raises(RobotFailure) as again:  # a failed process stays failed
        robot.process.step(1.0)
    assert again.value.reason == "exited"
    with pytest.raises(RobotFailure):  # the fresh process crashes the same way, but it was started
        run_episode_on_robot(robot, make_agent("straight"), 1, 2 / 15, map_="loop_3x3")
    assert robot.restarts == 1


@pytest.mark.parametrize("transport", ["pipes", "fifos"])
def test_a_robot_without_ground_truth_refuses_privileged_agents_and_records_frame_samples(transport):
    with RemoteRobot([*MISBEHAVE, "none", "never"], init_timeout=5, transport=transport) as robot:
        with pytest.raises(RobotLacksGroundTruth, match="reports no true lane pose"):
            run_episode_on_robot(robot, make_agent("pid"), 1, 0.5, map_="loop_3x3")
        traj = run_episode_on_robot(robot, make_agent("straight"), 1, 0.4, map_="loop_3x3", camera=False)
    assert traj.meta["source"] == "robot"  # what the robot says it is
    assert np.allclose(traj.columns["t"], np.arange(7) / 15)  # one sample per frame from robot_state
    assert traj.termination == "timeout" and np.all(traj.columns["x"] == 0.3)


def test_caller_order_errors_send_nothing():
    with RobotProcess([*MISBEHAVE, "none", "never"], init_timeout=5) as proc:
        with pytest.raises(ProtocolUsageError, match='Unexpected input "step"'):
            proc.step(0.1)
        with pytest.raises(ProtocolUsageError):
            proc.set_commands("ego", 0.0, np.zeros(2))
        proc.seed(1)
        with pytest.raises(ProtocolUsageError):
            proc.seed(2)
    assert proc.returncode == 0


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX signals")
def test_real_robot_node_killed_mid_episode():
    serve = [sys.executable, "-m", "proxybench.cli", "robot", "serve", "--param", "image_width=32",
             "--param", "image_height=24"]
    robot = RemoteRobot(serve, init_timeout=60, step_timeout=5)
    robot.start_episode(load_map("loop_3x3"), 1)
    robot.frame(0.0, np.array([0.2, 0.2]), 1 / 15)
    os.kill(robot.process.pid, signal.SIGKILL)
    t0 = time.monotonic()
    with pytest.raises(RobotFailure) as exc:
        robot.frame(1 / 15, np.array([0.2, 0.2]), 2 / 15)
    assert exc.value.reason == "exited" and exc.value.exit_code == -signal.SIGKILL
    assert time.monotonic() - t0 < MARGIN
    assert_reaped(exc.value)


def test_start_failure():
    with pytest.raises(RobotFailure) as exc:
        RobotProcess(["/nonexistent/robot-bridge"])
    assert exc.value.reason == "start-failed" and exc.value.exit_code is None


def test_every_robot_reason_is_documented():
    doc = (HERE.parent / "docs" / "robot-protocol.md").read_text()
    for reason in ROBOT_REASONS:
        assert f"| `{reason}` |" in doc, reason
