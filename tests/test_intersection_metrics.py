"""Intersection metrics on hand-built trajectories through the 4-way of the ``intersections`` town.

The robot comes down column 2 heading south in the southbound lane (x = 2.5·ts − 0.22·ts), at
0.01 m per 0.05 s sample (0.2 m/s); the 4-way's north stop line is the tile edge y = 3·ts.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import Direction, load_map
from proxybench.tasks.intersection_metrics import STOP_BAND, STOP_TIME
from proxybench.tasks.metrics import METRICS, lane_steps
from proxybench.tasks.trajectory import Trajectory

TS = 0.585
X = 2.5 * TS - 0.22 * TS  # southbound lane centre
LINE = 3 * TS  # y of the stop line's near edge
DT = 0.05
CORNER = (3 * TS, 3 * TS)  # the left turn N→E curves around the 4-way's north-east corner
R_LEFT = (0.5 + 0.22) * TS


@pytest.fixture(scope="module")
def town():
    return load_map("intersections")


def southbound(town, y_from: float, y_to: float, hold_at: float | None = None, hold_s: float = 0.0,
               route_segment: np.ndarray | int | None = None) -> Trajectory:
    """Drive south from ``y_from`` to ``y_to``, standing still ``hold_s`` seconds at ``hold_at``."""
    y = list(np.arange(y_from, y_to, -0.01))
    if hold_at is not None:
        k = int(np.argmin(np.abs(np.array(y) - hold_at)))
        y[k + 1:k + 1] = [y[k]] * round(hold_s / DT)
    y = np.array(y)
    t = np.arange(len(y)) * DT
    pose = np.stack([np.full_like(y, X), y, np.full_like(y, -math.pi / 2)], axis=1)
    extra = None if route_segment is None else {"route_segment": np.broadcast_to(route_segment, y.shape)}
    return Trajectory.from_poses(town, t, pose, extra=extra)


def m(name: str, traj: Trajectory) -> float:
    return METRICS[name](traj)


def test_running_the_line_is_a_violation(town):
    traj = southbound(town, 2.203, 1.5)
    assert traj["stop_distance"][0] == pytest.approx(2.203 - LINE)
    assert m("stop_line_violations", traj) == 1 and m("stopped_at_line", traj) == 0.0


@pytest.mark.parametrize("hold_at, hold_s, stopped", [
    (LINE + 0.145, 1.0, True),  # in the band, long enough
    (LINE + 0.145, STOP_TIME, True),  # exactly the minimum
    (LINE + 0.145, 0.4, False),  # a rolling stop
    (LINE + STOP_BAND + 0.05, 1.0, False),  # stopped too early, then rolled over the line
    (LINE + 0.005, 1.0, True),  # right at the line
])
def test_a_full_stop_in_the_band(town, hold_at, hold_s, stopped):
    traj = southbound(town, 2.203, 1.5, hold_at, hold_s)
    assert m("stop_line_violations", traj) == (0 if stopped else 1)
    assert m("stopped_at_line", traj) == (1.0 if stopped else 0.0)


def test_no_line_crossed_gives_nan_fraction_and_no_violation(town):
    traj = southbound(town, 2.203, LINE + 0.05)  # stops short of the intersection: the episode ends
    assert m("stop_line_violations", traj) == 0 and math.isnan(m("stopped_at_line", traj))
    loop = Trajectory.from_poses(load_map("loop_3x3"), np.array([0.0, DT]),
                                 np.array([[0.3, 0.13, 0.0], [0.31, 0.13, 0.0]]))
    assert m("stop_line_violations", loop) == 0 and math.isnan(m("stopped_at_line", loop))


def test_distance_along_a_straight_route(town):
    traj = southbound(town, 2.203, 0.9)  # straight through the 4-way and on (the exit taken)
    assert m("distance_along_route", traj) == pytest.approx(2.203 - 0.903, abs=1e-9)
    assert m("driven_lanedir_consec", traj) == pytest.approx(2.203 - 0.903, abs=1e-9)
    assert traj["on_route"].min() == 1.0


def test_a_wrong_exit_ends_progress_along_the_route(town):
    net = LaneNetwork(town)
    left = next(k for k in net.by_tile[(2, 2)] if net.segments[k].entry == Direction.N
                and net.segments[k].exit == Direction.E)
    traj = southbound(town, 2.203, 0.9, route_segment=left)  # told to turn left, drove straight on
    y = traj["y"]
    tile = np.floor(y / TS)
    assert (traj["on_route"][tile >= 2] == 1).all() and (traj["on_route"][tile < 2] == 0).all()
    # by hand: 0.01 m a sample before the line; on the 4-way each 0.01 m step south projects on the left
    # lane's direction at the robot, cos δ with tan δ = (LINE − y) / R_LEFT (the robot is on the arc's
    # radius line x = corner − R_LEFT at the line)
    assert pytest.approx(CORNER[0] - R_LEFT) == X
    before = np.sum(tile[1:] == 3) * 0.01
    d = LINE - y[tile == 2]
    on_tile = np.sum(0.01 * R_LEFT / np.hypot(R_LEFT, d))
    assert m("distance_along_route", traj) == pytest.approx(before + on_tile, rel=1e-9)
    assert m("distance_along_route", traj) < m("driven_any", traj) - (2 * TS - 0.903)  # nothing south of it


def _walk(net: LaneNetwork, lanes: list[tuple[tuple[int, int], str, str]], ds: float = 0.01) -> np.ndarray:
    """Poses every ``ds`` metres along the centres of the given lanes, (tile, entry, exit) each."""
    segs = [net.segments[next(k for k in net.by_tile[t] if net.segments[k].entry == Direction[a]
                              and net.segments[k].exit == Direction[b])] for t, a, b in lanes]
    for s0, s1 in itertools.pairwise(segs):
        assert s1.index in net.successors(s0.index), (s0, s1)
    ends = np.cumsum([s.length for s in segs])
    out = []
    for u in np.arange(0.003, ends[-1], ds):
        k = int(np.searchsorted(ends, u, side="right"))
        s = u - (ends[k - 1] if k else 0.0)
        out.append((*segs[k].position(s), segs[k].heading_at(s)))
    return np.array(out)


def test_driven_lanedir_consec_counts_a_second_pass_by_another_lane(town):
    """Round the north-east block and back through the 4-way by another lane: both passes count."""
    net = LaneNetwork(town)
    pose = _walk(net, [((1, 2), "W", "E"), ((2, 2), "W", "E"), ((3, 2), "W", "E"), ((4, 2), "W", "N"),
                       ((4, 3), "S", "N"), ((4, 4), "S", "W"), ((3, 4), "E", "W"), ((2, 4), "E", "S"),
                       ((2, 3), "N", "S"), ((2, 2), "N", "E"), ((3, 2), "W", "E")])
    traj = Trajectory.from_poses(town, np.arange(len(pose)) * DT, pose)
    assert [v["turn"] for v in traj.meta["route"]] == ["straight", "left", "left", "left"]
    assert np.abs(traj["lateral"]).max() < 1e-9
    total = float(np.sum(lane_steps(traj)))
    assert m("driven_lanedir_consec", traj) == pytest.approx(total, rel=1e-12)
    assert m("distance_along_route", traj) == pytest.approx(total, rel=1e-12)
    assert total == pytest.approx(m("driven_any", traj), rel=1e-3)  # chords of the arcs
