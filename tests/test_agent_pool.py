"""The larger agent pool (issue 35 item 3): the independently written agents drive, and the zoo holds at least
30 agents of distinct behaviour in at least 6 families."""

from __future__ import annotations

import numpy as np
import pytest

from proxybench.agents import ZOO, make_agent
from proxybench.agents.families import (
    DEFAULT_FAMILY,
    FAMILY_CONCEPTS,
    ZOO_FAMILIES,
    family_map,
    family_of,
    pool_families,
    split_family_prefix,
)
from proxybench.agents.independent import INDEPENDENT
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.runner import run_episode
from proxybench.runner.backends import InlineBackend
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
from proxybench.runner.sweep import run_jobs
from proxybench.tasks.trajectory import Termination

NEW = [name for name, _, _ in INDEPENDENT]
PARAMS = DomainParams(image_width=160, image_height=120)
#: zoo agents that equal another on a map without stop lines (the "-stop" variants) — not distinct there
_SAME_ON_A_LOOP = {"pid-stop", "pure-pursuit-stop"}


@pytest.mark.parametrize("name", NEW)
def test_each_new_agent_drives_a_short_episode_with_finite_commands(name: str) -> None:
    agent = make_agent(name)
    traj = run_episode(Simulator("loop_3x3", PARAMS), agent, 3, 4.0, allow_privileged=agent.privileged)
    assert traj.termination != Termination.AGENT_FAILURE, traj.events
    pwm = np.stack([traj["pwm_left"], traj["pwm_right"]], 1)
    assert np.isfinite(pwm).all() and (np.abs(pwm) <= 1.0).all()
    assert np.abs(pwm).max() > 0.05  # it drives
    assert family_of(name) in FAMILY_CONCEPTS and family_of(name) not in ("other", "node", "learned")


@pytest.mark.parametrize("name", [n for n in NEW if not make_agent(n).privileged])
def test_camera_agents_never_read_the_true_pose(name: str) -> None:
    """Camera agents run where ground truth is refused, and their concept says camera."""
    traj = run_episode(Simulator("loop_3x3", PARAMS), make_agent(name), 5, 3.0, allow_privileged=False)
    assert traj.termination != Termination.AGENT_FAILURE, traj.events
    assert FAMILY_CONCEPTS[family_of(name)].startswith("camera")


def test_the_pool_holds_30_distinct_agents_in_6_families(tmp_path) -> None:
    """Every zoo agent on one seed through the runner's jobs: their lane scores and distances differ."""
    names = [n for n in ZOO if n not in _SAME_ON_A_LOOP]
    dom = DomainSpec("pool", PARAMS)
    jobs = [Job(AgentSpec(n), dom, "loop_3x3", 0, 7, 8.0, metrics=("lane_score", "driven_lanedir_consec"))
            for n in names]
    res = run_jobs(jobs, tmp_path, InlineBackend(), keep_trajectories=False)
    scores = {r.agent: (round(r.scores["lane_score"], 6), round(r.scores["driven_lanedir_consec"], 6))
              for r in res.results}
    assert set(scores) == set(names)
    distinct = set(scores.values())
    assert len(distinct) >= 30, sorted(scores.items(), key=lambda kv: kv[1])
    assert len({s[0] for s in scores.values()}) >= 6  # the lane score alone is not all equal either
    assert len(pool_families(names)) >= 6
    new_families = {family_of(n) for n in NEW}
    assert len(new_families) >= 6 and new_families.isdisjoint({"pid", "pursuit", "vision", "trivial"})


def test_every_zoo_agent_has_a_declared_family() -> None:
    assert set(ZOO) <= set(ZOO_FAMILIES)
    assert set(ZOO_FAMILIES.values()) <= set(FAMILY_CONCEPTS)
    for name, family in ZOO_FAMILIES.items():
        camera = FAMILY_CONCEPTS[family].startswith("camera")
        assert not (camera and ZOO[name].privileged), name  # a camera family holds no privileged agent


def test_agents_outside_the_zoo_get_a_family_from_a_prefix_or_their_kind() -> None:
    assert family_of("lqr:runs/net.pt") == "lqr"
    assert split_family_prefix("lqr:runs/net.pt") == ("lqr", "runs/net.pt")
    assert family_of("runs/bc-1-0.pt") == "learned"
    assert family_of("vision-node={python} -m proxybench.protocol vision") == "vision"  # the vision agent, as a node
    assert family_of("pid=python3 -m proxybench.protocol pid") == "pid"
    assert family_of("mine=python3 solution.py --x a:b") == "node"
    assert family_of("mine=sdk[lane]:python3 solution.py") == "node"
    assert family_of("package.module:Class") == DEFAULT_FAMILY
    assert family_map(["pid", "hough"]) == {"pid": "pid", "hough": "hough"}
