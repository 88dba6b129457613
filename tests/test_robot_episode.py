"""The runner driving the simulator through the robot protocol gives the in-process trajectory, sample for sample."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from proxybench.agents import make_agent
from proxybench.cli import app
from proxybench.domain.maps import parse_map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.protocol import RemoteRobot
from proxybench.runner.episode import run_episode
from proxybench.runner.outcomes import camera_filter
from proxybench.runner.robot_episode import run_episode_on_robot
from proxybench.tasks.trajectory import Trajectory

PARAMS = DomainParams(image_width=80, image_height=60)
SERVE = [sys.executable, "-m", "proxybench.cli", "robot", "serve", "--param", "image_width=80",
         "--param", "image_height=60"]


@pytest.fixture(scope="module")
def robot():
    with RemoteRobot(SERVE, init_timeout=60, step_timeout=10) as r:
        yield r
    assert r.process.returncode == 0


@pytest.fixture(scope="module")
def sims():
    return {name: Simulator(name, PARAMS) for name in ("loop_3x3", "intersections")}


@pytest.fixture(scope="module")
def sim(sims):
    return sims["loop_3x3"]


def assert_same(got: Trajectory, ref: Trajectory) -> None:
    assert set(got.columns) == set(ref.columns)
    for name, col in ref.columns.items():
        assert np.array_equal(got.columns[name], col, equal_nan=True), name
    assert (got.termination, got.events) == (ref.termination, ref.events)
    for key in ("agent", "privileged", "seed", "episode_seconds", "params", "map"):
        assert got.meta[key] == ref.meta[key], key


CASES = [("pid", "loop_3x3", 1, None, None), ("pid", "loop_3x3", 4, (0.9, 0.29, 0.1), None),
         ("vision", "loop_3x3", 2, None, None), ("straight", "loop_3x3", 3, (0.3, 0.3, 0.7), None),
         ("pid-stop", "intersections", 2, None, ["left", "right"]), ("vision", "intersections", 1, None, None)]


@pytest.mark.parametrize(("agent", "map_name", "seed", "pose", "route"), CASES)
def test_robot_protocol_gives_the_in_process_trajectory(robot, sims, agent, map_name, seed, pose, route):
    camera = not make_agent(agent).privileged  # privileged agents read the lane pose, camera agents the JPEG
    ref = run_episode(sims[map_name], make_agent(agent), seed, 3.0, pose=pose, camera=camera, route=route,
                      image_filter=camera_filter(), meta={"map": map_name})
    got = run_episode_on_robot(robot, make_agent(agent), seed, 3.0, map_=map_name, pose=pose, camera=camera,
                               route=route, meta={"map": map_name})
    assert_same(got, ref)
    assert got.meta.get("route_choices") == ref.meta.get("route_choices")
    assert got.meta["source"] == "simulation" and got.meta["robot"]["kind"] == "simulation"
    assert len(got.columns["t"]) > 20
    if agent == "straight":
        assert got.termination == "off_road"  # the end is reported by the robot, at the same tick


def test_collision_on_a_map_sent_by_set_map(robot, tmp_path):
    path = tmp_path / "duckie_loop.yaml"
    base = (sim_map := Simulator("loop_3x3", PARAMS, render=False).map).path
    duckie = "objects:\n- kind: duckie\n  pos: [1.5, 2.25]\n  rotate: 0\n  height: 0.08\n"
    path.write_text(Path(base).read_text() + duckie)
    m = parse_map(path.read_text(), path=str(path), name="duckie_loop")
    assert sim_map.objects == ()
    ref = run_episode(Simulator(m, PARAMS), make_agent("pid"), 1, 4.0, camera=False)
    got = run_episode_on_robot(robot, make_agent("pid"), 1, 4.0, map_=m, camera=False)
    assert ref.termination == "collision"
    assert_same(got, ref)


def test_agent_failure_ends_the_episode_like_in_process(robot, sim):
    class Failing:
        name, privileged = "failing", False

        def __init__(self):
            self.k = 0

        def reset(self, seed, episode=None):
            self.k = 0

        def act(self, obs):
            self.k += 1
            if self.k > 5:
                raise RuntimeError("gives up")
            return np.array([0.3, 0.3])

    ref = run_episode(sim, Failing(), 1, 2.0, image_filter=camera_filter())
    got = run_episode_on_robot(robot, Failing(), 1, 2.0, map_="loop_3x3")
    assert_same(got, ref)
    assert got.termination == "agent_failure" and "gives up" in got.events[0].message


def test_run_cli_drives_an_external_robot(tmp_path):
    out = tmp_path / "run"
    res = CliRunner().invoke(app, ["run", "--agent", "vision", "--seconds", "2", "--out", str(out),
                                   "--robot-cmd", " ".join(SERVE)])
    assert res.exit_code == 0, res.output
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["source"] == "simulation" and metrics["agent"] == "vision" and metrics["termination"] == "timeout"
    assert metrics["survival_time"] == 2.0
    assert len(pd.read_parquet(out / "trajectory.parquet")) == 2 * 60 + 1
    assert (out / "drive_strip.png").stat().st_size > 0


def test_run_cli_reports_a_robot_that_fails_to_start(tmp_path):
    res = CliRunner().invoke(app, ["run", "--seconds", "1", "--out", str(tmp_path), "--robot-cmd",
                                   "/nonexistent/robot-bridge"])
    assert res.exit_code == 1 and "robot failure" in res.output and "start-failed" in res.output


def test_robot_serve_rejects_bad_params():
    res = CliRunner().invoke(app, ["robot", "serve", "--param", "wheel_distanse=0.1"])
    assert res.exit_code == 2 and "wheel_distanse" in res.output
