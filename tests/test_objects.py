"""Map objects: camera occlusion, culling, top-down drawing and collisions."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from proxybench.domain.camera import camera_table
from proxybench.domain.maps import MapObject, load_map
from proxybench.domain.objects import DUCKIE_MARGIN, ROBOT_MARGIN, object_primitives, pack_objects
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.domain.topdown import top_down

TS = 0.585
LANE_Y = 1.28 * TS  # eastbound right-lane centre of straight_road
POSE = (1.0, LANE_Y, 0.0)
W, H = 160, 120
BASE = DomainParams(image_width=W, image_height=H, texture_noise=0.0, blur_time=0.0)
STRAIGHT = load_map("straight_road")
CAM_X = POSE[0] + BASE.camera_forward
WALL_X = CAM_X + 0.45  # a wall across the lane 0.45 m ahead of the camera
WALL = MapObject("barrier", WALL_X, LANE_Y, heading=math.pi / 2, height=0.3, scale=2.0)


def with_objects(*objs: MapObject):
    return dataclasses.replace(STRAIGHT, objects=tuple(objs))


def render(m, params: DomainParams = BASE, pose=POSE) -> np.ndarray:
    sim = Simulator(m, params)
    sim.reset(0, 0, pose=pose)
    return sim.render()[0]


def line_mask(img: np.ndarray) -> np.ndarray:
    im = img.astype(int)
    yellow = (im[..., 0] > 150) & (im[..., 1] > 120) & (im[..., 2] < 100)
    white = np.all(im > 200, axis=-1)
    return yellow | white


@pytest.fixture(scope="module")
def empty() -> np.ndarray:
    return render(STRAIGHT)


def test_object_in_front_hides_the_lines_behind_it(empty):
    img = render(with_objects(WALL))
    table = camera_table(BASE)
    lines = line_mask(empty)
    # line pixels whose ground point lies well behind the wall, within its width
    behind = lines & (table.gx + POSE[0] > WALL_X + 0.08) & (np.abs(table.gy) < 0.4) & ~table.sky
    assert behind.sum() > 20
    assert not line_mask(img)[behind].any()
    # they are now the wall's (shaded) red
    px = img[behind].astype(int)
    assert np.all(px[:, 0] > px[:, 1] + 40) and np.all(px[:, 0] > px[:, 2] + 40)
    # the line in front of the wall is still drawn, unchanged
    front = lines & (table.gx + POSE[0] < WALL_X - 0.08) & ~table.sky
    assert front.sum() > 20
    assert np.array_equal(img[front], empty[front])
    # rows that see only the road in front of the wall are bit-identical to the object-free frame
    rows = np.flatnonzero(np.all(table.gx + POSE[0] < WALL_X - 0.1, axis=1) & ~table.sky.any(axis=1))
    assert rows.size > 10
    assert np.array_equal(img[rows], empty[rows])


def test_tall_object_covers_the_sky():
    img = render(with_objects(WALL))
    u = W // 2
    assert camera_table(BASE).sky[:, u].any()
    col = img[:, u].astype(int)
    # every pixel of the centre column up to the top of the wall is wall-coloured, including sky rows
    table = camera_table(BASE)
    sky_rows = np.flatnonzero(table.sky[:, u])
    assert (col[sky_rows[-1], 0] > col[sky_rows[-1], 2] + 40)


def test_object_behind_the_camera_or_far_away_is_invisible(empty):
    behind = MapObject("barrier", POSE[0] - 0.3, LANE_Y, heading=math.pi / 2, height=0.3, scale=2.0)
    far = MapObject("cone", POSE[0] + 3.5, LANE_Y)
    assert np.array_equal(render(with_objects(behind, far)), empty)


def test_zigzag_duckie_parses_and_renders():
    m = load_map("zigzag")
    assert [o.kind for o in m.objects] == ["duckie"]
    duck = m.objects[0]
    prims, robot = object_primitives(duck)
    assert not robot and prims[0].z1 == pytest.approx(0.08)  # the map's height overrides the default
    pose = (duck.x - 0.4, duck.y, 0.0)
    img = render(m, pose=pose)
    bare = render(dataclasses.replace(m, objects=()), pose=pose)
    diff = np.any(img != bare, axis=-1)
    assert diff.sum() > 30
    _, cols = np.nonzero(diff)
    assert abs(cols.mean() - W / 2) < 5  # straight ahead
    px = img[diff].astype(int)
    assert np.median(px[:, 0]) > 120 and np.median(px[:, 2]) < 60  # yellow, shaded


def test_fisheye_and_blur_render_objects():
    p = BASE.replace(fisheye=True, blur_time=0.05, blur_samples=3)
    m = with_objects(WALL)
    sim = Simulator(m, p)
    sim.reset(0, 0, pose=POSE)
    for _ in range(3):
        sim.step(np.array([[0.3, 0.3]]))
    img = sim.render()[0]
    sim2 = Simulator(STRAIGHT, p)
    sim2.reset(0, 0, pose=POSE)
    for _ in range(3):
        sim2.step(np.array([[0.3, 0.3]]))
    bare = sim2.render()[0]
    centre = img[H // 4 - 5 : H // 4 + 5, W // 2 - 5 : W // 2 + 5].astype(int)
    assert np.all(centre[..., 0] > centre[..., 2] + 40)
    assert not np.array_equal(img, bare)


def test_rendering_with_objects_is_deterministic_and_batch_independent():
    m = with_objects(WALL, MapObject("duckie", POSE[0] + 0.4, LANE_Y + 0.05), MapObject("sign_stop", 1.8, 0.95))
    p = BASE.replace(noise_std=4.0, blur_time=0.05)
    sim = Simulator(m, [p, p])
    sim.reset(0, 3, pose=POSE)
    sim.reset(1, 4, pose=(1.2, LANE_Y + 0.02, 0.1))
    a = sim.render().copy()
    b = sim.render()
    assert np.array_equal(a, b)
    single = Simulator(m, p)
    single.reset(0, 4, pose=(1.2, LANE_Y + 0.02, 0.1))
    assert np.array_equal(single.render()[0], a[1])


def test_top_down_shows_the_object_colour():
    duck = MapObject("duckie", 2.0, LANE_Y, scale=2.0)
    m = with_objects(duck)
    px_per_tile = 64
    img = top_down(m, np.array([[0.5, LANE_Y, 0.0]]), px_per_tile=px_per_tile)
    s = px_per_tile / m.tile_size
    r, c = int(img.shape[0] - duck.y * s), int(duck.x * s)
    assert tuple(img[r, c]) == (240, 200, 20)
    assert not np.array_equal(img, top_down(STRAIGHT, np.array([[0.5, LANE_Y, 0.0]]), px_per_tile=px_per_tile))


def drive(m, pose, steps: int = 60, cmd=(0.5, 0.5)) -> Simulator:
    sim = Simulator(m, BASE, render=False)
    sim.reset(0, 0, pose=pose)
    for _ in range(steps):
        sim.step(np.array([cmd]))
        if sim.collided[0]:
            break
    return sim


def test_driving_into_a_duckie_collides():
    duck = MapObject("duckie", 2.0, LANE_Y)
    sim = drive(with_objects(duck), POSE)
    assert sim.collided[0]
    x = sim.state[0, 0]
    # caught at physics rate: within one tick's travel of the contact distance
    assert duck.x - 0.04 - DUCKIE_MARGIN - 0.03 < x < duck.x - 0.04 - DUCKIE_MARGIN + 0.03
    assert not sim.off_road[0]
    sim.reset(0, 1, pose=POSE)
    assert not sim.collided[0]


def test_passing_a_duckie_at_0_3_m_does_not_collide():
    duck = MapObject("duckie", 2.0, LANE_Y + 0.3)
    sim = drive(with_objects(duck), POSE, steps=80)
    assert sim.state[0, 0] > duck.x + 0.3  # drove past it
    assert not sim.collided[0]


def test_robot_like_objects_use_the_centre_distance():
    bot = MapObject("duckiebot", 2.0, LANE_Y)
    cols = pack_objects([bot]).colliders
    assert cols[0, 6] == ROBOT_MARGIN
    sim = drive(with_objects(bot), POSE)
    assert sim.collided[0]
    assert sim.state[0, 0] == pytest.approx(bot.x - ROBOT_MARGIN, abs=0.03)


def test_start_on_an_object_is_a_collision():
    sim = Simulator(with_objects(MapObject("cone", POSE[0], POSE[1])), BASE, render=False)
    sim.reset(0, 0, pose=POSE)
    assert sim.collided[0]


def test_unknown_kind_is_a_grey_box():
    prims, robot = object_primitives(MapObject("mystery", 0.0, 0.0))
    assert len(prims) == 1 and prims[0].rgb == (150.0, 150.0, 150.0) and not robot


def test_culling_boxes_are_conservative(monkeypatch):
    """Frames equal those rendered with every visible primitive tested at every pixel (objects close by,
    partly behind the camera, at the image edges)."""
    import proxybench.domain.renderer as rmod

    objs = [MapObject("duckie", POSE[0] + 0.05, LANE_Y + 0.12), MapObject("barrier", POSE[0] + 0.1, LANE_Y - 0.15),
            MapObject("sign_stop", POSE[0] + 0.3, LANE_Y + 0.25), MapObject("duckiebot", POSE[0] + 0.5, LANE_Y),
            MapObject("cone", POSE[0] + 1.0, LANE_Y - 0.3, scale=1.5)]
    m = with_objects(*objs)
    poses = [POSE, (1.0, LANE_Y + 0.05, 0.4), (1.1, LANE_Y - 0.05, -0.5), (1.3, LANE_Y, 0.05)]
    culled = [render(m, pose=p) for p in poses]
    original = rmod.cull_objects

    def full_boxes(*args):
        original(*args)
        box = args[-1]
        box[..., 0], box[..., 1], box[..., 2], box[..., 3] = 0, args[-5], 0, args[-4]  # (.., w, h, vis, nvis, box)

    monkeypatch.setattr(rmod, "cull_objects", full_boxes)
    for p, img in zip(poses, culled, strict=True):
        assert np.array_equal(render(m, pose=p), img)


def test_collision_ends_runner_episodes_and_env_episodes_with_reason():
    from proxybench.agents.simple import StraightAgent
    from proxybench.domain.env import LaneFollowingEnv
    from proxybench.runner.episode import run_episode

    m = with_objects(MapObject("duckie", POSE[0] + 0.5, POSE[1]))
    sim = Simulator(m, DomainParams(image_width=80, image_height=60))
    traj = run_episode(sim, StraightAgent(0.5), 0, 10.0, pose=POSE)
    assert traj.termination == "collision" and traj.events[-1].kind == "collision"
    assert traj.duration < 3.0
    env = LaneFollowingEnv(map=m, params={"image_width": 80, "image_height": 60})
    env.reset(seed=0, options={"pose": POSE})
    for _ in range(60):
        _, _, terminated, _, info = env.step(np.array([0.5, 0.5]))
        if terminated:
            break
    assert terminated and info["collision"] and info["reward_terms"]["off_road"] < 0
