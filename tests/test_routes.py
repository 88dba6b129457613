"""Routes through intersections: choices (seeded or planned), pinned lane poses, plans in benchmark files,
and the LF-I benchmark end to end."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from proxybench.agents import make_agent
from proxybench.domain.lane_pose import LP, lane_poses, lane_poses_on_segments
from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import Direction, load_map
from proxybench.domain.routes import RouteGraph, check_turns, pin_route, route_issues
from proxybench.domain.simulator import Simulator
from proxybench.runner.episode import run_episode, run_episodes
from proxybench.tasks.benchmark import Benchmark, BenchmarkError
from proxybench.tasks.metrics import METRICS

TS = 0.585
SOUTH_LANE_X = 2.5 * TS - 0.22 * TS  # southbound right lane of column 2 (x of the 4-way's north approach)


@pytest.fixture(scope="module")
def town() -> LaneNetwork:
    return LaneNetwork(load_map("intersections"))


@pytest.fixture(scope="module")
def sim() -> Simulator:
    return Simulator("intersections", render=False)


def lane_id(net: LaneNetwork, tile: tuple[int, int], entry: str, exit_: str) -> int:
    (k,) = [k for k in net.by_tile[tile] if net.segments[k].entry == Direction[entry]
            and net.segments[k].exit == Direction[exit_]]
    return k


def drive(sim: Simulator, agent: str, seed: int, seconds: float = 20.0, **kw):
    return run_episode(sim, make_agent(agent), seed, seconds, camera=False, **kw)


def turns_of(traj) -> list[str]:
    return [c["turn"] for c in traj.meta["route_choices"]]


def test_random_routes_are_fixed_by_the_seed_and_independent_of_the_batch(sim):
    a, b = drive(sim, "pid", 11), drive(sim, "pid", 11)
    assert turns_of(a) and turns_of(a) == turns_of(b)
    np.testing.assert_array_equal(a["route_segment"], b["route_segment"])
    assert len({tuple(turns_of(drive(sim, "pid", s))) for s in range(4)}) > 1  # seeds differ
    batch = Simulator("intersections", render=False, n=2)
    trajs = run_episodes(batch, [make_agent("pid"), make_agent("pid")], [3, 11], 20.0, camera=False)
    assert turns_of(trajs[1]) == turns_of(a)
    np.testing.assert_array_equal(trajs[1]["x"], a["x"])


def test_a_given_route_is_obeyed(sim, town):
    start = (SOUTH_LANE_X, 2.2, -math.pi / 2)  # southbound, north of the 4-way
    plan = ["left", "right", "right", "straight", "left"]
    assert route_issues(town, start, plan) == []
    traj = drive(sim, "pid", 5, 30.0, pose=start, route=plan)
    choices = traj.meta["route_choices"]
    assert len(choices) >= 4
    assert turns_of(traj)[: len(plan)] == plan[: len(choices)]
    assert [c["source"] for c in choices] == ["plan"] * min(len(plan), len(choices)) + ["random"] * (
        len(choices) - len(plan))  # after the plan, turns are drawn
    assert choices[0]["tile"] == [2, 2] and choices[0]["entry"] == "N"
    assert traj.meta["route_plan"] == plan
    # the robot left every intersection through the exit chosen for it, so it never left its route
    visits = [v for v in traj.meta["route"] if v["exit"] is not None]
    assert visits and all(v["rule"] == "chosen" for v in visits)
    assert all(Direction[v["exit"]] == sim.net.segments[v["segment"]].exit for v in visits)
    assert traj["on_route"].min() == 1.0


def test_a_turn_the_tile_does_not_allow_is_drawn_and_logged(sim, town):
    # straight through the 4-way, then into the 3-way at (2, 0) (open E, N, W) from the north
    start = (SOUTH_LANE_X, 2.2, -math.pi / 2)
    assert route_issues(town, start, ["straight", "straight"]) == [
        (1, "'straight' is not possible at the 3way_left tile (2, 0) entered from N (possible: left, right)")]
    assert route_issues(town, start, ["straight", "left"]) == []
    traj = drive(sim, "pid", 0, 8.0, pose=start, route=["straight", "straight"])
    first, second = traj.meta["route_choices"][:2]
    assert first["source"] == "plan" and first["turn"] == "straight"
    assert "planned turn 1 'straight' not allowed" in second["source"] and second["turn"] in ("left", "right")


def test_lane_pose_in_an_intersection_follows_the_chosen_lane(sim, town):
    pose = (SOUTH_LANE_X + 0.01, 3 * TS - 0.15 * TS, -math.pi / 2 + 0.1)  # just past the 4-way's north line
    for turn, exit_ in (("left", "E"), ("straight", "S"), ("right", "W")):
        sim.reset(0, 0, pose, route=[turn])
        k = lane_id(town, (2, 2), "N", exit_)
        assert int(sim.lane[0, LP.SEGMENT]) == k
        np.testing.assert_array_equal(sim.lane[0], lane_poses_on_segments(town, np.array([pose]), np.array([k]))[0])
        assert sim.routes.info(0, sim.lane[0]).next_turn == turn and sim.routes.info(0, sim.lane[0]).in_intersection


def test_maps_without_intersections_keep_the_plain_lane_pose():
    sim = Simulator("loop_3x3", render=False)
    traj = drive(sim, "pid", 4, 10.0, route=["left"])  # a plan on a map without intersections is never used
    net = LaneNetwork(sim.map)
    np.testing.assert_array_equal(traj.lane, lane_poses(net, traj.pose()))
    assert "route_choices" not in traj.meta and traj.meta["route_plan"] == ["left"]
    assert (traj["route_segment"] == -1).all() and np.isnan(traj["stop_distance"]).all()
    assert "route" not in traj.meta


def test_pin_route_uses_the_exit_taken_without_a_given_route(town):
    y = np.arange(2.203, 0.9, -0.01)  # southbound through the 4-way, 2 cm left of the lane centre
    pose = np.stack([np.full_like(y, SOUTH_LANE_X + 0.02), y, np.full_like(y, -math.pi / 2)], axis=1)
    lane = lane_poses(town, pose)
    route, visits = pin_route(town, pose, lane)
    straight = lane_id(town, (2, 2), "N", "S")
    on_tile = np.floor(y / TS) == 2
    assert (route[on_tile] == straight).all() and (route[~on_tile] == -1).all()
    assert visits == [{"sample": int(np.argmax(on_tile)), "tile": [2, 2], "entry": "N", "exit": "S",
                       "turn": "straight", "segment": straight, "rule": "taken"}]
    np.testing.assert_allclose(lane[on_tile, LP.LATERAL], 0.02, atol=1e-12)
    # the same pass told to turn left is measured against the left lane, which it leaves
    given = np.full(len(y), lane_id(town, (2, 2), "N", "E"))
    lane2 = lane_poses(town, pose)
    route2, visits2 = pin_route(town, pose, lane2, given=given)
    assert (route2[on_tile] == given[0]).all()
    assert visits2[0]["rule"] == "chosen" and visits2[0]["turn"] == "left" and visits2[0]["exit"] == "S"
    assert np.abs(lane2[on_tile, LP.LATERAL]).max() > 0.2


def test_check_turns_names_the_bad_entry():
    assert check_turns(["left", "straight"]) == ("left", "straight")
    with pytest.raises(ValueError, match="turn 1: 'u-turn'"):
        check_turns(["left", "u-turn"])


def test_route_graph_marks_stop_lines(town):
    g = RouteGraph(town)
    assert g.active and g.mask.sum() == 5
    assert g.leads_to_stop[lane_id(town, (2, 3), "N", "S")] and g.leads_to_stop[lane_id(town, (1, 4), "W", "E")]
    assert not g.leads_to_stop[lane_id(town, (1, 4), "E", "W")]  # towards the corner curve
    assert not RouteGraph(LaneNetwork(load_map("loop_3x3"))).active


# -- benchmark files ------------------------------------------------------------------------------

def lfi_data() -> dict:
    from importlib import resources

    return yaml.safe_load((resources.files("proxybench") / "benchmarks" / "aido_lfi.yaml").read_text())


def test_aido_lfi_contents():
    b = Benchmark.load("aido_lfi")
    assert b.map.endswith("intersections") and not b.camera_only
    assert [(c.metric, c.higher_is_better, c.tolerance) for c in b.criteria()] == [
        ("survival_time_median", True, 2.0), ("in_drivable_lane_median", False, 0.2),
        ("driven_lanedir_consec_median", True, 0.62), ("deviation_center_line_median", False, 0.01)]
    assert {"distance_along_route", "stop_line_violations", "stopped_at_line"} <= set(b.metrics)
    assert all(s.route is None for s in b.episode_specs())


def test_routes_in_benchmark_files(tmp_path):
    data = lfi_data()
    data["episodes"] = {"poses": [[SOUTH_LANE_X, 2.2, -math.pi / 2], [SOUTH_LANE_X, 1.0, -math.pi / 2]],
                        "routes": [["left", "right"], ["right"]]}
    specs = Benchmark.from_dict(data).episode_specs()
    assert [s.route for s in specs] == [("left", "right"), ("right",)]
    data["episodes"] = {"count": 2, "routes": [["left"], []]}
    assert [s.route for s in Benchmark.from_dict(data).episode_specs()] == [("left",), ()]


@pytest.mark.parametrize("episodes, field, words", [
    ({"count": 2, "routes": [["left"]]}, "episodes.routes", "1 routes for 2 episodes"),
    ({"count": 1, "routes": [["left", "u-turn"]]}, "episodes.routes.0.1", "Input should be 'left'"),
    ({"count": 1, "route": [["left"]]}, "episodes.route", "unknown key (did you mean routes"),
    ({"poses": [[SOUTH_LANE_X, 2.2, -math.pi / 2]], "routes": [["straight", "straight"]]},
     "episodes.routes.0.1", "'straight' is not possible at the 3way_left tile (2, 0)"),
])
def test_bad_routes_name_the_field(episodes, field, words):
    data = {**lfi_data(), "episodes": episodes}
    with pytest.raises(BenchmarkError) as exc_info:
        Benchmark.from_dict(data, origin="lfi.yaml")
    assert f"lfi.yaml: {field}: " in str(exc_info.value) and words in str(exc_info.value), str(exc_info.value)


def test_lfi_short_episodes_run_and_separate_stopping_agents(tmp_path):
    from proxybench.runner.evaluate import evaluate_benchmark
    from proxybench.runner.jobs import AgentSpec

    data = {**lfi_data(), "duration": 20.0, "episodes": {"count": 2, "seed": 1, "routes": [["left"], []]}}
    bench = Benchmark.from_dict(data)
    ev = evaluate_benchmark(bench, [AgentSpec("pid"), AgentSpec("pid-stop")], tmp_path)
    agg = ev.aggregates.set_index("agent")
    assert agg.loc["pid", "stop_line_violations_mean"] > 0
    assert agg.loc["pid-stop", "stop_line_violations_mean"] == 0
    assert agg.loc["pid-stop", "stopped_at_line_mean"] == 1.0
    assert (agg["survival_time_median"] == 20.0).all()
    assert {r.agent for r in ev.ranks} == {"pid", "pid-stop"}
    assert all(r.scores.keys() >= {"distance_along_route"} for r in ev.sweep.results)


def test_privileged_observations_carry_the_route(sim):
    seen = []

    class Spy:
        privileged, name = True, "spy"

        def reset(self, seed, episode=None):
            pass

        def act(self, obs):
            seen.append(obs.route)
            return np.array([0.4, 0.4])

    run_episodes(sim, [Spy()], [0], 1.0, poses=[(SOUTH_LANE_X, 2.2, -math.pi / 2)], camera=False, routes=[["right"]])
    assert seen[0].stop_distance == pytest.approx(2.2 - 3 * TS) and not seen[0].in_intersection
    assert seen[0].next_turn is None and seen[-1].next_turn == "right"
    assert METRICS["stopped_at_line"].higher_is_better and not METRICS["stop_line_violations"].higher_is_better


def test_cli_evaluates_aido_lfi_with_built_in_agents(tmp_path):
    from typer.testing import CliRunner

    from proxybench.cli import app

    res = CliRunner().invoke(app, ["evaluate", "aido_lfi", "--agent", "pid", "--agent", "pure-pursuit-stop",
                                   "--backend", "inline", "--run-dir", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "aido_lfi: 5 episodes × 60 s" in res.output and "pure-pursuit-stop" in res.output
    agg = (tmp_path / "aggregates.csv").read_text()
    assert "stop_line_violations_median" in agg and "distance_along_route_median" in agg
