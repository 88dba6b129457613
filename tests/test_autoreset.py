"""The auto-resetting plant under the engine's continuing loop: a robot whose episode ends restarts at once (next
start, next seed), per robot, while the stream goes on; the same starts give the same stream."""

from __future__ import annotations

import numpy as np
import pytest

from proxybench.domain.dynamics import ST
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator, StartDistribution
from proxybench.runner.autoreset import AutoResetPlant, Start, sim_stream
from proxybench.runner.rollout import BatchPolicy, rollout, stream

SMALL = DomainParams(image_width=32, image_height=24)
START = StartDistribution(lateral=0.05, heading=0.3, use_map_start=False)


def seeds_from(base: int):
    """``next_start``: episode e's seed is base + e, whichever robot it runs on."""
    count = iter(range(10_000))
    return lambda robot: Start(base + next(count))


def turning_and_straight(images, plant) -> np.ndarray:
    """Robot 0 turns off the road soon; robot 1 drives slowly straight on."""
    return np.array([[1.0, 0.3], [0.2, 0.2]])


def play(frames: int, episode_frames: int = 1000, policy=None, base: int = 7):
    plant = AutoResetPlant(sim_stream("loop_3x3", SMALL, 2, START), seeds_from(base), episode_frames)
    seen = []
    k = stream(plant, policy or BatchPolicy(turning_and_straight, 2, "test"), lambda: len(seen) >= frames,
               on_frame=lambda k, images, alive, p: seen.append((p.episode.copy(), p.frame.copy(),
                                                                 p.sim.state[:, :3].copy())))
    return k, plant, seen


def test_a_robot_whose_episode_ends_restarts_and_the_stream_goes_on():
    k, plant, seen = play(120)
    assert k == 120
    robots = [r for r, _ in plant.starts]
    assert robots[:2] == [0, 1] and robots.count(0) > 2  # robot 0 left the road, again and again
    assert robots.count(1) == 1  # robot 1 drove on: one episode all along, its frames counted through
    assert [f[1] for _, f, _ in seen] == list(range(120))
    assert [s.seed for _, s in plant.starts] == list(range(7, 7 + len(plant.starts)))  # next seed, in start order


def test_a_restarted_robot_starts_as_a_fresh_episode_of_its_seed():
    _, plant, seen = play(60)
    e, f, _ = seen[-1]
    seed = plant.starts[e[0]][1].seed
    back = f[0]  # frames into robot 0's latest episode: find the frame it began at
    fresh = Simulator("loop_3x3", SMALL, start=START)
    fresh.reset(0, seed)
    assert np.array_equal(seen[-1 - back][2][0], fresh.state[0, [ST.X, ST.Y, ST.THETA]])


def test_episodes_end_when_their_frames_are_spent():
    _, plant, seen = play(23, episode_frames=5, policy=BatchPolicy(lambda im, p: np.full((2, 2), 0.2), 2))
    assert [f.tolist() for _, f, _ in seen[:7]] == [[0, 0], [1, 1], [2, 2], [3, 3], [4, 4], [0, 0], [1, 1]]
    assert [r for r, _ in plant.starts] == [0, 1] * 5  # a new episode every 5 frames, robot 0 first


def test_a_failing_driver_ends_only_its_own_robots_episode():
    class FailsRobot1(BatchPolicy):
        """Robot 1's driver fails once, at the 4th frame of its first episode."""

        def act(self, plant, images, alive):
            commands, _ = super().act(plant, images, alive)
            return commands, ({1: RuntimeError("no label")} if plant.frame[1] == 3 and plant.episode[1] == 1 else {})

    _, plant, seen = play(10, policy=FailsRobot1(lambda im, p: np.full((2, 2), 0.2), 2))
    assert [f.tolist() for _, f, _ in seen] == [[i, i if i <= 3 else i - 4] for i in range(10)]
    assert [r for r, _ in plant.starts] == [0, 1, 1]


def test_the_same_starts_give_the_same_stream():
    a, b = play(40)[2], play(40)[2]
    for (ea, fa, pa), (eb, fb, pb) in zip(a, b, strict=True):
        assert np.array_equal(ea, eb) and np.array_equal(fa, fb) and np.array_equal(pa, pb)
    c = play(40, base=8)[2]
    assert not np.array_equal(a[0][2], c[0][2])


def test_a_plant_of_one_robot_restarts_by_beginning_again():
    class OneRobot:
        """A plant of one robot without per-robot restarts (as a robot node's): each episode ends after 3 frames."""

        n, map, frame_rate = 1, None, 10.0

        def __init__(self):
            self.calls = []

        def begin(self, seeds, poses, routes, seconds, camera, privileged):
            self.calls.append(("begin", seeds[0], poses[0], seconds))
            self.k = 0
            return 100

        def frames(self, alive):
            return [np.zeros((2, 2, 3), np.uint8)]

        def time(self, i):
            return self.k / 10.0

        def advance(self, commands, alive, k):
            assert k == self.k
            self.k += 1
            from proxybench.tasks.trajectory import Event
            return [(0, Event(self.k / 10.0, "off_road", "gone"), True)] if self.k == 3 else []

        def end(self):
            self.calls.append(("end",))

    inner = OneRobot()
    count = iter(range(100))
    plant = AutoResetPlant(inner, lambda r: Start(next(count), pose=(1.0, 2.0, 0.0)), 20)
    assert stream(plant, BatchPolicy(lambda im, p: np.zeros((1, 2)), 1), lambda: len(plant.starts) > 3) == 9
    assert inner.calls == [("begin", 0, (1.0, 2.0, 0.0), 2.0), ("end",), ("begin", 1, (1.0, 2.0, 0.0), 2.0), ("end",),
                           ("begin", 2, (1.0, 2.0, 0.0), 2.0), ("end",), ("begin", 3, (1.0, 2.0, 0.0), 2.0), ("end",)]
    with pytest.raises(ValueError, match="θ is its own"):
        AutoResetPlant(OneRobot(), lambda r: Start(0, params=SMALL), 20).open(True, [False])


def test_an_auto_resetting_plant_is_streamed_not_rolled_out():
    plant = AutoResetPlant(sim_stream("loop_3x3", SMALL, 1, START), seeds_from(0), 10)
    with pytest.raises(TypeError, match=r"rollout\.stream"):
        rollout(plant, BatchPolicy(lambda im, p: np.zeros((1, 2)), 1), [0], 1.0)
