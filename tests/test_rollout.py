"""The episode engine: one loop for every plant and policy, one ending rule, one trajectory assembly."""

from __future__ import annotations

import numpy as np
import pytest

from proxybench.agents.simple import StraightAgent
from proxybench.domain.episode_end import end_event, ended
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.experiments.predictivity.pod import pod
from proxybench.runner.episode import SimPlant, run_episodes
from proxybench.runner.rollout import AgentPolicy, BatchPolicy, OpenLoopPolicy, rollout

SMALL = DomainParams(image_width=80, image_height=60)


def test_a_batched_policy_and_per_robot_agents_give_the_same_trajectories():
    seeds = [3, 4, 5]
    by_agents = run_episodes(Simulator("loop_3x3", SMALL, n=3), [StraightAgent(0.45) for _ in seeds], seeds, 3.0)
    batched = rollout(SimPlant(Simulator("loop_3x3", SMALL, n=3)),
                      BatchPolicy(lambda images, plant: np.full((3, 2), 0.45), 3, "straight"), seeds, 3.0)
    for a, b in zip(by_agents, batched, strict=True):
        assert a.termination == b.termination and a.events == b.events
        for name, col in a.columns.items():
            assert np.array_equal(b.columns[name], col, equal_nan=True), name
    assert {t.termination for t in batched} <= {"off_road", "timeout"}


def test_open_loop_policy_replays_its_commands_then_stops():
    cmds = np.array([[0.2, 0.3], [0.4, 0.1], [0.0, 0.5]])
    policy = OpenLoopPolicy(cmds, 2)
    policy.reset([0, 0])
    got = [policy.act(None, None, np.ones(2, dtype=bool))[0] for _ in range(4)]
    assert np.array_equal(got[1], np.array([[0.4, 0.1]] * 2)) and np.array_equal(got[3], np.zeros((2, 2)))


def test_an_agent_that_fails_ends_only_its_own_robot():
    class Breaks(StraightAgent):
        def act(self, obs):
            if obs.time > 0.5:
                raise RuntimeError("lost")
            return super().act(obs)

    trajs = rollout(SimPlant(Simulator("loop_3x3", SMALL, n=2)), AgentPolicy([Breaks(0.3), StraightAgent(0.3)]),
                    [1, 2], 1.0, camera=False)
    assert trajs[0].termination == "agent_failure" and "lost" in trajs[0].events[-1].message
    assert trajs[1].termination == "timeout" and trajs[1].duration == pytest.approx(1.0)


def test_the_ending_rule_names_what_ended_the_episode():
    sim = Simulator("loop_3x3", SMALL, render=False)
    sim.reset(0, 1, (0.3, 0.3, 0.7))
    while not ended(sim)[0]:
        sim.step(np.array([[0.6, 0.6]]))
    event = end_event(sim, 0)
    assert event.kind == "off_road" and event.t == pytest.approx(float(sim.time[0]))
    with pytest.raises(ValueError, match="not ended"):
        sim.reset(0, 1)
        end_event(sim, 0)


def test_pod_is_zero_for_the_same_domain_and_matches_two_separate_simulators():
    cmds = np.tile([0.35, 0.36], (20, 1))
    assert pod(SMALL, SMALL, "loop_3x3", cmds, seed=2) == 0.0
    other = SMALL.replace(camera_pitch=24.0, light_rgb=[1.1, 0.9, 1.0])
    sims = [Simulator("loop_3x3", p) for p in (SMALL, other)]
    pose = sims[0].sample_start(np.random.default_rng(2))
    total = 0.0
    for s in sims:
        s.reset(0, 2, pose)
    for u in cmds:  # the definition, written out: both streams, frame by frame, while both robots drive
        frames = [s.render()[0].astype(np.int16) for s in sims]
        total += float(np.abs(frames[0] - frames[1]).mean()) / 255.0
        for s in sims:
            s.step(u[None])
    assert not any(ended(s)[0] for s in sims)
    assert pod(SMALL, other, "loop_3x3", cmds, seed=2) == total / len(cmds) > 0
