"""A classical vision lane follower, as in Duckietown's lane-following pipeline.

1. Colour segmentation of white and yellow markings (fixed RGB thresholds, so light matters).
2. Ground projection of the marked pixels with the agent's *own assumed* camera calibration (pitch,
   height, field of view, mounting); when the real camera differs, the projected lines bend and shift.
3. Lane-pose estimate: a robust straight-line fit (least squares with outlier trimming) to the yellow
   points and to the white points right of them, each turned into (lateral offset, heading error)
   through the known road geometry, then combined by point count and smoothed over time.
4. PID on the estimate; the speed drops while no marking is seen.

Everything the agent knows comes from the camera, so it runs anywhere, including on a real robot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numba as nb
import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.agents.pid import wheels_for
from proxybench.domain.camera import CameraModel
from proxybench.domain.params import DomainParams

__all__ = ["AssumedCamera", "LaneEstimate", "LaneVisionAgent", "estimate_lane"]

TILE = 0.585
YELLOW_OFFSET = 0.22 * TILE  # yellow centre line → right-lane centre [m]
WHITE_OFFSET = (0.5 * (0.408 + 0.49) - 0.22) * TILE  # right-lane centre → white line centre [m]


@dataclass(frozen=True)
class AssumedCamera:
    """The calibration the agent believes in (degrees, metres); defaults are the Duckiebot's."""

    pitch: float = 19.15
    height: float = 0.108
    forward: float = 0.066
    fov_y: float = 75.0


@lru_cache(maxsize=16)
def _ground_grid(cam: AssumedCamera, width: int, height: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    """Robot-frame ground (x, y) [m] of the centres of every ``step``-th pixel, NaN above the horizon."""
    p = DomainParams(image_width=width, image_height=height, camera_pitch=cam.pitch, camera_height=cam.height,
                     camera_forward=cam.forward, camera_fov_y=cam.fov_y)
    model = CameraModel.from_params(p)
    v, u = np.meshgrid(np.arange(0, height, step) + 0.5 * step, np.arange(0, width, step) + 0.5 * step,
                       indexing="ij")
    gx, gy = model.ground_points(u, v)
    return gx, gy


@dataclass(frozen=True)
class LaneEstimate:
    """Estimated offset from the right-lane centre [m] (+ = left) and heading error [rad], with support."""

    lateral: float
    heading_error: float
    n_yellow: int
    n_white: int


_MIN_POINTS = 6  # a line needs at least this many points
_TRIM = 0.03  # [m] points further than this from the first fit are dropped before the second


@nb.njit(cache=True)
def _fit_line(x: np.ndarray, y: np.ndarray, n: int, trim: float) -> tuple[bool, float, float]:
    """y = a + b x by least squares over the first ``n`` points, refitted once without points further than
    ``trim`` [m] from the first fit (unless that leaves fewer than ``_MIN_POINTS`` or drops none).

    The least-squares solution of ``np.linalg.lstsq``, in closed form (centred sums); where every x is
    equal, its minimum-norm solution.
    """
    if n < _MIN_POINTS:
        return False, 0.0, 0.0
    a = b = 0.0
    for rnd in range(2):
        mx = my = 0.0
        for k in range(n):
            mx += x[k]
            my += y[k]
        mx /= n
        my /= n
        sxx = sxy = 0.0
        for k in range(n):
            dx = x[k] - mx
            sxx += dx * dx
            sxy += dx * (y[k] - my)
        if sxx > 1e-300:
            b = sxy / sxx
            a = my - b * mx
        else:  # one x only: the minimum-norm (a, b) with a + b x = mean y
            a = my / (1.0 + mx * mx)
            b = a * mx
        if rnd == 1:
            break
        kept = 0
        for k in range(n):
            if abs(y[k] - (a + b * x[k])) < trim:
                x[kept] = x[k]
                y[kept] = y[k]
                kept += 1
        if kept < _MIN_POINTS or kept == n:
            break
        n = kept
    return True, a, b


@nb.njit(cache=True)
def _lane_lines(sub: np.ndarray, gx: np.ndarray, gy: np.ndarray, max_range: float) -> np.ndarray:
    """Segment the markings of a subsampled frame, project them to the ground and fit the yellow line and
    the white line right of it: [has_yellow, a, b, n_yellow, has_white, a, b, n_white] (y = a + b x, [m]).

    Colour thresholds (fixed RGB, so light matters): white = every channel > 150 and spread < 50;
    yellow = r > 140, g > 100, b < 110, r − b > 90. Only pixels whose ground point lies 0.05–``max_range``
    m ahead count.
    """
    h, w = gx.shape
    xs = np.empty(h * w)
    ys = np.empty(h * w)
    wx = np.empty(h * w)
    wy = np.empty(h * w)
    white = np.zeros((h, w), dtype=np.bool_)
    ny = nw = 0
    for i in range(h):
        for j in range(w):
            x = gx[i, j]
            if not (x > 0.05 and x < max_range):  # also False for NaN (above the horizon)
                continue
            r, g, b = np.int16(sub[i, j, 0]), np.int16(sub[i, j, 1]), np.int16(sub[i, j, 2])
            if r > 140 and g > 100 and b < 110 and r - b > 90:
                xs[ny] = x
                ys[ny] = gy[i, j]
                ny += 1
            lo, hi = min(r, g, b), max(r, g, b)
            if lo > 150 and hi - lo < 50:
                white[i, j] = True
    out = np.zeros(8)
    ok, a, b = _fit_line(xs, ys, ny, _TRIM)
    if ok:
        out[0], out[1], out[2], out[3] = 1.0, a, b, ny
    for i in range(h):
        for j in range(w):
            if white[i, j]:
                x, y = gx[i, j], gy[i, j]
                if (y < a + b * x - 0.1) if ok else (y < 0.15):  # only the white line right of the yellow one
                    wx[nw] = x
                    wy[nw] = y
                    nw += 1
    ok_w, a_w, b_w = _fit_line(wx, wy, nw, _TRIM)
    if ok_w:
        out[4], out[5], out[6], out[7] = 1.0, a_w, b_w, nw
    return out


def estimate_lane(img: np.ndarray, cam: AssumedCamera, step: int = 4, max_range: float = 0.45) -> LaneEstimate | None:
    """Lane pose from one RGB frame, or None when no marking supports an estimate."""
    h, w = img.shape[:2]
    gx, gy = _ground_grid(cam, w, h, step)
    sub = img[step // 2 :: step, step // 2 :: step][: gx.shape[0], : gx.shape[1]]
    has_y, a, b, n_y, has_w, a_w, b_w, n_w = _lane_lines(sub, gx, gy, max_range)
    estimates, weights = [], []
    if has_y:
        estimates.append((-(a - YELLOW_OFFSET * math.hypot(1.0, b)), -math.atan(b)))
        weights.append(int(n_y))
    if has_w:
        estimates.append((-(a_w + WHITE_OFFSET * math.hypot(1.0, b_w)), -math.atan(b_w)))
        weights.append(int(n_w))
    if not estimates:
        return None
    wsum = float(sum(weights))
    lat = sum(e[0] * wt for e, wt in zip(estimates, weights, strict=True)) / wsum
    head = sum(e[1] * wt for e, wt in zip(estimates, weights, strict=True)) / wsum
    return LaneEstimate(lat, head, int(n_y) if has_y else 0, int(n_w) if has_w else 0)


class LaneVisionAgent(Agent):
    """Camera-only lane following: segmentation → ground projection → line fit → PID."""

    name = "vision"

    def __init__(self, camera: AssumedCamera | None = None, speed: float = 0.25, k_lateral: float = 6.0,
                 k_heading: float = 3.0, smoothing: float = 0.5, step: int = 4):
        self.camera = camera or AssumedCamera()
        self.speed, self.k_lateral, self.k_heading = speed, k_lateral, k_heading
        self.smoothing, self.step = smoothing, step
        self._lat = 0.0
        self._head = 0.0
        self._lost = 0

    def reset(self, seed: int, episode: str | None = None) -> None:
        self._lat, self._head, self._lost = 0.0, 0.0, 0

    def act(self, obs: Observation) -> np.ndarray:
        if obs.camera is None:
            raise ValueError(f"{self.name} needs camera frames")
        est = estimate_lane(obs.camera, self.camera, max(1, self.step * obs.camera.shape[1] // 640))
        if est is None:
            self._lost += 1
        else:
            self._lost = 0
            a = self.smoothing
            self._lat = a * self._lat + (1 - a) * est.lateral
            self._head = a * self._head + (1 - a) * est.heading_error
        speed = self.speed if self._lost < 3 else 0.3 * self.speed
        omega = -(self.k_lateral * self._lat + self.k_heading * self._head)
        return wheels_for(speed, omega)
