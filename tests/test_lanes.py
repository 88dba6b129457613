"""Lane geometry (segments, continuity, loops) and hand-computed lane poses."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from proxybench.domain.lane_pose import LP, lane_pose, lane_poses
from proxybench.domain.lanes import ROAD, LaneNetwork, SegmentKind
from proxybench.domain.maps import Direction, builtin_map_names, load_map

TS = 0.585
LOOP_MAPS = ["loop_3x3", "small_loop", "small_loop_cw", "zigzag"]
_NETS = {name: LaneNetwork(load_map(name)) for name in builtin_map_names()}


@pytest.fixture(scope="module", params=builtin_map_names())
def net(request) -> LaneNetwork:
    return _NETS[request.param]


def angle_diff(a: float, b: float) -> float:
    return math.remainder(a - b, 2 * math.pi)


# ---------------------------------------------------------------------------------------------------
# Segments


def test_segment_counts():
    counts = {name: len(LaneNetwork(load_map(name)).segments) for name in builtin_map_names()}
    # two lanes per straight / curve tile, entries × exits through intersections (3way: 6, 4way: 12)
    assert counts == {
        "loop_3x3": 16,
        "small_loop": 8,
        "small_loop_cw": 8,
        "zigzag": 28,
        "straight_road": 24,
        "intersections": 4 * 6 + 12 + 4 * 2 + 12 * 2,
    }


def test_round_trip_local_coordinates_on_a_grid(net):
    for seg in net.segments:
        for s in np.linspace(0.0, seg.length, 7):
            for r in np.linspace(-0.1, 0.1, 5):
                x, y = seg.position(s, r)
                s2, r2 = seg.local_coordinates(x, y)
                assert s2 == pytest.approx(s, abs=1e-9)
                assert r2 == pytest.approx(r, abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(
    map_name=st.sampled_from(builtin_map_names()),
    k=st.integers(0, 10_000),
    frac=st.floats(0.0, 1.0),
    r=st.floats(-0.1, 0.1),
)
def test_round_trip_local_coordinates_hypothesis(map_name, k, frac, r):
    net = _NETS[map_name]
    seg = net.segments[k % len(net.segments)]
    s = frac * seg.length
    s2, r2 = seg.local_coordinates(*seg.position(s, r))
    assert s2 == pytest.approx(s, abs=1e-9)
    assert r2 == pytest.approx(r, abs=1e-9)


def test_segments_start_on_entry_edge_and_end_on_exit_edge(net):
    ts = net.map.tile_size
    for seg in net.segments:
        i, j = seg.tile
        cx, cy = (i + 0.5) * ts, (j + 0.5) * ts
        for d, (px, py) in ((seg.entry, seg.position(0.0)), (seg.exit, seg.position(seg.length))):
            dx, dy = d.unit
            # on the edge line...
            if dx:
                assert px == pytest.approx(cx + 0.5 * ts * dx, abs=1e-12)
            else:
                assert py == pytest.approx(cy + 0.5 * ts * dy, abs=1e-12)
        # entering heading points away from the entry edge, leaving heading towards the exit edge
        assert angle_diff(seg.heading_at(0.0), math.pi / 2 * int(seg.entry.opposite)) == pytest.approx(0, abs=1e-12)
        assert angle_diff(seg.heading_at(seg.length), math.pi / 2 * int(seg.exit)) == pytest.approx(0, abs=1e-12)


def test_lane_centre_is_0_22_tile_right_of_road_centre(net):
    ts = net.map.tile_size
    for seg in net.segments:
        i, j = seg.tile
        # entering heading h; the right of h is (sin h, -cos h)
        h = seg.heading0
        x0, y0 = seg.position(0.0)
        ex, ey = seg.entry.unit
        mid_x, mid_y = (i + 0.5 + 0.5 * ex) * ts, (j + 0.5 + 0.5 * ey) * ts
        off = (x0 - mid_x) * math.sin(h) - (y0 - mid_y) * math.cos(h)
        assert off == pytest.approx(ROAD.lane_offset * ts, abs=1e-12)
        assert seg.width_at(0.3 * seg.length) == pytest.approx(ROAD.lane_width * ts)


def test_turn_radii_and_lengths():
    net = _NETS["loop_3x3"]
    for seg in net.segments:
        if seg.kind == SegmentKind.STRAIGHT:
            assert seg.length == pytest.approx(TS)
        elif seg.kind == SegmentKind.LEFT:
            assert seg.radius == pytest.approx(0.72 * TS)
            assert seg.length == pytest.approx(0.72 * TS * math.pi / 2)
        else:
            assert seg.radius == pytest.approx(0.28 * TS)
            assert seg.length == pytest.approx(0.28 * TS * math.pi / 2)


def test_heading_is_continuous_along_each_segment(net):
    for seg in net.segments:
        ss = np.linspace(0.0, seg.length, 21)
        pts = np.array([seg.position(s) for s in ss])
        for a in range(20):
            # the chord direction equals the heading at the chord's middle
            dx, dy = pts[a + 1] - pts[a]
            mid = seg.heading_at(0.5 * (ss[a] + ss[a + 1]))
            assert angle_diff(math.atan2(dy, dx), mid) == pytest.approx(0.0, abs=1e-9)
            # consecutive samples a twentieth of the segment apart are exactly that far along the curve
            assert math.hypot(dx, dy) == pytest.approx(seg.length / 20, rel=2e-3)


def test_successors_continue_position_and_heading(net):
    n_links = 0
    for seg in net.segments:
        end = seg.position(seg.length)
        h_end = seg.heading_at(seg.length)
        for k in net.successors(seg.index):
            nxt = net.segments[k]
            assert nxt.position(0.0) == pytest.approx(end, abs=1e-9)
            assert angle_diff(nxt.heading_at(0.0), h_end) == pytest.approx(0.0, abs=1e-9)
            assert seg.index in net.predecessors(k)
            n_links += 1
    assert n_links > 0


def test_every_segment_continues_except_at_road_ends(net):
    ends = {(i, j, d) for i, j, d in net.map.road_ends}
    for seg in net.segments:
        if (seg.tile[0], seg.tile[1], seg.exit) in ends:
            assert net.successors(seg.index) == []
        else:
            assert net.successors(seg.index)


@pytest.mark.parametrize("name", LOOP_MAPS)
def test_lane_centres_form_closed_loops(name):
    net = _NETS[name]
    seen: set[int] = set()
    loops = []
    for start in range(len(net.segments)):
        if start in seen:
            continue
        loop = [start]
        k = start
        while True:
            (k,) = net.successors(k)  # exactly one way on
            if k == start:
                break
            assert k not in loop, "the chain ran into a cycle that does not return to its start"
            loop.append(k)
        seen.update(loop)
        loops.append(loop)
        # the centre line of the loop is a closed curve: total turning ±2π
        turning = sum(
            (1 if net.segments[q].kind == SegmentKind.LEFT else -1) * math.pi / 2
            for q in loop
            if net.segments[q].kind != SegmentKind.STRAIGHT
        )
        assert abs(turning) == pytest.approx(2 * math.pi)
    # one loop each way round (right lane of each direction)
    assert len(loops) == 2
    assert sorted(len(lp) for lp in loops) == [len(net.segments) // 2] * 2


def test_loop_3x3_ccw_loop_is_the_outer_lane():
    net = _NETS["loop_3x3"]
    # in the counter-clockwise loop every turn is a left turn of radius 0.72 tile
    left = [s for s in net.segments if s.kind == SegmentKind.LEFT]
    assert len(left) == 4
    k = left[0].index
    for _ in range(8):
        seg = net.segments[k]
        assert seg.kind in (SegmentKind.LEFT, SegmentKind.STRAIGHT)
        (k,) = net.successors(k)
    assert k == left[0].index


# ---------------------------------------------------------------------------------------------------
# Lane poses, hand-computed

# straight_road: road tiles in row j = 1; the eastbound right lane is 0.22 tile south of the road centre
EAST_LANE_Y = 1.5 * TS - 0.22 * TS
WEST_LANE_Y = 1.5 * TS + 0.22 * TS


@pytest.fixture(scope="module")
def straight() -> LaneNetwork:
    return _NETS["straight_road"]


def test_robot_on_lane_centre(straight):
    lp = lane_pose(straight, 2.0, EAST_LANE_Y, 0.0)
    assert lp.valid and lp.on_road
    assert lp.lateral == pytest.approx(0.0, abs=1e-12)
    assert lp.heading_error == pytest.approx(0.0, abs=1e-12)
    assert lp.left_in_lane and lp.right_in_lane and lp.in_lane
    assert lp.left_on_road and lp.right_on_road
    assert lp.tile == (3, 1)
    seg = straight.segments[lp.segment]
    assert seg.tile == (3, 1) and seg.entry == Direction.W and seg.exit == Direction.E
    assert lp.along == pytest.approx(2.0 - 3 * TS, abs=1e-12)
    assert lp.curvature == 0.0


@pytest.mark.parametrize("dy, dth", [(0.03, 0.1), (-0.03, -0.1), (0.05, 0.0), (0.0, -0.2)])
def test_offsets_reported_exactly(straight, dy, dth):
    lp = lane_pose(straight, 1.3, EAST_LANE_Y + dy, dth)
    assert lp.lateral == pytest.approx(dy, abs=1e-9)
    assert lp.heading_error == pytest.approx(dth, abs=1e-9)
    assert lp.along == pytest.approx(1.3 - 2 * TS, abs=1e-9)


def test_heading_wraps(straight):
    lp = lane_pose(straight, 1.3, EAST_LANE_Y, 2 * math.pi - 0.1)
    assert lp.heading_error == pytest.approx(-0.1, abs=1e-9)


def test_wheels_leave_the_lane_at_half_lane_width(straight):
    half = 0.5 * ROAD.lane_width * TS  # 0.10998 m
    wheel = 0.102 / 2
    # left wheel exactly inside / just outside the lane
    inside = lane_pose(straight, 1.0, EAST_LANE_Y + half - wheel - 1e-4, 0.0)
    assert inside.left_in_lane and inside.right_in_lane
    outside = lane_pose(straight, 1.0, EAST_LANE_Y + half - wheel + 1e-4, 0.0)
    assert not outside.left_in_lane and outside.right_in_lane and not outside.in_lane
    right_out = lane_pose(straight, 1.0, EAST_LANE_Y - (half - wheel + 1e-4), 0.0)
    assert right_out.left_in_lane and not right_out.right_in_lane
    # wheel_distance is honoured
    wide = lane_pose(straight, 1.0, EAST_LANE_Y, 0.0, wheel_distance=2 * half + 0.01)
    assert not wide.left_in_lane and not wide.right_in_lane


def test_wrong_way_in_left_lane(straight):
    # in the left (westbound) lane but heading east: described by the eastbound lane, far to its left
    lp = lane_pose(straight, 2.0, WEST_LANE_Y, 0.0)
    assert lp.valid and lp.on_road
    assert lp.lateral == pytest.approx(0.44 * TS, abs=1e-9)
    assert lp.heading_error == pytest.approx(0.0, abs=1e-12)
    assert not lp.left_in_lane and not lp.right_in_lane


def test_left_lane_heading_west_is_the_westbound_right_lane(straight):
    lp = lane_pose(straight, 2.0, WEST_LANE_Y + 0.02, math.pi + 0.05)
    seg = straight.segments[lp.segment]
    assert seg.entry == Direction.E and seg.exit == Direction.W
    # heading west, "left" is south: +0.02 north is 0.02 to the right
    assert lp.lateral == pytest.approx(-0.02, abs=1e-9)
    assert lp.heading_error == pytest.approx(0.05, abs=1e-9)
    assert lp.in_lane
    assert lp.along == pytest.approx(4 * TS - 2.0, abs=1e-9)


def test_curve_lane_pose_hand_computed():
    net = _NETS["loop_3x3"]
    # bottom-left tile (0, 0) is curve_left/S: the road joins its north and east edges and turns around
    # the tile's north-east corner (ts, ts), the inner corner of the loop.
    corner = net.arrays.curve_corner[0, 0]
    assert tuple(corner) == pytest.approx((TS, TS))
    (left,) = [net.segments[k] for k in net.by_tile[(0, 0)] if net.segments[k].kind == SegmentKind.LEFT]
    # counter-clockwise: enters from the north heading south, turns left to leave east, radius 0.72 tile
    assert left.entry == Direction.N and left.exit == Direction.E
    assert (left.cx, left.cy) == pytest.approx((TS, TS))
    assert left.radius == pytest.approx(0.72 * TS)
    # a point on the bisector (polar angle 225° around the corner), 2 cm inside the lane centre
    for dist, dth in ((0.72 * TS - 0.02, 0.05), (0.72 * TS + 0.035, -0.1), (0.72 * TS, 0.0)):
        phi = 1.25 * math.pi
        x, y = TS + dist * math.cos(phi), TS + dist * math.sin(phi)
        lane_heading = phi + math.pi / 2  # counter-clockwise tangent: -45°, i.e. heading south-east
        lp = lane_pose(net, x, y, lane_heading + dth)
        assert lp.valid and lp.segment == left.index
        assert lp.lateral == pytest.approx(0.72 * TS - dist, abs=1e-9)  # + = left = towards the corner
        assert lp.heading_error == pytest.approx(dth, abs=1e-9)
        assert lp.along == pytest.approx(0.72 * TS * math.pi / 4, abs=1e-9)
        assert lp.curvature == pytest.approx(1 / (0.72 * TS), rel=1e-12)  # turning left


def test_curve_right_turn_lane_pose_hand_computed():
    net = _NETS["loop_3x3"]
    (right,) = [net.segments[k] for k in net.by_tile[(0, 0)] if net.segments[k].kind == SegmentKind.RIGHT]
    assert right.entry == Direction.E and right.exit == Direction.N
    assert right.radius == pytest.approx(0.28 * TS)
    # clockwise (entering heading west), a point 1 cm outside the inner lane centre at polar angle 225°
    dist = 0.28 * TS + 0.01
    phi = 1.25 * math.pi
    x, y = TS + dist * math.cos(phi), TS + dist * math.sin(phi)
    lp = lane_pose(net, x, y, phi - math.pi / 2)  # clockwise tangent: north-west
    assert lp.segment == right.index
    # heading north-west around the corner, further from it is to the left
    assert lp.lateral == pytest.approx(0.01, abs=1e-9)
    assert lp.heading_error == pytest.approx(0.0, abs=1e-9)
    assert lp.curvature == pytest.approx(-1 / (0.28 * TS), rel=1e-12)  # turning right


@pytest.mark.parametrize("name", ["small_loop", "small_loop_cw"])
def test_map_start_pose_is_on_the_lane_centre(name):
    net = _NETS[name]
    x, y, th = net.map.start_pose
    lp = lane_pose(net, x, y, th)
    assert lp.valid and lp.in_lane
    assert lp.lateral == pytest.approx(0.0, abs=1e-9)
    assert lp.heading_error == pytest.approx(0.0, abs=1e-6)  # the file gives π to 9 digits


def test_curve_outer_corner_is_off_road():
    net = _NETS["loop_3x3"]
    # the far (south-west) corner of the bottom-left curve lies outside the road's outer edge
    lp = lane_pose(net, 0.02, 0.02, -math.pi / 4)
    assert lp.valid  # still on a drivable tile
    assert not lp.on_road
    assert lane_pose(net, 0.3 * TS, 0.3 * TS, -math.pi / 4).on_road


@pytest.mark.parametrize("x, y", [(1.5 * TS, 1.5 * TS), (-0.1, 0.3), (0.3, -0.1), (10.0, 0.5)])
def test_grass_or_outside_map_is_invalid(x, y):
    lp = lane_pose(_NETS["loop_3x3"], x, y, 0.0)
    assert not lp.valid
    assert lp.segment == -1
    assert not lp.on_road and not lp.in_lane
    assert math.isnan(lp.lateral) and math.isnan(lp.heading_error)


def test_grass_next_to_straight_road(straight):
    lp = lane_pose(straight, 1.0, 0.5 * TS, 0.0)
    assert not lp.valid and not lp.on_road
    assert lp.tile == (1, 0)


def test_lane_poses_batch_matches_single(straight):
    poses = np.array([[1.0, EAST_LANE_Y + 0.01, 0.05], [2.2, WEST_LANE_Y, math.pi], [1.0, 0.1, 0.0]])
    rows = lane_poses(straight, poses)
    assert rows.shape == (3, LP.N)
    for row, pose in zip(rows, poses, strict=True):
        lp = lane_pose(straight, *pose)
        assert row[LP.VALID] == lp.valid
        if lp.valid:
            assert row[LP.LATERAL] == lp.lateral
            assert row[LP.HEADING_ERROR] == lp.heading_error
