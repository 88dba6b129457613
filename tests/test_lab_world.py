"""A lab's shared world (issue 36 item 3, runner/lab_world.py): the virtual robots of one lab on one floor, stepped in
lock-step, each job's episodes on their own clock, the collision rule of docs/autolab.md. No agents' packages here:
zoo agents drive (tests/test_autolab_robots.py runs SDK jobs in a shared world)."""

from __future__ import annotations

import secrets
import threading
from pathlib import Path

import numpy as np
import pytest

from proxybench.domain.params import DomainParams
from proxybench.runner.lab_world import (
    CONTACT_EVENT,
    LabWorld,
    LabWorldAddress,
    LabWorldPlant,
    LabWorldSpec,
    connect,
    serve,
)
from proxybench.tasks.trajectory import Termination

A_START = (1.0, 0.3, 0.0)  # on loop_3x3's bottom straight, heading east
B_AHEAD = (1.4, 0.3, 0.0)  # 40 cm ahead of it, in its lane


@pytest.fixture(scope="module")
def world() -> LabWorld:
    return LabWorld(LabWorldSpec("loop_3x3", ("db1", "db2"), (410, 411)))


def _drive(world: LabWorld, a: np.ndarray, b: np.ndarray, frames: int = 60):
    """Step both robots with fixed commands until either's episode ends; the two last replies' histories."""
    got: dict[str, list] = {"db1": [], "db2": []}
    for _ in range(frames):
        world.command("db1", a)
        world.command("db2", b)
        for name, reply in world.step().items():
            got[name].append(reply)
        if any(r[-1].ended is not None for r in got.values()):
            break
    return got


def test_a_robot_driving_into_a_standing_one_is_at_fault_and_the_other_run_is_invalid(world: LabWorld) -> None:
    p = DomainParams()
    world.begin("db1", p, 1, A_START, None, False, None)
    world.begin("db2", p, 2, B_AHEAD, None, False, None)
    got = _drive(world, np.array([0.5, 0.5]), np.zeros(2))
    a_end = got["db1"][-1].ended
    assert a_end is not None and a_end.kind is Termination.COLLISION and "robot 'db2'" in a_end.message
    b_events = [e for r in got["db2"] for e in r.events]
    assert [e.kind for e in b_events] == [CONTACT_EVENT] and "robot 'db1' ran into this robot" in b_events[0].message
    assert got["db2"][-1].ended is None  # the innocent robot's episode goes on; the evaluator re-runs it
    world.end("db1")
    world.end("db2")


def test_a_head_on_contact_ends_both_as_collisions(world: LabWorld) -> None:
    p = DomainParams()
    world.begin("db1", p, 1, A_START, None, False, None)
    world.begin("db2", p, 2, (1.5, 0.3, np.pi), None, False, None)
    got = _drive(world, np.array([0.5, 0.5]), np.array([0.5, 0.5]))
    assert [got[n][-1].ended.kind for n in ("db1", "db2")] == [Termination.COLLISION] * 2
    assert not [e for r in got["db1"] + got["db2"] for e in r.events]
    world.end("db1")
    world.end("db2")


def test_the_robots_see_each_other_and_watchtowers_see_each_under_its_own_roof_tag(world: LabWorld) -> None:
    from proxybench.domain.fixed_cameras import FixedCamera, FixedCameraRig
    from proxybench.domain.objects import robot_primitives

    p = DomainParams()
    alone = world.begin("db1", p, 1, A_START, None, True, None).camera
    world.end("db1")
    world.begin("db2", p, 2, B_AHEAD, None, False, None)
    seen = world.begin("db1", p, 1, A_START, None, True, None).camera
    assert np.abs(seen.astype(int) - alone.astype(int)).mean() > 1.0  # db2 stands in db1's view
    rig = FixedCameraRig(world.sim, [FixedCamera("wt", 1.2, 0.3, 2.0, 0.0, 80.0, 64, 48)])
    tags = set(rig.world_primitives(0)[:, 9]) - set(robot_primitives(400)[:, 9])
    assert {robot_primitives(t)[1, 9] for t in (410, 411)} <= tags
    world.end("db1")
    world.end("db2")


def test_a_start_taken_by_an_idle_robot_parks_it_and_one_taken_by_a_driving_robot_waits(world: LabWorld) -> None:
    p = DomainParams()
    world.begin("db2", p, 2, A_START, None, False, None)
    world.end("db2")  # db2 stands on the start, idle
    assert not isinstance(world.begin("db1", p, 1, A_START, None, False, None), str)
    assert world.sim.state[world.robots["db2"].index, 1] < -10  # lifted off the floor
    assert world.begin("db2", p, 2, A_START, None, False, None) == "db1"  # db1 drives there: db2 waits
    world.end("db1")


def test_a_robot_that_misses_the_step_deadline_is_dropped_and_the_other_goes_on() -> None:
    world = LabWorld(LabWorldSpec("loop_3x3", ("db1", "db2"), (410, 411), step_deadline_s=0.01))
    p = DomainParams()
    world.begin("db1", p, 1, A_START, None, False, None)
    world.begin("db2", p, 2, (0.3, 1.0, np.pi / 2), None, False, None)
    world.command("db1", np.zeros(2))
    world.command("db2", np.zeros(2))
    world.step()  # both in lock-step now
    world.command("db1", np.array([0.3, 0.3]))
    assert world.waiting_for() == ["db2"] and not world.due(now=world.round_start)
    assert world.due(now=world.round_start + 1.0)
    out = world.step()
    assert list(out) == ["db1"] and out["db1"].ended is None
    dropped = world.robots["db2"].ended
    assert dropped.kind is Termination.AGENT_FAILURE and "step deadline" in dropped.message
    world.command("db1", np.array([0.3, 0.3]))
    assert world.due() and list(world.step()) == ["db1"]  # db1 no longer waits for db2


def test_two_jobs_drive_one_world_at_once_each_on_its_own_clock(tmp_path: Path) -> None:
    """Two plants (two workers' jobs) through the world's server, at once: both episodes whole, their watchtower
    streams written per episode, the trajectories start at t = 0."""
    from proxybench.domain.fixed_cameras import FixedCamera
    from proxybench.protocol.failures import RobotFailure
    from proxybench.runner.episode import run_episodes  # noqa: F401 - the engine is imported before the threads
    from proxybench.runner.robot_episode import run_episode_on_plant
    from proxybench.runner.streams import StreamSpec

    agents = pytest.importorskip("proxybench.agents.zoo")
    cams = (FixedCamera("wt1", 1.5, 0.3, 2.5, 0.0, 80.0, 64, 48),)
    spec = LabWorldSpec("loop_3x3", ("db1", "db2"), (410, 411), StreamSpec(cams, (5.0,), (0.0,)))
    address = LabWorldAddress(str(tmp_path / "world.sock"), secrets.token_bytes(16))
    ready, stop = threading.Event(), threading.Event()
    server = threading.Thread(target=serve, args=(spec, address, ready, stop), daemon=True)
    server.start()
    assert ready.wait(120)
    with pytest.raises(RobotFailure, match=r"robot 'db9': not a robot of this lab \(it has db1, db2\)"):
        connect(address, "db9")
    starts = {"db1": 3, "db2": 11}  # seeds: starts drawn apart on the loop
    out: dict[str, object] = {}

    def job(name: str) -> None:
        conn = connect(address, name)
        plant = LabWorldPlant(conn, name, "loop_3x3", DomainParams(frame_rate=10.0), tmp_path / name)
        out[name] = run_episode_on_plant(plant, agents.make_agent("pid"), starts[name], 1.0, camera=False)
        conn.close()

    threads = [threading.Thread(target=job, args=(n,)) for n in starts]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    stop.set()
    server.join(30)
    for name in starts:
        traj = out[name]
        assert traj.termination is Termination.TIMEOUT and traj.meta["lab_world"]["robot"] == name
        assert traj["t"][0] == 0.0 and traj["t"][-1] == pytest.approx(1.0)
        assert (tmp_path / name / "0" / "wt1" / "timestamps.csv").is_file()
