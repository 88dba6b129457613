"""Calibration without a simulator (usefulness/calibration.py): the estimators recover a known trim and command
delay from synthetic drives (the DB18 dynamic model integrated here, sampled like a robot's log) and from the
scripted drives in proxybench's own simulator."""

from __future__ import annotations

import numpy as np
import pytest

from proxybench.usefulness.calibration import curvature, curvature_per_trim, delay_from_step, trim_from_drive


def _drive(trim: float, delay: float, *, step_time: float = 0.0, pwm: float = 0.4, seconds: float = 3.0,
           rate: float = 60.0, kinematic: bool = False) -> tuple[np.ndarray, ...]:
    """(t, x, y, θ) of a DB18 driving PWM ``pwm`` on both wheels from ``step_time`` (0 before), the command acting
    ``delay`` later; forward Euler at ``rate`` Hz (the dynamic model's default coefficients)."""
    dt = 1.0 / rate
    n = int(seconds * rate) + 1
    t = np.arange(n) * dt
    x, y, th, v, w = np.zeros(n), np.zeros(n), np.zeros(n), 0.0, 0.0
    for k in range(1, n):
        u = pwm if t[k - 1] >= step_time + delay - 1e-9 else 0.0
        r, left = (1 + trim) * u, (1 - trim) * u
        if kinematic:
            v, w = 0.3 * (r + left), 0.6 * (r - left) / 0.102
        else:
            v, w = v + dt * (-5.0 * v + 1.5 * (r + left)), w + dt * (-4.0 * w + 15.0 * (r - left))
        th[k] = th[k - 1] + w * dt
        x[k] = x[k - 1] + v * np.cos(th[k - 1]) * dt
        y[k] = y[k - 1] + v * np.sin(th[k - 1]) * dt
    return t, x, y, th


@pytest.mark.parametrize("trim", [-0.25, -0.05, 0.0, 0.1, 0.3])
def test_trim_is_recovered_from_a_straight_drive(trim):
    t, x, y, th = _drive(trim, 0.1)
    assert trim_from_drive(t, x, y, th, curvature_per_trim(kinematic=False)) == pytest.approx(trim, abs=0.01)
    tk, xk, yk, thk = _drive(trim, 0.0, kinematic=True)
    assert trim_from_drive(tk, xk, yk, thk, curvature_per_trim(kinematic=True)) == pytest.approx(trim, abs=0.005)


def test_the_dynamic_db18_model_turns_less_per_trim_than_the_kinematic_formula_says():
    """Why the study uses the model's κ per trim: the kinematic formula (2 / wheel distance) would read a dynamic
    DB18's trim 0.2 as about 0.13."""
    t, x, y, th = _drive(0.2, 0.0)
    assert trim_from_drive(t, x, y, th, curvature_per_trim(kinematic=True)) == pytest.approx(0.128, abs=0.01)


@pytest.mark.parametrize("delay", [0.0, 0.05, 0.12, 0.3])
def test_delay_is_recovered_from_a_step_drive(delay):
    t, x, y, _ = _drive(0.05, delay, step_time=1.0)
    assert delay_from_step(t, x, y, 1.0) == pytest.approx(delay, abs=0.02)


def test_nothing_to_read_is_nan_not_a_guess():
    t = np.linspace(0, 2, 61)
    still = np.zeros_like(t)
    assert np.isnan(curvature(t, still, still, still)) and np.isnan(delay_from_step(t, still, still, 1.0))
    with pytest.raises(ValueError, match="per_trim"):
        trim_from_drive(t, still, still, still, 0.0)


@pytest.mark.parametrize(("trim", "delay"), [(0.15, 0.2), (-0.12, 0.05), (0.3, 0.25)])
def test_the_scripted_drives_calibrate_proxybench_s_simulator(trim, delay):
    """The zoo's calibration drives in the simulator (60 Hz physics, 15 Hz commands, off the road ends them)."""
    from proxybench.agents.zoo import make_agent
    from proxybench.domain.simulator import Simulator
    from proxybench.experiments.proxies import proxy_params
    from proxybench.runner.episode import run_episode

    sim = Simulator("loop_3x3", proxy_params((160, 120), trim=trim, command_delay=delay), render=False)
    straight = run_episode(sim, make_agent("calib-straight"), 1, 6.0, camera=False)
    step = run_episode(sim, make_agent("calib-step"), 1, 6.0, camera=False)
    per = curvature_per_trim(kinematic=False)
    assert trim_from_drive(straight["t"], straight["x"], straight["y"], straight["theta"], per) == pytest.approx(
        trim, abs=0.01)
    assert delay_from_step(step["t"], step["x"], step["y"], 1.0) == pytest.approx(delay, abs=0.02)
