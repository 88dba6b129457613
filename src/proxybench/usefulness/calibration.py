"""Calibration without a simulator: a robot's wheel trim and command delay from short scripted drives on the robot
itself (the validation study's ``calibration`` method, docs/validate.md). Pure functions: arrays in, numbers out.

- **Trim** from a straight drive (the same PWM u on both wheels): the DB18 model turns the wheels' imbalance into
  a curvature κ = ω / v (yaw rate over speed) proportional to the trim. In the DB18's dynamic model (gym-duckietown's
  and proxybench's: dv/dt = −a_v v + b_v (R + L), dω/dt = −a_ω ω + b_ω (R − L), R = (1 + trim) u, L = (1 − trim) u)
  the steady state gives κ = trim · (b_ω a_v) / (a_ω b_v) (:func:`curvature_per_trim`); in the kinematic model
  κ = 2 trim / wheel distance. κ is the slope of the heading against the distance driven, fitted after the
  start-up transient.
- **Command delay** from a step drive (still, then a step to PWM u at a known time): the distance driven s(t) is
  fitted by a delayed first-order response, s = V (τ − (1 − e^(−aτ)) / a) for τ = t − t_step − delay > 0 (0 before),
  over a grid of delays and rates (V by least squares): the delay of the best fit.

>>> import numpy as np
>>> t = np.linspace(0, 2, 121)
>>> s, k = 0.3 * t, 0.6  # a drive at 0.3 m/s on a circle of curvature 0.6 /m
>>> round(trim_from_drive(t, np.sin(k * s) / k, (1 - np.cos(k * s)) / k, k * s, 12.0), 3)
0.05
"""

from __future__ import annotations

import numpy as np

__all__ = ["curvature", "curvature_per_trim", "delay_from_step", "trim_from_drive"]


def curvature_per_trim(*, kinematic: bool, wheel_distance: float = 0.102, v_decay: float = 5.0, v_gain: float = 1.5,
                       w_decay: float = 4.0, w_gain: float = 15.0) -> float:
    """κ / trim [1/m] of a straight drive in the DB18 model (the defaults: the DB18's, as gym-duckietown and
    proxybench's nominal proxy have them): 2 / wheel distance in the kinematic model, (b_ω a_v) / (a_ω b_v) at the
    dynamic model's steady state."""
    if kinematic:
        return 2.0 / wheel_distance
    return (w_gain * v_decay) / (w_decay * v_gain)


def _path(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Distance driven [m] along the sampled path, from its first sample."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])


def curvature(t: np.ndarray, x: np.ndarray, y: np.ndarray, theta: np.ndarray, *, settle: float = 0.4,
              least: float = 0.05) -> float:
    """κ [1/m]: the least-squares slope of the (unwrapped) heading against the distance driven, over the samples
    after ``settle`` [s] (the motors' start-up; all samples where fewer than 5 remain). NaN when the robot drove
    under ``least`` [m] (nothing to read)."""
    t, x, y = (np.asarray(a, float) for a in (t, x, y))
    th = np.unwrap(np.asarray(theta, float))
    s = _path(x, y)
    keep = t >= t[0] + settle
    if keep.sum() < 5:
        keep = np.ones_like(t, bool)
    s, th = s[keep], th[keep]
    if s.size < 3 or s[-1] - s[0] < least:
        return float("nan")
    return float(np.polyfit(s, th, 1)[0])


def trim_from_drive(t: np.ndarray, x: np.ndarray, y: np.ndarray, theta: np.ndarray, per_trim: float, *,
                    settle: float = 0.4) -> float:
    """The trim a straight drive shows: its curvature (:func:`curvature`) over ``per_trim`` (κ per unit trim,
    :func:`curvature_per_trim`); positive: the right wheel is the stronger (the robot drifts left)."""
    if per_trim <= 0:
        raise ValueError(f"per_trim must be > 0, got {per_trim}")
    return curvature(t, x, y, theta, settle=settle) / per_trim


def _response(tau: np.ndarray, rate: float) -> np.ndarray:
    """The distance a first-order response to a unit speed step covers in ``tau`` (0 before the step)."""
    tau = np.clip(tau, 0.0, None)
    return tau - (1.0 - np.exp(-rate * tau)) / rate


def delay_from_step(t: np.ndarray, x: np.ndarray, y: np.ndarray, step_time: float, *, most: float = 1.0,
                    resolution: float = 0.002, rates: np.ndarray | None = None) -> float:
    """The command delay [s] a step drive shows (the command stepped at ``step_time``): the delay d in
    [0, ``most``] (steps of ``resolution``) and the rate a (``rates``, 1/s) whose delayed first-order response
    fits the distance driven best (least squares, its speed V fitted). NaN when the robot never moved."""
    t, x, y = (np.asarray(a, float) for a in (t, x, y))
    s = _path(x, y)
    if s.size < 5 or s[-1] < 0.02:
        return float("nan")
    rates = np.geomspace(0.5, 60.0, 40) if rates is None else np.asarray(rates, float)
    delays = np.arange(0.0, most + resolution / 2, resolution)
    tau = t[None, :] - step_time - delays[:, None]  # (delays, samples)
    best, best_d = np.inf, float("nan")
    for a in rates:
        g = _response(tau, a)
        gg = (g * g).sum(1)
        v = np.where(gg > 0, (g * s).sum(1) / np.where(gg > 0, gg, 1.0), 0.0)
        sse = ((s[None, :] - v[:, None] * g) ** 2).sum(1)
        i = int(np.argmin(sse))
        if sse[i] < best:
            best, best_d = float(sse[i]), float(delays[i])
    return best_d
