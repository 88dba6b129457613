"""Map objects in every placement the Duckietown maps use, written by hand: each form, each mistake."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from proxybench.domain.camera import camera_table
from proxybench.domain.maps import MapError, MapObject, MapWarning, load_map, parse_map
from proxybench.domain.objects import object_collides, object_primitives, pack_objects
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.domain.topdown import map_image

TS = 0.585
# 3 columns × 2 rows, so that rows and columns, top and bottom cannot be confused
HEAD = "tiles:\n- [straight/E, straight/E, straight/E]\n- [grass, grass, grass]\ntile_size: 0.585\n"


def one(objects_yaml: str):
    """The single object of a map whose ``objects:`` mapping is ``objects_yaml`` (indented 2)."""
    (obj,) = parse_map(HEAD + "objects:\n" + objects_yaml, path="m.yaml").objects
    return obj


def errors(objects_yaml: str) -> list[str]:
    with pytest.raises(MapError) as exc_info:
        parse_map(HEAD + "objects:\n" + objects_yaml, path="m.yaml")
    return [str(i) for i in exc_info.value.issues]


# ---------------------------------------------------------------------------------------------------
# The four placements


def test_pose_is_metres_in_the_map_frame():
    o = one("  a:\n    kind: duckie\n    pose:\n      ~SE2Transform:\n        p: [1.2, 0.3]\n        theta_deg: 90\n")
    assert (o.x, o.y, o.heading) == pytest.approx((1.2, 0.3, math.pi / 2))


@pytest.mark.parametrize("pose, expected", [
    ("{~SE2Transform: {p: [0.5, 0.6], theta: 1.0}}", (0.5, 0.6, 1.0)),  # radians
    ("{p: [0.5, 0.6], theta_deg: -45}", (0.5, 0.6, -math.pi / 4)),  # the type tag may be left out
    ("{~SE2Transform: {theta_deg: 180}}", (0.0, 0.0, math.pi)),  # no p: the origin
    ("{~SE2Transform: {p: [0.5, 0.6]}}", (0.5, 0.6, 0.0)),
])
def test_pose_variants(pose, expected):
    o = one(f"  a: {{kind: cone, pose: {pose}}}\n")
    assert (o.x, o.y, o.heading) == pytest.approx(expected)


def test_place_is_metres_from_the_centre_of_a_tile_counted_from_the_bottom():
    o = one("  light:\n    kind: trafficlight\n    place:\n      tile: [2, 1]\n      relative:\n"
            "        ~SE2Transform: {p: [-0.18, 0.1], theta_deg: 135}\n    height: 0.4\n")
    # tile [2, 1]: third column, top row of this 2-row map (j counts from the bottom)
    assert (o.x, o.y) == pytest.approx((2.5 * TS - 0.18, 1.5 * TS + 0.1))
    assert o.heading == pytest.approx(math.radians(135)) and o.height == 0.4


def test_pos_is_tiles_down_the_listing_and_may_have_three_numbers():
    o = one("  d: {kind: duckie, pos: [1.5, 0.25, 0.0], rotate: 30}\n")
    assert (o.x, o.y, o.heading) == pytest.approx((1.5 * TS, (2 - 0.25) * TS, math.radians(30)))


def test_attach_is_a_sign_slot_around_the_south_west_corner_of_the_tile():
    a = one("  s: {kind: sign_stop, attach: {tile: [1, 0], slot: 4}, rotate: 90}\n")
    assert (a.x, a.y, a.heading) == pytest.approx(((1 - 0.09) * TS, -0.035 * TS, math.pi / 2))
    # heading from a pose without p (as the robotarium maps write it); the east edge's corners are slots too
    b = one("  s:\n    kind: sign_T_intersect\n    attach: {tile: [3, 1], slot: '1'}\n"
            "    pose: {~SE2Transform: {theta_deg: 270}}\n")
    assert (b.x, b.y, b.heading) == pytest.approx(((3 + 0.035) * TS, (1 + 0.09) * TS, math.radians(270)))


def test_tags_are_kept():
    o = one("  t:\n    kind: floor_tag\n    pose: {~SE2Transform: {p: [0.3, 0.3]}}\n"
            "    tag: {~TagInstance: {family: 36h11, tag_id: 42, size: 0.065}}\n")
    assert (o.tag.family, o.tag.tag_id, o.tag.size) == ("36h11", 42, 0.065)


# ---------------------------------------------------------------------------------------------------
# Mistakes: each a clear error naming the object, the field and the line


@pytest.mark.parametrize("obj, message", [
    ("{kind: duckie}", "objects[0]: no position: give 'pos: [x, y]' (tiles), 'pose: "),
    ("{kind: duckie, pose: {~SE2Transform: {p: [1, 2], theta_degree: 5}}}",
     "objects[0]: 'pose' has unknown field(s) 'theta_degree' (known: p, theta_deg, theta)"),
    ("{kind: duckie, pose: {~SE2Transform: {p: [1]}}}", "objects[0]: 'pose.p' must be [x, y] in metres, got [1]"),
    ("{kind: duckie, pose: {p: [1, 2], theta: 1, theta_deg: 5}}", "'pose' gives both 'theta' and 'theta_deg'"),
    ("{kind: duckie, pose: {p: [1, 2], theta_deg: north}}", "'pose.theta_deg' must be a number, got 'north'"),
    ("{kind: duckie, place: {tile: [3, 0], relative: {p: [0, 0]}}}",
     "'place.tile' [3, 0] is outside the map (3×2 tiles)"),
    ("{kind: duckie, place: {tile: [0, 0], relative: {p: [0, 0]}, offset: 1}}", "'place' must be {tile: [i, j]"),
    ("{kind: sign_stop, attach: {tile: [0, 0], slot: 8}}", "'attach.slot' must be an integer 0-7, got 8"),
    ("{kind: sign_stop, attach: {tile: [4, 0], slot: 1}}", "'attach.tile' [4, 0] is outside the map"),
    ("{kind: sign_stop, attach: {tile: [0, 0], slot: 1}, pose: {p: [1, 1]}}",
     "'attach' and 'pose' with 'p' both place the object"),
    ("{kind: floor_tag, pose: {p: [1, 1]}, tag: {~TagInstance: {tag_id: x}}}",
     "'tag.tag_id' must be a non-negative integer, got 'x'"),
    ("{kind: floor_tag, pose: {p: [1, 1]}, tag: {~TagInstance: {tag_id: 3, size: 0}}}",
     "'tag.size' must be a positive number of metres, got 0"),
])
def test_bad_objects_are_errors_that_name_the_field(obj, message):
    (msg,) = errors(f"  - {obj}\n".replace("  - ", "- "))
    assert msg.startswith("m.yaml:6:3: ") and message in msg, msg


def test_a_problem_shared_by_many_objects_is_reported_once_with_a_count():
    objs = "".join(f"- {{kind: duckie, pose: {{~SE2Transform: {{p: [{i}, 0], theta_deg: 5, z: 1}}}}}}\n"
                   for i in range(30))
    (msg,) = errors(objs)
    assert "objects[0]: 'pose' has unknown field(s) 'z'" in msg
    assert "(and 29 more object(s) alike, at line(s) 7, 8, 9, 10, 11, …)" in msg


# ---------------------------------------------------------------------------------------------------
# Kinds: every kind the real maps use has a shape; unknown ones are grey boxes with one warning per kind


def test_unknown_kinds_are_grey_boxes_with_one_warning_per_kind():
    m = parse_map(HEAD + "objects:\n- {kind: ufo, pos: [0.5, 0.5]}\n- {kind: ufo, pos: [1.5, 0.5]}\n"
                  "- {kind: lamp_post, pos: [2.5, 0.5]}\n- {kind: duckie, pos: [2.5, 1.5]}\n", path="m.yaml")
    assert len(m.objects) == 4
    assert [str(w) for w in m.warnings] == [
        "m.yaml:6:3: unknown object kind 'ufo' (2 object(s)): drawn as a grey 0.1 m box that collides like a duckie",
        "m.yaml:8:3: unknown object kind 'lamp_post' (1 object(s)): drawn as a grey 0.1 m box that collides like "
        "a duckie",
    ]
    prims, robot = object_primitives(m.objects[0])
    assert prims[0].rgb == (150.0, 150.0, 150.0) and not robot and object_collides("ufo")


def test_loading_a_file_warns_where_nobody_prints_the_warnings(tmp_path):
    f = tmp_path / "m.yaml"
    f.write_text(HEAD + "objects:\n- {kind: ufo, pos: [0.5, 0.5]}\n")
    with pytest.warns(MapWarning, match=rf"{f}:6:3: unknown object kind 'ufo'"):
        Simulator(str(f), render=False)


@pytest.mark.parametrize("kind", ["duckie", "duckiebot", "cone", "barrier", "house", "building", "tree", "bus",
                                  "truck", "trafficlight", "floor_tag", "checkerboard", "sign_stop", "sign_blank",
                                  "sign_t_light_ahead", "sign_4_way_intersect"])
def test_every_kind_of_the_real_maps_is_known(kind):
    m = parse_map(HEAD + f"objects:\n- {{kind: {kind}, pos: [0.5, 0.5]}}\n", path="m.yaml")
    assert m.warnings == ()


def test_floor_tags_and_traffic_lights_are_drawn_but_not_hit():
    tag = MapObject("floor_tag", 1.0, 0.3)
    light = MapObject("trafficlight", 1.0, 0.3, height=0.4)
    assert not object_collides("floor_tag") and not object_collides("trafficlight")
    packed = pack_objects([tag, light, MapObject("cone", 2.0, 0.3)])
    assert packed.prims.shape[0] == 4 and packed.colliders.shape[0] == 1
    prims, _ = object_primitives(light)
    assert min(p.z0 for p in prims) == pytest.approx(0.3) and max(p.z1 for p in prims) == pytest.approx(0.4)
    big = object_primitives(dataclasses.replace(tag, tag=one(
        "  t: {kind: floor_tag, pos: [0, 0], tag: {~TagInstance: {tag_id: 1, size: 0.2}}}\n").tag))[0]
    assert max(p.a for p in big) == pytest.approx(0.1 / 0.8)  # the white border around a 0.2 m tag


def test_a_floor_tag_in_front_of_the_robot_darkens_the_road_and_the_robot_drives_over_it():
    straight = load_map("straight_road")
    lane_y = 1.28 * TS
    params = DomainParams(image_width=80, image_height=60, texture_noise=0.0, blur_time=0.0)
    tagged = dataclasses.replace(straight, objects=(MapObject("floor_tag", 1.4, lane_y),))
    frames = []
    for m in (straight, tagged):
        sim = Simulator(m, params)
        sim.reset(0, 0, pose=(1.0, lane_y, 0.0))
        frames.append(sim.render()[0].astype(int))
    changed = np.any(frames[0] != frames[1], axis=-1)
    assert 3 < changed.sum() < 200 and not changed[camera_table(params).sky].any()
    assert (frames[1][changed].sum(axis=-1) < frames[0][changed].sum(axis=-1)).mean() > 0.5  # mostly the black
    for _ in range(30):
        sim.step(np.array([[0.5, 0.5]]))
    assert sim.state[0, 0] > 1.5 and not sim.collided[0]


# ---------------------------------------------------------------------------------------------------
# Tiles and starts


def test_a_road_may_end_on_a_calibration_tile_drawn_as_floor():
    m = parse_map("tiles:\n- [straight/E, calibration_tile]\ntile_size: 0.585\n", path="m.yaml")
    assert not m.tile(1, 0).drivable and len(m.road_ends) == 2
    img = map_image(m, px_per_tile=8, params=DomainParams())
    assert np.abs(img[4, 12].astype(float) - np.asarray(DomainParams().floor_rgb)).max() <= 2


def test_start_pose_counts_from_the_start_tile_when_the_map_gives_one():
    text = HEAD + "start_tile: [1, 0]\nstart_pose: [[0.1, 0, 0.2], 0.5]\n"
    m = parse_map(text, path="m.yaml")
    # gym-duckietown-daffy: x from the tile's west edge, z down from its north edge; file row 0 is j = 1
    assert m.start_pose == pytest.approx((TS + 0.1, 2 * TS - 0.2, 0.5))
    assert m.start_tile == (1, 1)
    absolute = parse_map(HEAD + "start_pose: [[0.1, 0, 0.2], 0.5]\n", path="m.yaml")
    assert absolute.start_pose == pytest.approx((0.1, 2 * TS - 0.2, 0.5))


def test_random_starts_keep_clear_of_map_objects():
    straight = load_map("straight_road")
    cones = tuple(MapObject("cone", x, 1.28 * TS) for x in np.arange(0.2, 7.0, 0.5))
    sim = Simulator(dataclasses.replace(straight, objects=cones), render=False)
    for seed in range(30):
        sim.reset(0, seed)
        assert not sim.collided[0], seed
