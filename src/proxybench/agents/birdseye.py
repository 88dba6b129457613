"""A camera agent on a bird's-eye view: warp to the ground, threshold adaptively, histogram peaks, pursue.

Written independently of :mod:`proxybench.agents.vision` (which projects marked pixels and fits lines):

1. **Inverse perspective mapping**: a fixed grid of ground cells ahead of the robot (``x`` forward 0.08–0.5 m,
   ``y`` ±0.35 m) is projected into the image once with the agent's *assumed* camera (an
   :class:`~proxybench.agents.vision.AssumedCamera`-like calibration of its own, :class:`GroundCamera`), and
   every frame is sampled there: a small top-down image of the road.
2. **Adaptive colour thresholds**: white = brighter than the view's mean + ``white_sigma`` standard deviations and
   grey (channel spread < 60); yellow = (r + g)/2 − b > 50 and r > 100. The white threshold follows the light, so
   light acts on this agent differently from fixed thresholds.
3. **Column histograms** of each colour in a near and a far band: the peaks are where the yellow line and the white
   line right of it cross the band; the lane centre lies a known distance from each (road geometry).
4. **Pure pursuit** of the far band's centre point (the near band's when the far one is empty): ω = 2 v y / (x² + y²).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.agents.pid import wheels_for
from proxybench.domain.camera import CameraModel
from proxybench.domain.params import DomainParams

__all__ = ["BirdsEyeAgent", "GroundCamera", "lane_centre_points"]

_TILE = 0.585  # [m]
_YELLOW_TO_CENTRE = 0.22 * _TILE  # yellow line centre → right-lane centre [m]
_WHITE_TO_CENTRE = (0.449 - 0.22) * _TILE  # white line centre → right-lane centre [m]
_XS = np.arange(0.08, 0.5, 0.02)  # ground grid, forward [m]
_YS = np.arange(-0.35, 0.3501, 0.01)  # ground grid, left [m]


@dataclass(frozen=True)
class GroundCamera:
    """The camera the agent believes it has (degrees, metres); defaults are the Duckiebot's."""

    pitch: float = 19.15
    height: float = 0.108
    forward: float = 0.066
    fov_y: float = 75.0


@lru_cache(maxsize=16)
def _sample_map(cam: GroundCamera, width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel rows, columns and an in-image mask for the ground grid (len(_XS), len(_YS))."""
    p = DomainParams(image_width=width, image_height=height, camera_pitch=cam.pitch, camera_height=cam.height,
                     camera_forward=cam.forward, camera_fov_y=cam.fov_y)
    gx, gy = np.meshgrid(_XS, _YS, indexing="ij")
    u, v = CameraModel.from_params(p).project(gx, gy)
    inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    rows = np.where(inside, np.nan_to_num(v), 0).astype(np.int64)
    cols = np.where(inside, np.nan_to_num(u), 0).astype(np.int64)
    return rows, cols, inside


def _peak(hist: np.ndarray, min_count: float) -> int | None:
    smooth = np.convolve(hist, np.ones(3), mode="same")
    k = int(smooth.argmax())
    return k if smooth[k] >= min_count else None


def lane_centre_points(img: np.ndarray, cam: GroundCamera, bands: tuple[tuple[float, float], ...],
                       white_sigma: float = 1.5) -> list[tuple[float, float] | None]:
    """Per band (x_lo, x_hi) [m]: the lane centre (x, y) [m] in the robot frame, or None where no line is seen."""
    h, w = img.shape[:2]
    rows, cols, inside = _sample_map(cam, w, h)
    view = img[rows, cols].astype(np.float32)  # (nx, ny, 3)
    r, g, b = view[..., 0], view[..., 1], view[..., 2]
    bright = view.mean(-1)
    seen = bright[inside]
    if seen.size == 0:
        return [None for _ in bands]
    grey = view.max(-1) - view.min(-1) < 60
    white = inside & grey & (bright > seen.mean() + white_sigma * seen.std())
    yellow = inside & ((r + g) / 2 - b > 50) & (r > 100)
    out: list[tuple[float, float] | None] = []
    for lo, hi in bands:
        band = (lo <= _XS) & (hi > _XS)
        need = max(2.0, 0.3 * band.sum())
        ky = _peak(yellow[band].sum(0).astype(float), need)
        estimates = []
        if ky is not None:
            estimates.append(_YS[ky] - _YELLOW_TO_CENTRE)
        wh = white[band].sum(0).astype(float)
        if ky is not None:
            wh[_YS[ky] - 0.08 < _YS] = 0.0  # only the white line right of the yellow one
        kw = _peak(wh, need)
        if kw is not None:
            estimates.append(_YS[kw] + _WHITE_TO_CENTRE)
        out.append((0.5 * (lo + hi), float(np.mean(estimates))) if estimates else None)
    return out


class BirdsEyeAgent(Agent):
    """Camera-only lane following: bird's-eye view → adaptive thresholds → histogram peaks → pure pursuit."""

    name = "birdseye"

    def __init__(self, camera: GroundCamera | None = None, speed: float = 0.25,
                 near: tuple[float, float] = (0.08, 0.22), far: tuple[float, float] = (0.22, 0.4),
                 white_sigma: float = 1.5):
        if speed <= 0:
            raise ValueError(f"speed must be positive, got {speed}")
        for name, (lo, hi) in (("near", near), ("far", far)):
            if not 0.0 <= lo < hi:
                raise ValueError(f"{name} band must have 0 <= lo < hi, got {(lo, hi)}")
        self.camera = camera or GroundCamera()
        self.speed, self.near, self.far, self.white_sigma = speed, near, far, white_sigma
        self.reset(0)

    def reset(self, seed: int, episode: str | None = None) -> None:
        self._omega = 0.0
        self._lost = 0

    def act(self, obs: Observation) -> np.ndarray:
        if obs.camera is None:
            raise ValueError(f"{self.name} needs camera frames")
        near, far = lane_centre_points(obs.camera, self.camera, (self.near, self.far), self.white_sigma)
        target = far if far is not None else near
        if target is None:
            self._lost += 1
            self._omega *= 0.7
        else:
            self._lost = 0
            x, y = target
            self._omega = float(2.0 * self.speed * y / max(x * x + y * y, 1e-4))
        speed = self.speed if self._lost < 3 else 0.3 * self.speed
        return wheels_for(speed, self._omega)
