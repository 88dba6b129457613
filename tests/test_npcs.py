"""NPC robots, pedestrians and per-episode worlds: motion, camera, collisions, batching, benchmark files."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from proxybench.agents import make_agent
from proxybench.agents.simple import StraightAgent
from proxybench.domain.camera import camera_table
from proxybench.domain.lane_pose import point_on_road
from proxybench.domain.maps import MapObject, load_map
from proxybench.domain.npcs import NpcRobot, Pedestrian, Traffic, pedestrian_positions
from proxybench.domain.params import DomainParams, ParamSpace
from proxybench.domain.simulator import Simulator
from proxybench.runner.episode import run_episode, run_episodes
from proxybench.tasks.benchmark import Benchmark, BenchmarkError

TS = 0.585
LANE_Y = 1.28 * TS  # eastbound right-lane centre of straight_road
POSE = (1.0, LANE_Y, 0.0)
BASE = DomainParams(image_width=160, image_height=120, texture_noise=0.0, blur_time=0.0)
SMALL = DomainParams(image_width=80, image_height=60)
STRAIGHT = load_map("straight_road")
AHEAD = (POSE[0] + 0.5, LANE_Y, 0.0)  # 0.5 m ahead of POSE in the same lane
CAM_X = POSE[0] + BASE.camera_forward
PARKED = NpcRobot(pose=AHEAD, speed_scale=0.0)  # its driver's commands are multiplied by 0: it stands still
TRAFFIC = Traffic(robots=(NpcRobot(ahead=0.8), NpcRobot(driver="pure-pursuit")),
                  pedestrians=(Pedestrian(((0.88, 0.70), (0.88, -0.08)), speed=0.15, delay=1.0),))


def frame(m=STRAIGHT, npcs=None, params=BASE, pose=POSE):
    sim = Simulator(m, params, npcs=npcs)
    sim.reset(0, 0, pose=pose)
    return sim.render()[0]


def positions(traj) -> np.ndarray:
    return np.stack([traj["x"], traj["y"], traj["theta"]], axis=1)


# -- pedestrians ----------------------------------------------------------------------------------


def test_pedestrian_paths_are_functions_of_time():
    path = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0))  # 2 m long, 1 + √2 m back to the start
    at = {mode: [pedestrian_positions([Pedestrian(path, 0.5, delay=1.0, mode=mode)], t)[0].round(6).tolist()
                 for t in (0.5, 2.0, 4.0, 6.0, 7.0)] for mode in ("loop", "back-and-forth", "once")}
    assert at["once"] == [[0.0, 0.0], [0.5, 0.0], [1.0, 0.5], [1.0, 1.0], [1.0, 1.0]]  # waits, walks, stays
    assert at["back-and-forth"][3:] == [[1.0, 0.5], [1.0, 0.0]]  # turned round at the end
    s = 3.0 - 2.0  # loop at t = 7: 3 m walked, 1 m along the closing leg from (1, 1) towards (0, 0)
    assert at["loop"][4] == pytest.approx([1.0 - s / math.sqrt(2), 1.0 - s / math.sqrt(2)], abs=1e-6)
    assert pedestrian_positions([Pedestrian(path, 0.5)], 2.0, scale=0.5)[0].tolist() == [0.5, 0.0]
    assert pedestrian_positions([Pedestrian(((2.0, 3.0),), 1.0)], 9.0)[0].tolist() == [2.0, 3.0]


# -- camera ---------------------------------------------------------------------------------------


def test_npc_robot_looks_like_a_duckiebot_and_hides_the_lane_line_behind_it():
    line_y = LANE_Y + 0.22 * TS  # the yellow centre line: the camera looks along it at an NPC standing on it
    ego, npc = (POSE[0], line_y, 0.0), (POSE[0] + 0.35, line_y, 0.0)
    empty = frame(pose=ego)
    img = frame(npcs=Traffic(robots=(NpcRobot(pose=npc, speed_scale=0.0),)), pose=ego)
    static = frame(dataclasses.replace(STRAIGHT, objects=(MapObject("duckiebot", *npc[:2]),)), pose=ego)
    # drawn like the static duckiebot object at its pose, plus its roof tag (a few pixels of its top face)
    differ = np.any(img != static, axis=-1)
    assert 0 < differ.sum() < 60 and np.all(np.abs(img[differ].astype(int) - static[differ]) > 0)
    table = camera_table(BASE)
    im, em = img.astype(int), empty.astype(int)
    yellow = (em[..., 0] > 150) & (em[..., 1] > 120) & (em[..., 2] < 100)
    ratio = (table.gx - BASE.camera_forward) / (npc[0] - ego[0] - BASE.camera_forward)  # distance / the NPC's
    behind = yellow & ~table.sky & (np.abs(table.gy) < 0.04 * ratio) & (table.gx > npc[0] - ego[0] + 0.1)
    assert behind.sum() > 5  # centre-line pixels on the ground behind it, inside its silhouette ...
    assert not ((im[..., 0] > 150) & (im[..., 1] > 120) & (im[..., 2] < 100))[behind].any()  # ... are hidden
    body = np.all(np.abs(im - [30, 40, 90]) < 60, axis=-1) & (np.abs(im - em).sum(axis=-1) > 30)
    assert body.sum() > 200  # by its dark-blue body
    near = np.flatnonzero(np.all(table.gx < npc[0] - ego[0] - 0.15, axis=1) & ~table.sky.any(axis=1))
    assert near.size > 10 and np.array_equal(img[near], empty[near])  # rows of road in front of it are untouched


def test_pedestrians_and_extra_duckies_look_like_duckies_in_camera_and_top_down():
    spot = (POSE[0] + 0.3, LANE_Y + 0.05)
    waiting = Traffic(pedestrians=(Pedestrian((spot, (spot[0], 0.0)), 0.2, delay=60.0),))  # not set off yet
    duckie = frame(dataclasses.replace(STRAIGHT, objects=(MapObject("duckie", *spot),)))
    assert np.array_equal(frame(npcs=waiting), duckie) and not np.array_equal(duckie, frame())
    from proxybench.domain.topdown import top_down

    sim = Simulator(STRAIGHT, SMALL.replace(extra_duckies=3),
                    npcs=Traffic(robots=(PARKED,), pedestrians=waiting.pedestrians))
    objects, npc_poses = sim.world_view(0)
    assert len(objects) == 4 and np.allclose(npc_poses, [AHEAD])
    img = top_down(sim.map, sim.state[:, :3], px_per_tile=64, params=sim.params[0], objects=objects,
                   npc_poses=npc_poses).astype(int)
    scale = 64 / TS
    u, v = int(spot[0] * scale), img.shape[0] - int(spot[1] * scale)
    assert np.abs(img[v, u] - [240, 200, 20]).max() < 40  # the waiting duckie
    u, v = int(AHEAD[0] * scale), img.shape[0] - int(AHEAD[1] * scale)
    assert np.abs(img[v, u] - [30, 40, 90]).max() < 40  # the NPC robot, in the duckiebot colour


def test_each_robot_sees_and_hits_only_its_own_world():
    sim = Simulator(STRAIGHT, BASE, n=2, npcs=[Traffic(robots=(PARKED,)), Traffic()])
    for i in range(2):
        sim.reset(i, 0, pose=POSE)
    frames = sim.render()
    assert not np.array_equal(frames[0], frames[1])
    assert np.array_equal(frames[1], frame())
    for _ in range(40):  # both drive straight on: robot 0 into its NPC, robot 1 through the empty spot
        sim.step(np.full((2, 2), 0.5), npc_commands=np.full((1, 2), 0.5))
    assert sim.collided.tolist() == [True, False] and sim.hit_kind[0] == 4


# -- collisions -----------------------------------------------------------------------------------


def test_driving_into_an_npc_robot_ends_the_episode_with_collision():
    sim = Simulator(STRAIGHT, SMALL, npcs=Traffic(robots=(PARKED,)))
    traj = run_episode(sim, StraightAgent(0.5), 0, 6.0, pose=POSE, camera=False)
    assert traj.termination == "collision" and traj.duration < 3.0
    hit = [e for e in traj.events if e.kind == "collision"]
    assert hit[0].with_ == "robot"
    gap = math.hypot(traj["x"][-1] - AHEAD[0], traj["y"][-1] - AHEAD[1])
    assert 0.13 < gap < 0.15  # stopped at the first tick within 0.15 m of its centre
    assert any(e.kind == "npc_stopped" and "hit a robot" in e.message for e in traj.events)
    assert traj.meta["npcs"]["robots"][0]["speed_scale"] == 0.0


def test_a_crossing_pedestrian_ends_the_episode_a_waiting_one_does_not():
    crossing = ((POSE[0] + 0.6, LANE_Y - 0.35), (POSE[0] + 0.6, LANE_Y + 0.35))
    for delay, ending in ((0.0, "collision"), (30.0, "timeout")):
        sim = Simulator(STRAIGHT, SMALL, npcs=Traffic(pedestrians=(Pedestrian(crossing, 0.2, delay),)))
        traj = run_episode(sim, StraightAgent(0.5), 0, 4.0, pose=POSE, camera=False)
        assert traj.termination == ending
        if ending == "collision":
            assert traj.events[-1].with_ == "pedestrian"


def test_an_npc_that_leaves_the_road_stops_for_good():
    off = NpcRobot(driver="straight", pose=(POSE[0] + 1.0, LANE_Y, math.pi / 2))  # heads across the road
    sim = Simulator(STRAIGHT, SMALL, npcs=Traffic(robots=(off,)))
    traj = run_episode(sim, make_agent("pid"), 0, 5.0, pose=POSE, camera=False)
    assert sim.npc_stopped.tolist() == [True] and abs(sim.npc_state[0, 3]) < 0.01  # stopped, standing
    stop = [e for e in traj.events if e.kind == "npc_stopped"]
    assert len(stop) == 1 and "left the road" in stop[0].message and stop[0].t < 2.0
    assert traj.termination == "timeout"  # stranded beside the road, it is in nobody's way


# -- determinism and batching ---------------------------------------------------------------------


def test_npc_motion_is_deterministic_given_the_seed():
    def run(seed):
        sim = Simulator("loop_3x3", SMALL, npcs=TRAFFIC)
        traj = run_episode(sim, make_agent("pid"), seed, 3.0, camera=False)
        return sim.npc_state.copy(), positions(traj)

    a, b, c = run(7), run(7), run(8)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.allclose(a[0][:, :2], c[0][:, :2])  # another seed places them elsewhere
    assert np.linalg.norm(a[0][:, :2] - run_start(7)[:, :2], axis=1).min() > 0.3  # and they drove


def run_start(seed: int) -> np.ndarray:
    sim = Simulator("loop_3x3", SMALL, npcs=TRAFFIC, render=False)
    sim.reset(0, seed)
    return sim.npc_state.copy()


def test_a_batch_with_npcs_equals_single_runs():
    traffic = dataclasses.replace(TRAFFIC, robots=(*TRAFFIC.robots, NpcRobot(driver="vision", tile=(1, 2))))
    seeds = [3, 4, 5]
    batch = run_episodes(Simulator("loop_3x3", SMALL, n=3, npcs=traffic), [make_agent("pid") for _ in seeds],
                         seeds, 3.0, camera=False)
    for seed, tb in zip(seeds, batch, strict=True):
        ts = run_episode(Simulator("loop_3x3", SMALL, npcs=traffic), make_agent("pid"), seed, 3.0, camera=False)
        assert np.array_equal(positions(tb), positions(ts))
        assert tb.termination == ts.termination and tb.events == ts.events


# -- domain parameters ----------------------------------------------------------------------------


def test_object_parameters_default_to_nothing_added():
    p = DomainParams()
    assert (p.extra_duckies, p.npc_speed_scale, p.duckie_rgb) == (0, 1.0, (240.0, 200.0, 20.0))
    assert not Simulator("loop_3x3", SMALL, render=False).worlds.active


def test_extra_duckies_stand_beside_the_road_per_robot_and_follow_object_seed():
    p = SMALL.replace(extra_duckies=6)
    sim = Simulator("loop_3x3", [p, SMALL, p.replace(object_seed=1)], render=False)
    spots = [sim.world_view(i)[0][:, 1:3] for i in range(3)]
    assert [len(s) for s in spots] == [6, 0, 6] and not np.allclose(spots[0], spots[2])
    a = sim.arrays
    for x, y in spots[0]:
        assert not point_on_road(x, y, a.tile_kind, a.curve_corner, a.tile_size)
        near = [point_on_road(x + 0.25 * math.cos(t), y + 0.25 * math.sin(t), a.tile_kind, a.curve_corner,
                              a.tile_size) for t in np.linspace(0, 2 * math.pi, 16)]
        assert any(near)  # within 25 cm of the road
    again = Simulator("loop_3x3", p, render=False).world_view(0)[0][:, 1:3]
    assert np.array_equal(again, spots[0])
    space = ParamSpace.from_dict({"extra_duckies": {"uniform": [0, 10]}})
    assert all(isinstance(space.sample(np.random.default_rng(k)).extra_duckies, int) for k in range(5))


def test_duckie_colour_follows_the_params():
    m = dataclasses.replace(STRAIGHT, objects=(MapObject("duckie", POSE[0] + 0.4, LANE_Y),))
    blue = frame(m, params=BASE.replace(duckie_rgb=(20.0, 40.0, 240.0))).astype(int)
    yellow = frame(m).astype(int)
    assert ((blue[..., 2] > 150) & (blue[..., 0] < 80)).sum() > 50
    assert ((yellow[..., 2] > 150) & (yellow[..., 0] < 80)).sum() == 0


def test_npc_speed_scale_scales_npc_robots_and_pedestrians():
    def moved(scale):
        npcs = Traffic(robots=(NpcRobot(pose=AHEAD),), pedestrians=(Pedestrian(((0.5, 0.2), (3.0, 0.2)), 0.2),))
        sim = Simulator(STRAIGHT, SMALL.replace(npc_speed_scale=scale), npcs=npcs)
        run_episode(sim, make_agent("pid"), 0, 3.0, pose=(3.0, LANE_Y, 0.0), camera=False)
        ped = sim.world_view(0)[0][0, 1] - 0.5
        return sim.npc_state[0, 0] - AHEAD[0], ped

    (r1, p1), (r2, p2) = moved(1.0), moved(0.5)
    assert 0.4 < r2 / r1 < 0.6 and p2 / p1 == pytest.approx(0.5)


# -- benchmark files ------------------------------------------------------------------------------


def test_npc_schema_errors_name_the_field(tmp_path):
    import yaml

    import proxybench

    data = yaml.safe_load((Path(proxybench.__file__).parent / "benchmarks" / "aido_lfv.yaml").read_text())
    cases = [
        ({"kind": "duckiebot", "agent": "pdi"}, "npcs.0.duckiebot.agent: unknown agent 'pdi'"),
        ({"kind": "duckiebot", "speed_scal": 1.0}, "npcs.0.duckiebot.speed_scal: unknown key (did you mean speed_sc"),
        ({"kind": "duckiebot", "start": {"tile": [1, 1], "ahead": 1.0}}, "npcs.0.duckiebot.start: give one of"),
        ({"kind": "duckiebot", "start": {"tile": [1, 1]}}, "npcs.0.duckiebot.start.tile: [1, 1] has no lanes"),
        ({"kind": "duckiebot", "start": "anywhere"}, "npcs.0.duckiebot.start: 'anywhere'"),
        ({"kind": "pedestrian", "path": [[0.5, 0.5], [9.0, 0.5]]}, "npcs.0.pedestrian.path.1: (9, 0.5) m is more"),
        ({"kind": "pedestrian", "path": [[0.5, 0.5]], "mode": "zigzag"}, "npcs.0.pedestrian.mode: Input should be"),
        ({"kind": "car"}, "npcs.0: an NPC needs a 'kind': duckiebot or pedestrian"),
    ]
    for npc, words in cases:
        with pytest.raises(BenchmarkError) as exc_info:
            Benchmark.from_dict({**data, "npcs": [npc]}, origin="b.yaml")
        assert f"b.yaml: {words}" in str(exc_info.value), str(exc_info.value)


@pytest.mark.parametrize("name", ["aido_lfv", "aido_lfp"])
def test_lfv_and_lfp_load_and_run_a_short_episode(tmp_path, name):
    from proxybench.runner.evaluate import evaluate_benchmark
    from proxybench.runner.jobs import AgentSpec, DomainSpec, Job

    bench = Benchmark.load(name)
    assert [c.metric for c in bench.criteria()] == [
        "survival_time_median", "in_drivable_lane_median", "driven_lanedir_consec_median",
        "deviation_center_line_median"]
    assert not bench.traffic().empty
    short = bench.model_copy(update={"duration": 2.0, "episodes": bench.episodes.model_copy(update={"count": 1})})
    ev = evaluate_benchmark(short, [AgentSpec("pid")], tmp_path)
    (res,) = ev.sweep.results
    assert res.termination in ("timeout", "collision") and res.scores["survival_time"] > 0
    plain = Job(AgentSpec("pid"), DomainSpec("default", DomainParams()), "loop_3x3", 0, 0, 2.0)
    assert dataclasses.replace(plain, npcs=bench.traffic()).key != plain.key  # NPCs are part of the job key


def test_cli_evaluate_quick_shows_collisions(tmp_path):
    import json

    from typer.testing import CliRunner

    from proxybench.cli import app

    res = CliRunner().invoke(app, ["evaluate", "aido_lfp", "--agent", "pid", "--quick", "--backend", "inline",
                                   "--run-dir", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "aido_lfp-quick: 2 episodes × 15 s" in res.output and "collisions" in res.output
    (row,) = json.loads((tmp_path / "leaderboard.json").read_text())
    assert row["agent"] == "pid" and 0 <= row["collisions"] <= 2
    assert sum(row["collided_with"].values()) == row["collisions"]
