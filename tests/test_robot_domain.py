"""A robot node is a domain kind of the runner: same jobs, results, trajectories, cache and resume."""

from __future__ import annotations

import json
import math
import shlex
import sys
from pathlib import Path

import numpy as np
import pytest

from proxybench.domain.params import DomainParams
from proxybench.runner.backends import LocalBackend
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job, ProtocolLink, RobotDomain
from proxybench.runner.robot_jobs import robot_slot
from proxybench.runner.sweep import run_jobs
from proxybench.tasks.trajectory import Trajectory

HERE = Path(__file__).resolve().parent
SMALL = {"image_width": 80, "image_height": 60}
SERVE = shlex.join([sys.executable, "-m", "proxybench.cli", "robot", "serve", "--param", "image_width=80",
                    "--param", "image_height=60"])
MISBEHAVE = shlex.join([sys.executable, str(HERE / "protocol_agents" / "misbehave_robot.py")])
METRICS = ("survival_time", "driven_lanedir_consec", "deviation_center_line")


def _jobs(domain: DomainSpec, agents=("pid", "vision"), episodes=2, seconds=3.0) -> list[Job]:
    poses = [None, (0.9, 0.29, 0.1)]
    return [Job(AgentSpec(a), domain, "loop_3x3", e, 20 + e, seconds, pose=poses[e % 2], metrics=METRICS)
            for a in agents for e in range(episodes)]


def test_spec_rejects_what_a_robot_domain_cannot_be():
    with pytest.raises(ValueError, match=r"command \(the robot node to start\) must be a non-empty string"):
        DomainSpec.robot(" ", frame_rate=15)
    with pytest.raises(ValueError, match=r"a robot is DomainSpec\.robot"):
        DomainSpec("r", DomainParams(trim=0.1), kind="robot")
    with pytest.raises(TypeError, match="unexpected keyword argument 'params'"):  # θ is the robot's own
        RobotDomain("r", ProtocolLink("x"), params=DomainParams(trim=0.1))
    with pytest.raises(TypeError, match="a simulated domain, not command"):
        DomainSpec("s", command="x")
    with pytest.raises(ValueError, match="kind must be one of"):
        DomainSpec("s", kind="real")
    with pytest.raises(ValueError, match="nodes must be"):
        DomainSpec.robot("x", frame_rate=15, nodes=0)
    assert DomainSpec.robot("x", frame_rate=15).params is None


def test_the_command_is_part_of_the_key_and_simulated_keys_did_not_change():
    a, b = (DomainSpec.robot(cmd, frame_rate=15, name="r") for cmd in ("bridge --robot 1", "bridge"))
    job = _jobs(a)[0]
    assert job.key != Job(job.agent, b, job.map, job.episode, job.seed, job.duration, job.pose,
                          metrics=job.metrics).key
    small = DomainParams(**SMALL)  # θ in the key exactly as the dict of its fields was before it was typed
    assert DomainSpec("s", small).canonical() == json.dumps({"kind": "simulation",
                                                             "params": small.model_dump(mode="json")}, sort_keys=True)


def test_robot_domain_equals_the_in_process_run_and_resumes_from_the_cache(tmp_path):
    sim = run_jobs(_jobs(DomainSpec("small", DomainParams(**SMALL))), tmp_path / "sim")
    robot_dom = DomainSpec.robot(SERVE, frame_rate=15, name="robot")
    got = run_jobs(_jobs(robot_dom), tmp_path / "robot", batch_size=3)  # two node processes, one after another
    assert got.ran == 4 and got.cached == 0
    for r, ref in zip(got.results, sim.results, strict=True):
        assert (r.agent, r.episode, r.termination, r.message) == (ref.agent, ref.episode, ref.termination, "")
        assert r.scores == pytest.approx(ref.scores, rel=0, abs=0), r.agent
        a, b = Trajectory.load(r.trajectory), Trajectory.load(ref.trajectory)
        for name, col in b.columns.items():
            assert np.array_equal(a.columns[name], col, equal_nan=True), name
        assert a.meta["domain_kind"] == "robot" and a.meta["source"] == "simulation"  # what the robot says
        assert a.meta["robot"]["command"] == SERVE
    assert got.results[0].scores["survival_time"] == 3.0
    again = run_jobs(_jobs(robot_dom), tmp_path / "robot")
    assert again.ran == 0 and again.cached == 4
    assert [r.scores for r in again.results] == [r.scores for r in got.results]


def test_a_robot_that_fails_is_each_jobs_result_and_is_retried_next_time(tmp_path):
    dom = DomainSpec.robot("/nonexistent/robot-bridge", frame_rate=15, name="broken")
    jobs = _jobs(dom, agents=("straight",), episodes=3, seconds=0.5)
    res = run_jobs(jobs, tmp_path)
    assert [r.termination for r in res.results] == ["robot_failure"] * 3
    assert "start-failed" in res.results[0].message and "not run" in res.results[2].message
    assert all(math.isnan(v) for v in res.results[0].scores.values())
    assert not list((tmp_path / "episodes").glob("*.json"))  # not cached: the next run tries again
    assert run_jobs(jobs, tmp_path).ran == 3


def test_a_robot_crashing_mid_batch_costs_one_episode_and_is_restarted(tmp_path):
    # the misbehaving robot crashes at its first get_robot_state: every episode fails, the node is restarted
    # once after the first failure, and after two failures in a row the batch gives up
    dom = DomainSpec.robot(MISBEHAVE + " crash get_robot_state", frame_rate=15, name="crashy")
    res = run_jobs(_jobs(dom, agents=("straight",), episodes=3, seconds=0.2), tmp_path)
    terms = [r.termination for r in res.results]
    assert terms == ["robot_failure"] * 3
    assert "exited" in res.results[0].message and "boom" in res.results[0].message
    assert "2 times in a row" in res.results[2].message


def test_privileged_agent_on_a_robot_without_ground_truth_is_refused_not_crashed(tmp_path):
    dom = DomainSpec.robot(MISBEHAVE + " none never", frame_rate=15, name="no-truth")
    res = run_jobs(_jobs(dom, agents=("pid", "straight"), episodes=1, seconds=0.4), tmp_path)
    pid, straight = res.results
    assert pid.termination == "agent_failure" and "reports no true lane pose" in pid.message
    assert straight.termination == "timeout" and Trajectory.load(straight.trajectory).meta["source"] == "robot"


def test_robot_jobs_run_on_a_process_pool_one_node_at_a_time(tmp_path):
    dom = DomainSpec.robot(SERVE, frame_rate=15, name="robot")
    backend = LocalBackend(2)
    try:
        res = run_jobs(_jobs(dom, agents=("pid", "straight"), seconds=1.0), tmp_path, backend)
    finally:
        backend.close()
    assert res.ran == 4 and {r.termination for r in res.results} <= {"timeout", "off_road"}


def test_robot_slots_exclude_each_other():
    with robot_slot("cmd-under-test", 2) as a, robot_slot("cmd-under-test", 2) as b:
        assert {a, b} == {0, 1}
