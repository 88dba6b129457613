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


def _fit_line(x: np.ndarray, y: np.ndarray, trim: float = 0.03) -> tuple[float, float] | None:
    """y = a + b x by least squares, refitted once without points further than ``trim`` [m]."""
    if x.size < 6:
        return None
    for _ in range(2):
        A = np.stack([np.ones_like(x), x], axis=1)
        (a, b), *_ = np.linalg.lstsq(A, y, rcond=None)
        keep = np.abs(y - (a + b * x)) < trim
        if keep.sum() < 6 or keep.all():
            break
        x, y = x[keep], y[keep]
    return float(a), float(b)


def _segment(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boolean (white, yellow) masks from fixed colour thresholds."""
    rgb = img.astype(np.int16)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    lo = np.minimum(np.minimum(r, g), b)
    hi = np.maximum(np.maximum(r, g), b)
    white = (lo > 150) & (hi - lo < 50)
    yellow = (r > 140) & (g > 100) & (b < 110) & (r - b > 90)
    return white, yellow


def estimate_lane(img: np.ndarray, cam: AssumedCamera, step: int = 4, max_range: float = 0.45) -> LaneEstimate | None:
    """Lane pose from one RGB frame, or None when no marking supports an estimate."""
    h, w = img.shape[:2]
    gx, gy = _ground_grid(cam, w, h, step)
    sub = img[step // 2 :: step, step // 2 :: step][: gx.shape[0], : gx.shape[1]]
    white, yellow = _segment(sub)
    near = np.isfinite(gx) & (gx > 0.05) & (gx < max_range)
    estimates, weights = [], []
    n_y = n_w = 0
    yl = yellow & near
    line_y = _fit_line(gx[yl], gy[yl])
    if line_y is not None:
        n_y = int(yl.sum())
        a, b = line_y
        estimates.append((-(a - YELLOW_OFFSET * math.hypot(1.0, b)), -math.atan(b)))
        weights.append(n_y)
    wl = white & near
    if line_y is not None:
        wl &= gy < line_y[0] + line_y[1] * gx - 0.1  # only the white line right of the yellow one
    else:
        wl &= gy < 0.15
    line_w = _fit_line(gx[wl], gy[wl])
    if line_w is not None:
        n_w = int(wl.sum())
        a, b = line_w
        estimates.append((-(a + WHITE_OFFSET * math.hypot(1.0, b)), -math.atan(b)))
        weights.append(n_w)
    if not estimates:
        return None
    wsum = float(sum(weights))
    lat = sum(e[0] * wt for e, wt in zip(estimates, weights, strict=True)) / wsum
    head = sum(e[1] * wt for e, wt in zip(estimates, weights, strict=True)) / wsum
    return LaneEstimate(lat, head, n_y, n_w)


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
