"""Duckiebot (DB18) motion: motor model, command latency, velocity dynamics, exact SE(2) pose update.

The default ("dynamic") model is the one of the AIDO simulator: first-order velocity dynamics

    dv/dt = -a_v v + b_v (R + L)          [m/s²]
    dω/dt = -a_ω ω + b_ω (R - L)          [rad/s²]

with effective wheel inputs R = gain (1 + trim) r, L = gain (1 - trim) l from the PWM commands (l, r),
forward Euler on (v, ω) and then an exact SE(2) update of the pose with the new, constant-over-the-step
velocities (a circular arc). The "kinematic" model sets each wheel's speed to PWM × max speed at once.

Effects that the reality model uses (and a proxy may or may not): motor dead-band and saturation,
response curves that differ between the two motors, wheel slip that grows with speed and turn rate, and
latency jitter on top of the fixed command delay (uniform, or mostly short with rare spikes).
Every constant is a field of ``DomainParams``; ``pack_dynamics`` lays them out for the kernel.

All arrays are per robot, so one call advances a whole batch; ``physics_ticks`` is compiled with
Numba and has no Python in its loop.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from proxybench.domain.lane_pose import point_on_road, wrap_angle
from proxybench.domain.params import DomainParams

__all__ = [
    "DYN_FIELDS",
    "ST",
    "TRACE_FIELDS",
    "blur_poses",
    "pack_dynamics",
    "physics_ticks",
    "pwm_from_velocity",
    "wheel_ticks",
]

#: columns of the packed per-robot dynamics parameters
DYN_FIELDS = (
    "kinematic", "trim", "gain", "v_decay", "v_gain", "w_decay", "w_gain", "kinematic_max_speed",
    "wheel_distance", "wheel_radius", "motor_deadband", "motor_saturation", "slip_speed", "slip_turn",
    "physics_dt", "delay_ticks", "jitter_ticks", "motor_gamma_left", "motor_gamma_right", "delay_jitter_shape",
)
(_KIN, _TRIM, _GAIN, _VDEC, _VGAIN, _WDEC, _WGAIN, _VMAX, _WD, _WR, _DB, _SAT, _SLIPV, _SLIPW, _DT, _DELAY,
 _JITTER, _GAMMA_L, _GAMMA_R, _JSHAPE) = range(len(DYN_FIELDS))


#: columns of a physics trace row: pose, velocities, the PWM applied during the tick, off-road flag
TRACE_FIELDS = ("x", "y", "theta", "v", "omega", "pwm_left", "pwm_right", "off_road")


class ST:
    """Columns of the per-robot physical state row."""

    X, Y, THETA, V, OMEGA, WHEEL_L, WHEEL_R, OFF_ROAD = 0, 1, 2, 3, 4, 5, 6, 7
    N = 8


def pack_dynamics(p: DomainParams) -> np.ndarray:
    """One robot's dynamics constants as a float64 row in ``DYN_FIELDS`` order."""
    row = np.empty(len(DYN_FIELDS))
    for k, name in enumerate(DYN_FIELDS):
        row[k] = float(p.dynamics == "kinematic") if name == "kinematic" else getattr(p, name)
    return row


@nb.njit(cache=True, inline="always")
def _motor(u, deadband, saturation, gamma):
    """PWM → effective motor drive: clipped to ±saturation, zero inside the dead-band, rescaled above, then
    shaped by the motor's response curve |·|^gamma (gamma 1: linear, computed without the power)."""
    u = min(max(u, -saturation), saturation)
    a = abs(u)
    if a <= deadband:
        return 0.0
    drive = (a - deadband) / (1.0 - deadband)
    if gamma != 1.0:
        drive = drive**gamma
    return math.copysign(drive, u)


@nb.njit(cache=True, inline="always")
def _jitter(seed, tick, max_ticks, shape):
    """Extra latency in whole ticks for this tick, in [0, max_ticks], fixed by (seed, tick): uniform for
    ``shape`` 1, else ⌊(max_ticks + 1)·U^shape⌋ (mostly short, with rare delays up to ``max_ticks``)."""
    z = np.uint64(seed) ^ (np.uint64(tick) * np.uint64(0x9E3779B97F4A7C15))
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    if shape == 1.0:
        return z % np.uint64(max_ticks + 1)
    unit = float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)  # U[0, 1) from the top 53 bits
    return min(np.uint64(math.floor((max_ticks + 1) * unit**shape)), np.uint64(max_ticks))


@nb.njit(cache=True)
def physics_ticks(
    state, dyn, commands, cmd_hist, applied_tick, tick, seeds, n_ticks, pose_hist,
    tile_kind, curve_corner, tile_size, trace,
):
    """Advance every robot by ``n_ticks`` physics steps under its current ``commands`` (N, 2) PWM (l, r).

    ``cmd_hist`` (N, D, 2) is a ring of the commands issued at each tick (index tick % D); the command
    applied at tick t is the one issued at t - delay - jitter (never older than the one applied before,
    i.e. commands arrive in order). ``pose_hist`` (N, M, 3) keeps the pose after each tick (ring by
    tick % M) for motion blur. ``tick`` (N,) counts ticks per robot. ``state[:, OFF_ROAD]`` becomes 1
    the first tick the robot centre leaves the drivable area and stays 1. If ``trace`` has shape
    (N, n_ticks, TRACE_N), row k receives the state after tick k and the PWM applied during it.
    """
    record = trace.shape[0] == state.shape[0] and trace.shape[1] >= n_ticks
    n_envs = state.shape[0]
    depth = cmd_hist.shape[1]
    m_hist = pose_hist.shape[1]
    for n in range(n_envs):
        s = state[n]
        d = dyn[n]
        dt = d[_DT]
        delay = int(d[_DELAY])
        jit = int(d[_JITTER])
        for k in range(n_ticks):
            t = tick[n]
            cmd_hist[n, t % depth, 0] = commands[n, 0]
            cmd_hist[n, t % depth, 1] = commands[n, 1]
            src = t - delay
            if jit > 0:
                src -= _jitter(seeds[n], t, jit, d[_JSHAPE])
            src = max(src, applied_tick[n])
            applied_tick[n] = src
            if src < 0:
                ul = 0.0
                ur = 0.0
            else:
                ul = cmd_hist[n, src % depth, 0]
                ur = cmd_hist[n, src % depth, 1]
            gain = d[_GAIN]
            L = gain * (1.0 - d[_TRIM]) * _motor(ul, d[_DB], d[_SAT], d[_GAMMA_L])
            R = gain * (1.0 + d[_TRIM]) * _motor(ur, d[_DB], d[_SAT], d[_GAMMA_R])
            if d[_KIN] > 0.5:
                vl = L * d[_VMAX]
                vr = R * d[_VMAX]
                v = 0.5 * (vl + vr)
                w = (vr - vl) / d[_WD]
            else:
                v = s[3] + dt * (-d[_VDEC] * s[3] + d[_VGAIN] * (R + L))
                w = s[4] + dt * (-d[_WDEC] * s[4] + d[_WGAIN] * (R - L))
            s[3] = v
            s[4] = w
            # wheels (and encoders) turn with the commanded motion; slip makes the body move less
            half = 0.5 * d[_WD]
            s[5] += (v - w * half) * dt / d[_WR]
            s[6] += (v + w * half) * dt / d[_WR]
            ve = v / (1.0 + d[_SLIPV] * abs(v))
            we = w / (1.0 + d[_SLIPW] * abs(w))
            th = s[2]
            if abs(we) < 1e-9:
                s[0] += ve * math.cos(th) * dt
                s[1] += ve * math.sin(th) * dt
            else:
                rad = ve / we
                th1 = th + we * dt
                s[0] += rad * (math.sin(th1) - math.sin(th))
                s[1] -= rad * (math.cos(th1) - math.cos(th))
                s[2] = wrap_angle(th1)
            t += 1
            tick[n] = t
            pose_hist[n, t % m_hist, 0] = s[0]
            pose_hist[n, t % m_hist, 1] = s[1]
            pose_hist[n, t % m_hist, 2] = s[2]
            if record:
                tr = trace[n, k]
                tr[0] = s[0]
                tr[1] = s[1]
                tr[2] = s[2]
                tr[3] = s[3]
                tr[4] = s[4]
                tr[5] = ul
                tr[6] = ur
                tr[7] = s[7]
            if s[7] == 0.0 and not point_on_road(s[0], s[1], tile_kind, curve_corner, tile_size):
                s[7] = 1.0


@nb.njit(cache=True)
def blur_poses(pose_hist, tick, state, dyn, blur_ticks, k_count, out):
    """Sub-frame poses (N, K, 3) spread evenly over the last ``blur_ticks[n]`` ticks (linear in between).

    Sub-frame 0 is the current pose; robots with ``k_count[n] < K`` repeat their current pose.
    """
    m_hist = pose_hist.shape[1]
    k_max = out.shape[1]
    for n in range(out.shape[0]):
        kc = k_count[n]
        for k in range(k_max):
            if k == 0 or k >= kc:
                out[n, k, 0] = state[n, 0]
                out[n, k, 1] = state[n, 1]
                out[n, k, 2] = state[n, 2]
                continue
            back = blur_ticks[n] * k / (kc - 1)  # ticks into the past, may be fractional
            back = min(back, float(tick[n]))  # nothing before the episode start
            i0 = int(math.floor(back))
            f = back - i0
            a = (tick[n] - i0) % m_hist
            b = (tick[n] - i0 - 1) % m_hist
            if f == 0.0:
                b = a
            dth = wrap_angle(pose_hist[n, b, 2] - pose_hist[n, a, 2])
            out[n, k, 0] = pose_hist[n, a, 0] + f * (pose_hist[n, b, 0] - pose_hist[n, a, 0])
            out[n, k, 1] = pose_hist[n, a, 1] + f * (pose_hist[n, b, 1] - pose_hist[n, a, 1])
            out[n, k, 2] = pose_hist[n, a, 2] + f * dth


def wheel_ticks(wheel_angle: np.ndarray, resolution: float) -> np.ndarray:
    """Encoder counts of wheel angles [rad] for an encoder step of ``resolution`` [rad]."""
    return np.floor(np.asarray(wheel_angle) / resolution).astype(np.int64)


def pwm_from_velocity(
    v: float, omega: float, *, gain: float = 1.0, trim: float = 0.0, radius: float = 0.0318,
    k: float = 27.0, limit: float = 1.0, wheel_distance: float = 0.102,
) -> tuple[float, float]:
    """(v [m/s], ω [rad/s]) → wheel PWM (left, right), the conversion of Duckietown's ``DuckietownEnv``.

    Wheel angular speeds from the differential-drive kinematics, scaled by the motor constant ``k`` and
    the gain, with ``trim`` shifting power between the wheels; clipped to ±``limit``.

    >>> pwm_from_velocity(0.0, 0.0)
    (0.0, 0.0)
    >>> l, r = pwm_from_velocity(0.2, 1.0)
    >>> r > l > 0
    True
    """
    k_r = k_l = k
    k_r_inv = (gain + trim) / k_r
    k_l_inv = (gain - trim) / k_l
    omega_r = (v + 0.5 * omega * wheel_distance) / radius
    omega_l = (v - 0.5 * omega * wheel_distance) / radius
    u_r = float(np.clip(omega_r * k_r_inv, -limit, limit))
    u_l = float(np.clip(omega_l * k_l_inv, -limit, limit))
    return u_l, u_r
