"""DB18 dynamics through the simulator: trim, top speed, command delay, exact SE(2), dead-band, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from proxybench.domain.dynamics import DYN_FIELDS, ST, pack_dynamics, pwm_from_velocity, wheel_ticks
from proxybench.domain.lane_pose import LP
from proxybench.domain.maps import load_map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator

TS = 0.585
LANE_Y = 1.28 * TS  # eastbound right-lane centre of straight_road
START = (0.3, LANE_Y, 0.0)
STRAIGHT = load_map("straight_road")
LOOP = load_map("loop_3x3")


def make_sim(map_=STRAIGHT, pose=START, seed=0, **params) -> Simulator:
    sim = Simulator(map_, DomainParams(**params), render=False)
    sim.reset(0, seed, pose=pose)
    return sim


def drive(sim: Simulator, left: float, right: float, steps: int) -> None:
    for _ in range(steps):
        sim.step(np.array([[left, right]]))


# ---------------------------------------------------------------------------------------------------
# (a) trim


@pytest.mark.parametrize("dynamics", ["dynamic", "kinematic"])
def test_positive_trim_curves_left_negative_right_zero_straight(dynamics):
    headings = {}
    ys = {}
    for trim in (0.1, 0.0, -0.1):
        sim = make_sim(trim=trim, dynamics=dynamics)
        drive(sim, 0.5, 0.5, 15)
        headings[trim] = sim.state[0, ST.THETA]
        ys[trim] = sim.state[0, ST.Y]
        assert sim.state[0, ST.X] > START[0] + 0.1  # it moved forward
    assert headings[0.1] > 0.05  # left turn: heading increases (counter-clockwise)
    assert headings[-0.1] < -0.05
    assert headings[0.0] == 0.0  # equal wheels, no trim: exactly straight
    assert ys[0.0] == LANE_Y
    assert ys[0.1] > LANE_Y > ys[-0.1]
    # the model is mirror-symmetric in the trim
    assert headings[0.1] == pytest.approx(-headings[-0.1], abs=1e-12)


def test_gain_scales_speed():
    slow = make_sim(dynamics="kinematic", command_delay=0.0, gain=0.5)
    drive(slow, 1.0, 1.0, 1)
    assert slow.state[0, ST.V] == pytest.approx(0.3)


def test_leaving_the_road_sets_off_road_but_physics_keeps_running():
    sim = make_sim(pose=(2.0, LANE_Y, math.pi / 2))  # heading north, across the road
    assert not sim.off_road[0]
    ys = []
    for _ in range(40):
        sim.step(np.array([[1.0, 1.0]]))
        ys.append(sim.state[0, ST.Y])
    assert sim.off_road[0]
    assert ys[-1] > 2 * TS + 0.3  # well into the grass north of the road
    assert np.all(np.diff(ys[5:]) > 0)  # still moving at the end
    # the flag sticks even if the robot came back onto the road
    back = make_sim(pose=(2.0, LANE_Y, math.pi / 2))
    drive(back, 1.0, 1.0, 15)
    assert back.off_road[0]
    returned = False
    for _ in range(40):
        back.step(np.array([[-1.0, -1.0]]))
        returned |= back.lane[0, LP.ON_ROAD] == 1.0  # on the road again by position
        assert back.off_road[0]
    assert returned


# ---------------------------------------------------------------------------------------------------
# (b) top speed


def test_dynamic_model_top_speed():
    sim = make_sim(physics_rate=60.0, frame_rate=15.0)
    drive(sim, 1.0, 1.0, 75)  # 5 s, 25 time constants of 1/a_v = 0.2 s
    # steady state of dv/dt = -a_v v + b_v (R + L): v = 1.5 × 2 / 5
    assert sim.state[0, ST.V] == pytest.approx(0.6, abs=1e-6)
    assert sim.state[0, ST.OMEGA] == 0.0


def test_dynamic_model_first_order_response():
    sim = make_sim(command_delay=0.0, physics_rate=60.0, frame_rate=60.0)
    a, b, dt = 5.0, 1.5, 1 / 60
    v = 0.0
    for _ in range(30):
        sim.step(np.array([[0.4, 0.4]]))
        v = v + dt * (-a * v + b * 0.8)  # forward Euler, as documented
        assert sim.state[0, ST.V] == pytest.approx(v, rel=1e-12)
    # steady state scales with the command
    drive(sim, 0.4, 0.4, 600)
    assert sim.state[0, ST.V] == pytest.approx(1.5 * 0.8 / 5.0, rel=1e-9)


def test_kinematic_model_reaches_top_speed_immediately():
    sim = make_sim(dynamics="kinematic", command_delay=0.0, kinematic_max_speed=0.6)
    drive(sim, 1.0, 1.0, 1)
    assert sim.state[0, ST.V] == pytest.approx(0.6, abs=1e-12)
    # one frame = 4 ticks at full speed from the start
    assert sim.state[0, ST.X] == pytest.approx(START[0] + 0.6 / 15, abs=1e-12)


def test_motor_saturation_clips_the_command():
    sim = make_sim(dynamics="kinematic", command_delay=0.0, motor_saturation=0.5)
    drive(sim, 1.0, 1.0, 1)
    assert sim.state[0, ST.V] == pytest.approx(0.3, abs=1e-12)


def test_commands_outside_unit_range_are_clipped_and_non_finite_rejected():
    sim = make_sim(dynamics="kinematic", command_delay=0.0)
    drive(sim, 3.0, 3.0, 1)
    assert sim.state[0, ST.V] == pytest.approx(0.6, abs=1e-12)
    with pytest.raises(ValueError, match="finite"):
        sim.step(np.array([[np.nan, 0.0]]))


# ---------------------------------------------------------------------------------------------------
# (c) command delay


def _velocity_trace(command_delay: float, commands: np.ndarray, dynamics: str = "dynamic") -> np.ndarray:
    sim = make_sim(physics_rate=60.0, frame_rate=60.0, command_delay=command_delay, dynamics=dynamics)
    assert sim.substeps == 1
    out = []
    for c in commands:
        sim.step(c[None])
        out.append(sim.state[0, [ST.V, ST.OMEGA]].copy())
    return np.array(out)


@pytest.mark.parametrize("k", [1, 3, 9])
@pytest.mark.parametrize("dynamics", ["dynamic", "kinematic"])
def test_command_delay_shifts_response_by_exactly_the_delay(k, dynamics):
    rng = np.random.default_rng(k)
    commands = rng.uniform(-1, 1, (60, 2))
    ref = _velocity_trace(0.0, commands, dynamics)
    delayed = _velocity_trace(k / 60.0, commands, dynamics)
    assert np.any(ref != 0.0)
    # nothing happens before the first command arrives
    assert np.all(delayed[:k] == 0.0)
    # then exactly the undelayed response, k ticks later (bit for bit)
    np.testing.assert_array_equal(delayed[k:], ref[:-k])


def test_command_delay_is_rounded_to_physics_ticks():
    p = DomainParams(command_delay=0.05, physics_rate=60.0, frame_rate=15.0)
    assert p.delay_ticks == 3
    assert DomainParams(command_delay=0.0, physics_rate=60.0).delay_ticks == 0


def test_delay_jitter_never_reorders_commands():
    """Commands arrive in order: the applied command index never goes backwards, so a step up stays up."""
    sim = make_sim(dynamics="kinematic", physics_rate=60.0, frame_rate=60.0, command_delay=0.0, delay_jitter=0.1)
    speeds = []
    for t in range(60):
        u = 0.5 if t >= 10 else 0.0
        sim.step(np.array([[u, u]]))
        speeds.append(sim.state[0, ST.V])
    speeds = np.array(speeds)
    assert np.all(speeds[:10] == 0.0)
    first = int(np.argmax(speeds > 0))
    assert 10 <= first <= 10 + 6  # at most jitter_ticks late
    assert np.all(speeds[first:] == pytest.approx(0.3))


# ---------------------------------------------------------------------------------------------------
# (d) exact SE(2) update


def test_constant_twist_draws_an_exact_circle():
    # kinematic model, no delay: v = 0.6 (l + r) / 2, ω = 0.6 (r - l) / d, held for N ticks = one revolution
    n_ticks, dt, d = 120, 1 / 60, 0.102
    left = 0.2
    right = left + 2 * math.pi * d / (0.6 * n_ticks * dt)
    v = 0.6 * (left + right) / 2
    w = 0.6 * (right - left) / d
    assert w * n_ticks * dt == pytest.approx(2 * math.pi, abs=1e-14)
    radius = v / w
    x0, y0, th0 = 3.0 * TS, 1.0, 0.3
    sim = make_sim(LOOP, pose=(x0, y0, th0), dynamics="kinematic", command_delay=0.0,
                   physics_rate=60.0, frame_rate=60.0)
    centre = (x0 - radius * math.sin(th0), y0 + radius * math.cos(th0))
    for t in range(1, n_ticks + 1):
        sim.step(np.array([[left, right]]))
        x, y, th = sim.state[0, :3]
        # every pose on the circle, tangent to it
        assert math.hypot(x - centre[0], y - centre[1]) == pytest.approx(radius, abs=1e-9)
        assert math.remainder(th - (th0 + w * t * dt), 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
        if t == n_ticks // 2:
            assert math.hypot(x - x0, y - y0) == pytest.approx(2 * radius, abs=1e-9)
    x, y, th = sim.state[0, :3]
    assert x == pytest.approx(x0, abs=1e-9)
    assert y == pytest.approx(y0, abs=1e-9)
    assert math.remainder(th - th0, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    assert sim.off_road[0]  # driven on the grass beside the loop: the physics ran regardless


def test_turning_on_the_spot():
    sim = make_sim(dynamics="kinematic", command_delay=0.0)
    drive(sim, -0.5, 0.5, 5)
    assert sim.state[0, ST.X] == pytest.approx(START[0], abs=1e-12)
    assert sim.state[0, ST.Y] == pytest.approx(START[1], abs=1e-12)
    assert sim.state[0, ST.THETA] == pytest.approx(5 / 15 * 0.6 / 0.102, abs=1e-12)


# ---------------------------------------------------------------------------------------------------
# (e) dead-band


@pytest.mark.parametrize("dynamics", ["dynamic", "kinematic"])
def test_deadband_below_threshold_does_not_move(dynamics):
    sim = make_sim(motor_deadband=0.2, command_delay=0.0, dynamics=dynamics)
    drive(sim, 0.19, 0.19, 10)
    drive(sim, -0.15, 0.1, 10)
    assert tuple(sim.state[0, :3]) == START
    assert sim.state[0, ST.V] == 0.0 and sim.state[0, ST.OMEGA] == 0.0
    drive(sim, 0.3, 0.3, 5)
    assert sim.state[0, ST.X] > START[0]


def test_deadband_rescales_above_threshold():
    sim = make_sim(motor_deadband=0.2, command_delay=0.0, dynamics="kinematic")
    drive(sim, 0.6, 0.6, 1)
    # (0.6 - 0.2) / (1 - 0.2) = 0.5 of full speed
    assert sim.state[0, ST.V] == pytest.approx(0.3, abs=1e-12)


# ---------------------------------------------------------------------------------------------------
# (f) pwm_from_velocity


def test_pwm_from_velocity_direction_and_symmetry():
    assert pwm_from_velocity(0.0, 0.0) == (0.0, 0.0)
    ul, ur = pwm_from_velocity(0.2, 0.0)
    assert ul == ur > 0
    assert pwm_from_velocity(-0.2, 0.0) == (-ul, -ur)
    ul, ur = pwm_from_velocity(0.2, 1.0)
    assert ur > ul > 0  # turning left (positive ω): right wheel faster
    assert pwm_from_velocity(0.2, -1.0) == pytest.approx((ur, ul))  # mirror image
    assert pwm_from_velocity(-0.2, -1.0) == pytest.approx((-ul, -ur))
    ul, ur = pwm_from_velocity(0.0, 2.0)
    assert ul == pytest.approx(-ur) and ur > 0  # on the spot


def test_pwm_from_velocity_values_and_limit():
    # ω_wheel = v / radius, PWM = ω_wheel × gain / k
    ul, ur = pwm_from_velocity(0.1, 0.0)
    assert ul == pytest.approx(0.1 / 0.0318 / 27.0)
    assert pwm_from_velocity(5.0, 0.0) == (1.0, 1.0)
    assert pwm_from_velocity(-5.0, 0.0, limit=0.8) == (-0.8, -0.8)
    # trim shifts power to the right wheel
    ul, ur = pwm_from_velocity(0.1, 0.0, trim=0.1)
    assert ur > ul


# ---------------------------------------------------------------------------------------------------
# (g) determinism


def test_same_seed_same_params_bit_identical_with_jitter():
    params = DomainParams(delay_jitter=0.05, command_delay=0.05, slip_speed=0.3, slip_turn=0.1, trim=0.03)
    sims = [Simulator(LOOP, params, render=False) for _ in range(2)]
    rng = np.random.default_rng(7)
    commands = rng.uniform(-0.2, 1.0, (100, 1, 2))
    for sim in sims:
        sim.reset(0, seed=123)
    np.testing.assert_array_equal(sims[0].state, sims[1].state)
    for c in commands:
        for sim in sims:
            sim.step(c)
    np.testing.assert_array_equal(sims[0].state, sims[1].state)
    np.testing.assert_array_equal(sims[0].lane, sims[1].lane)
    np.testing.assert_array_equal(sims[0].tick, sims[1].tick)
    # the jitter depends on the seed: another seed, same start pose, differs
    other = Simulator(LOOP, params, render=False)
    other.reset(0, seed=124, pose=tuple(sims[0].state[0, :3]))
    sims[0].reset(0, seed=123, pose=tuple(sims[0].state[0, :3]))
    for c in commands[:40]:
        other.step(c)
        sims[0].step(c)
    assert not np.array_equal(sims[0].state, other.state)


def test_batch_robot_equals_single_robot():
    pa = DomainParams(trim=0.05, delay_jitter=0.03)
    pb = DomainParams(trim=-0.05, command_delay=0.1)
    batch = Simulator(LOOP, [pa, pb], render=False)
    singles = [Simulator(LOOP, p, render=False) for p in (pa, pb)]
    for i, s in enumerate(singles):
        batch.reset(i, seed=10 + i)
        s.reset(0, seed=10 + i)
    rng = np.random.default_rng(1)
    for _ in range(50):
        c = rng.uniform(0, 1, (2, 2))
        batch.step(c)
        for i, s in enumerate(singles):
            s.step(c[i : i + 1])
    for i, s in enumerate(singles):
        np.testing.assert_array_equal(batch.state[i], s.state[0])


def test_reset_with_seed_draws_a_reproducible_start_on_the_lane():
    sim = Simulator(LOOP, DomainParams(), render=False)
    sim.reset(0, seed=5)
    a = sim.state[0].copy()
    sim.reset(0, seed=5)
    np.testing.assert_array_equal(sim.state[0], a)
    assert sim.lane[0, 0] == 1.0 and abs(sim.lane[0, 3]) <= 0.04 + 1e-12 and abs(sim.lane[0, 4]) <= 0.35 + 1e-12
    sim.reset(0, seed=6)
    assert not np.array_equal(sim.state[0], a)


def test_wheel_encoders_follow_the_wheels():
    sim = make_sim(dynamics="kinematic", command_delay=0.0)
    drive(sim, 1.0, 1.0, 15)  # 1 s at 0.6 m/s
    angle = 0.6 / 0.0318
    assert sim.state[0, ST.WHEEL_L] == pytest.approx(angle)
    assert sim.state[0, ST.WHEEL_R] == pytest.approx(angle)
    ticks = wheel_ticks(sim.state[0, ST.WHEEL_L : ST.WHEEL_R + 1], DomainParams().encoder_resolution)
    assert ticks.tolist() == [math.floor(angle / (2 * math.pi / 135))] * 2


def test_pack_dynamics_layout():
    row = pack_dynamics(DomainParams(dynamics="kinematic", trim=0.2, command_delay=0.1, physics_rate=60.0))
    assert row[0] == 1.0 and row[1] == 0.2
    assert row[DYN_FIELDS.index("physics_dt")] == pytest.approx(1 / 60)
    assert row[DYN_FIELDS.index("delay_ticks")] == 6.0
    assert row[DYN_FIELDS.index("motor_gamma_left")] == 1.0 and row[DYN_FIELDS.index("delay_jitter_shape")] == 1.0
