"""Effects the held-out targets use and no proxy θ expresses: per-motor response curves, latency jitter of
another shape, camera yaw and roll, the equidistant fisheye lens. Their defaults must change nothing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from proxybench.domain.camera import CameraModel, camera_table
from proxybench.domain.dynamics import ST, _jitter
from proxybench.domain.maps import load_map
from proxybench.domain.params import DUCKIEBOT_INTRINSICS, DomainParams
from proxybench.domain.render_objects import camera_row
from proxybench.domain.simulator import Simulator

TS = 0.585
START = (0.3, 1.28 * TS, 0.0)
STRAIGHT = load_map("straight_road")
W, H = 160, 120
PIN = DomainParams(image_width=W, image_height=H, texture_noise=0.0, blur_time=0.0)


def one_step(**params) -> np.ndarray:
    sim = Simulator(STRAIGHT, DomainParams(dynamics="kinematic", command_delay=0.0, physics_rate=15.0,
                                           frame_rate=15.0, **params), render=False)
    sim.reset(0, 0, pose=START)
    sim.step(np.array([[0.5, 0.5]]))
    return sim.state[0]


# --- motors ----------------------------------------------------------------------------------------


def test_motor_response_curves_are_applied_per_wheel():
    s = one_step(motor_gamma_left=1.5, motor_gamma_right=0.8)
    vl, vr = 0.6 * 0.5**1.5, 0.6 * 0.5**0.8
    assert s[ST.V] == pytest.approx(0.5 * (vl + vr), rel=1e-12)
    assert s[ST.OMEGA] == pytest.approx((vr - vl) / 0.102, rel=1e-12)
    assert s[ST.OMEGA] > 0  # the weaker left motor turns the robot left


def test_unequal_curves_make_an_imbalance_that_changes_with_speed_unlike_trim():
    """Trim scales both wheels by fixed factors; unequal curves give a left/right ratio that depends on the
    command, so no single trim cancels them at every speed."""
    def ratio(u: float, **params) -> float:
        sim = Simulator(STRAIGHT, DomainParams(dynamics="kinematic", command_delay=0.0, **params), render=False)
        sim.reset(0, 0, pose=START)
        sim.step(np.array([[u, u]]))
        v, w = sim.state[0, ST.V], sim.state[0, ST.OMEGA]
        return (v - 0.051 * w) / (v + 0.051 * w)  # left / right wheel speed
    assert ratio(0.3, trim=0.1) == pytest.approx(ratio(0.9, trim=0.1))
    assert ratio(0.3, motor_gamma_left=1.3) < ratio(0.9, motor_gamma_left=1.3) - 0.1


def test_equal_curves_drive_straight_and_unit_curves_change_nothing():
    s = one_step(motor_gamma_left=1.4, motor_gamma_right=1.4)
    assert s[ST.OMEGA] == 0.0 and s[ST.THETA] == 0.0
    assert np.array_equal(one_step(motor_gamma_left=1.0, motor_gamma_right=1.0), one_step())


# --- latency ---------------------------------------------------------------------------------------


def test_jitter_shape_one_is_the_uniform_draw_and_larger_shapes_are_mostly_short_with_rare_spikes():
    ticks = np.arange(20_000)
    uniform = np.array([_jitter(7, t, 6, 1.0) for t in ticks])
    spiky = np.array([_jitter(7, t, 6, 4.0) for t in ticks])
    assert uniform.min() == 0 and uniform.max() == 6 and abs(uniform.mean() - 3.0) < 0.1
    assert spiky.min() == 0 and spiky.max() == 6  # the longest delays still happen ...
    assert (spiky == 0).mean() > 0.5 and (spiky == 6).mean() < 0.05  # ... rarely
    # E[⌊7 U⁴⌋] computed on a fine grid of U
    u = (np.arange(1_000_000) + 0.5) / 1_000_000
    assert spiky.mean() == pytest.approx(np.floor(7 * u**4).mean(), abs=0.05)


def test_spiky_latency_keeps_commands_in_order():
    sim = Simulator(STRAIGHT, DomainParams(dynamics="kinematic", physics_rate=60.0, frame_rate=60.0, command_delay=0.0,
                                           delay_jitter=0.1, delay_jitter_shape=3.0), render=False)
    sim.reset(0, 0, pose=START)
    speeds = []
    for t in range(60):
        u = 0.5 if t >= 10 else 0.0
        sim.step(np.array([[u, u]]))
        speeds.append(sim.state[0, ST.V])
    first = int(np.argmax(np.array(speeds) > 0))
    assert 10 <= first <= 16 and np.all(np.array(speeds[first:]) == pytest.approx(0.3))


# --- camera mounting -------------------------------------------------------------------------------


@pytest.mark.parametrize(("yaw", "roll"), [(4.0, 0.0), (0.0, -3.0), (-2.5, 5.0)])
def test_project_inverts_ground_points_with_yaw_and_roll(yaw, roll):
    model = camera_table(PIN.replace(camera_yaw=yaw, camera_roll=roll)).model
    v, u = np.meshgrid(np.arange(70, 120, 7) + 0.5, np.arange(3, 160, 11) + 0.5, indexing="ij")
    gx, gy = model.ground_points(u, v)
    pu, pv = model.project(gx, gy)
    np.testing.assert_allclose(pu, u, atol=1e-6)
    np.testing.assert_allclose(pv, v, atol=1e-6)


def test_yaw_turns_the_view_left_and_roll_tilts_the_horizon():
    centre = camera_table(PIN).gy[H - 10, W // 2]
    left = camera_table(PIN.replace(camera_yaw=5.0)).gy[H - 10, W // 2]
    assert abs(centre) < 1e-3 and left > 0.005  # the image centre now looks left of the robot
    sky = camera_table(PIN.replace(camera_roll=4.0)).sky  # clockwise seen from behind: the right side dips
    first_ground = [int(np.argmax(~sky[:, u])) for u in (2, W - 3)]
    assert first_ground[1] < first_ground[0]  # so the horizon sits higher on the right of the image


def test_roll_renders_rows_that_are_part_sky_part_ground():
    p = PIN.replace(camera_roll=8.0)
    assert not CameraModel.from_params(p).rows_are_lines and CameraModel.from_params(p.replace(camera_roll=0,
                                                                                              camera_yaw=3)).rows_are_lines
    sim = Simulator(STRAIGHT, p)
    sim.reset(0, 0, pose=(1.0, 1.28 * TS, 0.0))
    img = sim.render()[0].astype(float)
    sky = camera_table(p).sky
    mixed = [v for v in range(H) if sky[v].any() and not sky[v].all()]
    assert mixed  # the horizon crosses rows
    sky_colour = np.all(np.abs(img - np.array(p.horizon_rgb)) < 40, axis=-1) | np.all(
        np.abs(img - np.array(p.sky_rgb)) < 40, axis=-1)
    assert sky_colour[sky].mean() > 0.99  # every sky pixel is drawn as sky, also on mixed rows


def test_yaw_or_roll_turn_off_the_pinhole_object_culling():
    assert camera_row(camera_table(PIN).model)[8] == 1.0
    assert camera_row(camera_table(PIN.replace(camera_yaw=2.0)).model)[8] == 0.0
    assert camera_row(camera_table(PIN.replace(camera_roll=2.0)).model)[8] == 0.0


# --- lens ------------------------------------------------------------------------------------------


def test_equidistant_lens_round_trip_and_near_the_calibrated_plumb_bob():
    eq = PIN.replace(fisheye=True, lens_model="equidistant", distortion=(0.119, -0.044, 0.0, 0.0, 0.0))
    model = CameraModel.from_params(eq)
    x = np.linspace(-1.2, 1.2, 25)
    xd, yd = model._distort_equidistant(x, 0.6 * x)
    xu, yu = model.undistort(xd, yd)
    np.testing.assert_allclose(xu, x, atol=1e-9)
    np.testing.assert_allclose(yu, 0.6 * x, atol=1e-9)
    # ground hits of the lower image: the fitted equidistant lens is close to the plumb-bob calibration,
    # an uncorrected equidistant one (all k = 0) is not
    pb = camera_table(PIN.replace(fisheye=True))
    near = camera_table(eq)
    far = camera_table(eq.replace(distortion=(0.0, 0.0, 0.0, 0.0, 0.0)))
    rows = slice(H - 30, H)
    d_near = np.median(np.hypot(near.gx[rows] - pb.gx[rows], near.gy[rows] - pb.gy[rows]))
    d_far = np.median(np.hypot(far.gx[rows] - pb.gx[rows], far.gy[rows] - pb.gy[rows]))
    assert d_near < 0.002 < d_far  # [m], median over the pixels


def test_equidistant_lens_renders():
    p = PIN.replace(fisheye=True, lens_model="equidistant", distortion=(0.1, -0.03, 0.0, 0.0, 0.0),
                    intrinsics=DUCKIEBOT_INTRINSICS, camera_yaw=2.0, camera_roll=-2.0)
    sim = Simulator(STRAIGHT, p)
    sim.reset(0, 0, pose=(1.0, 1.28 * TS, 0.0))
    img = sim.render()[0]
    assert img.shape == (H, W, 3)
    assert np.abs(img[H - 3, W // 2].astype(float) - p.road_rgb).max() <= 3  # road ahead
    assert camera_table(p).sky[:3].all()


def test_lens_model_is_validated():
    with pytest.raises(ValueError, match="lens_model"):
        DomainParams(lens_model="fisheye")
    assert math.isclose(DomainParams(camera_yaw=45.0).camera_yaw, 45.0)
    with pytest.raises(ValueError, match="camera_yaw"):
        DomainParams(camera_yaw=60.0)
