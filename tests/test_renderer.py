"""Camera images: what the robot sees where, horizon geometry, blur, light, lens and noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from proxybench.domain.camera import CameraModel, camera_table
from proxybench.domain.maps import load_map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator

TS = 0.585
LANE_Y = 1.28 * TS  # eastbound right-lane centre of straight_road
POSE = (1.0, LANE_Y, 0.0)
W, H = 160, 120
BASE = DomainParams(image_width=W, image_height=H, texture_noise=0.0, blur_time=0.0)
STRAIGHT = load_map("straight_road")


def render(params: DomainParams = BASE, pose=POSE, seed: int = 0, steps: int = 0, cmd=(0.0, 0.0)) -> np.ndarray:
    sim = Simulator(STRAIGHT, params)
    sim.reset(0, seed, pose=pose)
    for _ in range(steps):
        sim.step(np.array([cmd]))
    img = sim.render()
    assert img.shape == (1, params.image_height, params.image_width, 3)
    assert img.dtype == np.uint8
    return img[0]


def is_sky(img: np.ndarray, p: DomainParams = BASE) -> np.ndarray:
    """Pixels coloured as a blend of sky_rgb and horizon_rgb (both have blue 225 in the defaults)."""
    lo = np.minimum(p.sky_rgb, p.horizon_rgb) - 1
    hi = np.maximum(p.sky_rgb, p.horizon_rgb) + 1
    return np.all((img >= lo) & (img <= hi), axis=-1)


def first_ground_row(img: np.ndarray) -> int:
    rows = np.flatnonzero(~is_sky(img).all(axis=1))
    return int(rows[0])


@pytest.fixture(scope="module")
def centred() -> np.ndarray:
    return render()


# ---------------------------------------------------------------------------------------------------
# (a), (b) what is where


def test_road_ahead_is_road_coloured(centred):
    patch = centred[H - 20 :, W // 2 - 10 : W // 2 + 10].reshape(-1, 3).astype(float)
    assert np.abs(patch - np.array(BASE.road_rgb)).max() <= 2.0


def test_road_colour_follows_params():
    img = render(BASE.replace(road_rgb=(100.0, 20.0, 30.0)))
    assert np.abs(img[H - 5, W // 2].astype(float) - (100, 20, 30)).max() <= 2.0


def test_yellow_left_white_right_when_centred_in_right_lane(centred):
    lower = centred[H // 2 :].astype(int)
    yellow = (lower[..., 0] > 150) & (lower[..., 1] > 120) & (lower[..., 2] < 100)
    white = np.all(lower > 200, axis=-1)
    assert yellow.sum() > 20 and white.sum() > 20
    assert np.nonzero(yellow)[1].mean() < W / 2
    assert np.nonzero(white)[1].mean() > W / 2
    # a robot in the left lane heading west sees the same picture: the road is symmetric
    mirrored = render(pose=(3.0, 1.72 * TS, math.pi))[H // 2 :].astype(int)
    yellow_w = (mirrored[..., 0] > 150) & (mirrored[..., 1] > 120) & (mirrored[..., 2] < 100)
    assert np.nonzero(yellow_w)[1].mean() < W / 2


def test_markings_swap_sides_when_heading_the_other_way():
    # in the eastbound lane but heading west: the yellow line is now on the right
    img = render(pose=(3.0, LANE_Y, math.pi))[H // 2 :].astype(int)
    yellow = (img[..., 0] > 150) & (img[..., 1] > 120) & (img[..., 2] < 100)
    white = np.all(img > 200, axis=-1)
    assert np.nonzero(yellow)[1].mean() > W / 2
    assert np.nonzero(white)[1].mean() < W / 2


def test_projected_white_line_point_is_white(centred):
    model = CameraModel.from_params(BASE)
    # the outer white line spans 0.408..0.49 tile right of the road centre; the robot is 0.22 tile right
    y_white = -((0.408 + 0.49) / 2 - 0.22) * TS
    y_road = -0.05
    for x in (0.3, 0.45):
        u, v = model.project(np.array(x), np.array(y_white))
        assert 0 <= u < W and 0 <= v < H
        assert np.all(centred[int(v), int(u)] > 200)
        u, v = model.project(np.array(x), np.array(y_road))
        assert np.abs(centred[int(v), int(u)].astype(float) - BASE.road_rgb).max() <= 2


def test_grass_beside_the_road():
    # turned to face north from the lane centre: the road ends 0.72 tile ahead, then grass
    img = render(pose=(2.0, LANE_Y, math.pi / 2))
    model = CameraModel.from_params(BASE)
    u, v = model.project(np.array(0.9), np.array(0.0))  # 0.9 m ahead: on the grass north of the road
    assert np.abs(img[int(v), int(u)].astype(float) - BASE.grass_rgb).max() <= 2


def test_default_image_size():
    img = render(DomainParams(texture_noise=0.0, blur_time=0.0))
    assert img.shape == (480, 640, 3)
    assert np.abs(img[470, 320].astype(float) - BASE.road_rgb).max() <= 2


# ---------------------------------------------------------------------------------------------------
# (c) horizon


def horizon_row(p: DomainParams) -> int:
    """First pixel row whose centre looks below the horizon, by hand for a pinhole camera."""
    fy = 0.5 * p.image_height / math.tan(math.radians(p.camera_fov_y) / 2)
    v_h = 0.5 * p.image_height - fy * math.tan(math.radians(p.camera_pitch))
    return math.floor(v_h - 0.5) + 1  # smallest v with v + 0.5 > v_h


@pytest.mark.parametrize("pitch", [10.0, 19.15, 25.0])
def test_camera_table_horizon_matches_hand_computation(pitch):
    p = BASE.replace(camera_pitch=pitch)
    table = camera_table(p)
    row = horizon_row(p)
    assert table.sky[:row].all()
    assert not table.sky[row:].any()
    # the rendered frame changes from sky to ground at the same row
    assert first_ground_row(render(p)) == row


def test_more_pitch_moves_the_horizon_up():
    low = BASE.replace(camera_pitch=10.0)
    high = BASE.replace(camera_pitch=25.0)
    row_low = first_ground_row(render(low))
    row_high = first_ground_row(render(high))
    # tilting the camera further down brings the horizon up the image (smaller row index)
    assert row_high < row_low
    assert (row_low, row_high) == (46, 24)
    # a camera looking up above the horizon sees the sky in its whole upper half
    up = BASE.replace(camera_pitch=-10.0)
    assert first_ground_row(render(up)) > H // 2


def test_camera_table_ground_points_are_on_the_ground():
    table = camera_table(BASE)
    model = table.model
    v, u = 100, 40
    gx, gy = table.gx[v, u], table.gy[v, u]
    pu, pv = model.project(np.array(gx), np.array(gy))
    assert pu == pytest.approx(u + 0.5, abs=1e-6)
    assert pv == pytest.approx(v + 0.5, abs=1e-6)
    assert gy > 0  # left half of the image sees the left of the robot


# ---------------------------------------------------------------------------------------------------
# (d) motion blur


def test_motion_blur_only_while_moving():
    blur = BASE.replace(blur_time=0.1, blur_samples=4)
    moving_sharp = render(BASE, steps=10, cmd=(0.5, 1.0))
    moving_blur = render(blur, steps=10, cmd=(0.5, 1.0))
    assert np.abs(moving_sharp.astype(int) - moving_blur).max() > 20
    still_sharp = render(BASE, steps=10, cmd=(0.0, 0.0))
    still_blur = render(blur, steps=10, cmd=(0.0, 0.0))
    np.testing.assert_array_equal(still_sharp, still_blur)


def test_blur_does_not_reach_before_the_episode_start():
    # right after reset there is no past motion to blur
    np.testing.assert_array_equal(render(BASE.replace(blur_time=0.2)), render(BASE))


# ---------------------------------------------------------------------------------------------------
# (e) light


def test_brightness_adds_to_every_channel(centred):
    bright = render(BASE.replace(brightness=30.0)).astype(int)
    dark = render(BASE.replace(brightness=-30.0)).astype(int)
    base = centred.astype(int)
    room = base <= 255 - 30
    assert np.all(bright >= base)
    assert np.abs(bright[room] - (base[room] + 30)).max() <= 1
    assert np.all(bright[~room] == 255)
    floor = base >= 30
    assert np.all(dark <= base)
    assert np.abs(dark[floor] - (base[floor] - 30)).max() <= 1


def test_contrast_spreads_values_around_mid_grey(centred):
    high = render(BASE.replace(contrast=1.5)).astype(float)
    low = render(BASE.replace(contrast=0.5)).astype(float)
    base = centred.astype(float)
    expect_high = np.clip(127.5 + 1.5 * (base - 127.5), 0, 255)
    assert np.abs(high - expect_high).max() <= 1.5
    assert np.abs(low - (127.5 + 0.5 * (base - 127.5))).max() <= 1.5
    road = (H - 1, W // 2)
    assert high[road].max() < base[road].min()  # dark road darker
    assert low[road].min() > base[road].max()  # and lighter with less contrast
    sky = (0, W // 2)
    assert high[sky][0] > base[sky][0]


def test_light_rgb_scales_channels(centred):
    img = render(BASE.replace(light_rgb=(1.0, 0.5, 2.0))).astype(float)
    road = np.array(BASE.road_rgb)
    assert img[H - 1, W // 2] == pytest.approx(np.minimum(road * (1.0, 0.5, 2.0), 255), abs=1)


def test_vignetting_darkens_corners_not_centre(centred):
    img = render(BASE.replace(vignetting=0.8)).astype(int)
    base = centred.astype(int)
    assert np.all(img <= base)
    assert img[H - 1, 0].sum() < base[H - 1, 0].sum()
    assert np.abs(img[H // 2, W // 2] - base[H // 2, W // 2]).max() <= 1


# ---------------------------------------------------------------------------------------------------
# (f) fisheye


def test_fisheye_renders_and_differs_from_pinhole(centred):
    fish = render(BASE.replace(fisheye=True))
    assert fish.shape == centred.shape
    assert (fish != centred).any(axis=-1).mean() > 0.05
    # still the road ahead at the bottom centre and sky at the top
    assert np.abs(fish[H - 3, W // 2].astype(float) - BASE.road_rgb).max() <= 2
    assert is_sky(fish[:5]).all()


def test_fisheye_table_uses_calibrated_intrinsics():
    p = BASE.replace(fisheye=True)
    model = camera_table(p).model
    fx, fy, cx, cy = p.intrinsics
    assert (model.fx, model.fy) == pytest.approx((fx * W / 640, fy * H / 480))
    assert (model.cx, model.cy) == pytest.approx((cx * W / 640, cy * H / 480))
    assert model.distortion == p.distortion


# ---------------------------------------------------------------------------------------------------
# (g) noise


def test_noise_reproducible_for_same_seed_and_frame(centred):
    p = BASE.replace(noise_std=10.0)
    a = render(p, seed=3, steps=2)
    b = render(p, seed=3, steps=2)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a.astype(int) - render(BASE, seed=3, steps=2)).mean() > 3  # noise is there
    assert not np.array_equal(a, render(p, seed=4, steps=2))  # another seed, other noise
    # another frame, other noise (the robot stands still, so only the noise changes)
    assert not np.array_equal(a, render(p, seed=3, steps=3))


def test_render_twice_same_frame_identical():
    sim = Simulator(STRAIGHT, BASE.replace(noise_std=5.0, texture_noise=0.06))
    sim.reset(0, 11, pose=POSE)
    sim.step(np.array([[0.3, 0.3]]))
    np.testing.assert_array_equal(sim.render(), sim.render())


def test_batch_render_equals_single_render():
    pa = BASE.replace(noise_std=4.0, brightness=10.0)
    pb = BASE.replace(contrast=1.2, camera_pitch=15.0)
    batch = Simulator(STRAIGHT, [pa, pb])
    poses = [POSE, (2.0, 1.72 * TS, math.pi)]
    for i, pose in enumerate(poses):
        batch.reset(i, 20 + i, pose=pose)
    frames = batch.render()
    for i, (p, pose) in enumerate(zip((pa, pb), poses, strict=True)):
        np.testing.assert_array_equal(frames[i], render(p, pose=pose, seed=20 + i))


def test_span_renderer_equals_per_pixel_renderer():
    """The fast pinhole path (rows as lines on the ground, cut into per-tile spans) and the general per-pixel
    path (used for the fisheye lens) give the same image, at tile corners and axis-aligned headings too."""
    p = BASE.replace(texture_noise=0.06)
    rng = np.random.default_rng(0)
    for name in ("intersections", "zigzag"):
        sim = Simulator(name, p)
        w, h = sim.map.size_m
        for k in range(8):
            heading = (0.0, math.pi / 2, math.pi, rng.uniform(-math.pi, math.pi))[k % 4]
            pose = (rng.uniform(0, w), rng.uniform(0, h), heading)
            if k == 0:
                pose = (2 * TS, 2 * TS, math.pi / 4)  # on a tile corner, rows cross many tile edges
            sim.reset(0, 0, pose=pose)
            fast = sim.render().copy()
            stack = sim.renderer._prepare()
            assert stack[0].all()  # pinhole camera: the span path is used
            sim.renderer._stack = (np.zeros_like(stack[0]), *stack[1:])
            slow = sim.render().copy()
            sim.renderer._stack = stack
            np.testing.assert_array_equal(fast, slow)


def test_render_without_renderer_raises():
    sim = Simulator(STRAIGHT, BASE, render=False)
    with pytest.raises(RuntimeError, match="render=False"):
        sim.render()


def _ground_reference(r, n: int, x: float, y: float, level: int) -> np.ndarray:
    """Robot n's ground colour at map point (x, y), mip level ``level``, shaded in plain Python."""
    la, tex, pal = r.lanes, r.tex, r.palette[n]
    n_pal = pal.shape[0] - 5
    fi, fj = x * (1.0 / la.tile_size), y * (1.0 / la.tile_size)
    if not (0.0 <= fi < la.tile_kind.shape[0] and 0.0 <= fj < la.tile_kind.shape[1]):
        return pal[n_pal + 4]  # the world outside the map
    ti, tj = int(fi), int(fj)
    lx, ly = fi - ti, fj - tj
    kind = int(la.tile_kind[ti, tj])
    a = r._affine[ti, tj]
    tu, tv = (lx, ly) if kind < 0 else (a[0] + a[1] * lx + a[2] * ly, a[3] + a[4] * lx + a[5] * ly)
    sz = tex.size >> level
    tx, ty = min(max(int(tu * sz), 0), sz - 1), min(max(int(tv * sz), 0), sz - 1)
    idx = n_pal + int(r._base[ti, tj]) if kind < 0 else int(tex.texels[tex.offsets[kind, level] + ty * sz + tx])
    g = r._grain[r.grain_index[n]]
    gsize = int(math.isqrt(g.size))
    grain = float(g[((ty + int(a[7])) % gsize) * gsize + (tx + int(a[6])) % gsize])
    return pal[idx] * (1.0 + r.post[n, 0] / (1 << level) * grain)


def test_curved_row_shading_equals_plain_python_reference():
    """A fisheye camera's rows go through ``curve_row`` (the serial kernel's general path): it stores, then
    adds, every ground pixel's colour as the plain per-point shading gives it, on and off the map, and
    leaves sky pixels alone."""
    from proxybench.domain.render_ground import curve_row

    p = DomainParams(image_width=24, image_height=18, fisheye=True, texture_noise=0.3, blur_time=0.0)
    sim = Simulator("intersections", p)
    r = sim.renderer
    _, gx, gy, levels, *_ = r._prepare()
    la, tex = r.lanes, r.tex
    amp = np.array([r.post[0, 0] / (1 << lv) for lv in range(16)])
    w, h = sim.map.size_m
    # the last two look off the map
    poses = [(0.5 * w, 0.5 * h, 0.3), (0.05, 0.4 * h, math.pi), (0.7 * w, 0.2, -math.pi / 2)]
    n_ground = n_outside = 0
    for v in range(p.image_height):
        acc = np.full((p.image_width, 3), -7.0)
        expected = acc.copy()
        for k, (px, py, th) in enumerate(poses):
            cs, sn = math.cos(th), math.sin(th)
            curve_row(acc, k == 0, px, py, cs, sn, gx[0, v], gy[0, v], levels[0, v], amp, r.palette[0],
                      r._grain[0], 1.0 / la.tile_size, la.tile_kind, r._affine, r._base, tex.texels, tex.offsets,
                      tex.size, r.palette.shape[1] - 5)
            for u in range(p.image_width):
                if levels[0, v, u] < 0:
                    continue
                x = px + cs * gx[0, v, u] - sn * gy[0, v, u]
                y = py + sn * gx[0, v, u] + cs * gy[0, v, u]
                colour = _ground_reference(r, 0, x, y, int(levels[0, v, u]))
                expected[u] = colour if k == 0 else expected[u] + colour
                n_ground += 1
                n_outside += not (0.0 <= x < w and 0.0 <= y < h)
        np.testing.assert_allclose(acc, expected, rtol=1e-9, atol=1e-9)
    assert n_ground > 300 and n_outside > 10  # both the map and the world beyond it were shaded
    assert (levels[0] < 0).any()  # and some pixels were sky, left at -7


def test_sky_rows_copied_from_the_cache_equal_shaded_ones(monkeypatch):
    """All-sky rows come from a per-robot cache of the kernel's own bytes; a change of sky colour, light,
    camera pitch or lens (``set_params``) must refresh it, and frames equal those shaded at every frame."""
    import proxybench.domain.renderer as renderer_mod

    variants = [BASE, BASE.replace(sky_rgb=(90.0, 120.0, 250.0), brightness=12.0), BASE.replace(contrast=1.3),
                BASE.replace(camera_pitch=5.0), BASE.replace(vignetting=0.5), BASE.replace(fisheye=True),
                BASE.replace(camera_pitch=-10.0, horizon_rgb=(250.0, 200.0, 150.0))]

    def frames() -> list[np.ndarray]:
        sim = Simulator(STRAIGHT, [BASE, BASE])
        out = []
        for k, p in enumerate(variants):
            sim.set_params(k % 2, p)
            sim.reset(k % 2, k, pose=POSE)
            out.append(sim.render().copy())
        return out

    cached = frames()
    sim = Simulator(STRAIGHT, BASE)
    sim.render()
    assert (sim.renderer._sky[0] >= 0).any() and sim.renderer._sky[1].shape[1] > 0  # the cache is in use
    monkeypatch.setattr(renderer_mod, "SKY_CACHE_BYTES", 0)
    shaded = frames()
    for a, b in zip(cached, shaded, strict=True):
        np.testing.assert_array_equal(a, b)
