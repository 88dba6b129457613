"""A camera agent that finds the lane in the image, not on the ground: HSV thresholds, a Hough transform, PD.

Written independently of :mod:`proxybench.agents.vision` and deliberately different in every stage:

1. **Segmentation in HSV** (hue, saturation, value), not fixed RGB: yellow = hue 30–70°, saturation > 0.45,
   value > 0.45; white = saturation < 0.25, value > 0.6; only in the image below ``roi_top`` (a fraction of the
   height: the agent assumes the road lies there).
2. **Lines by a Hough transform** in pixel coordinates (votes over (θ, ρ)), the strongest non-horizontal yellow
   line, then the strongest white line right of it. No camera calibration and no ground projection: nothing about
   the camera's pitch, height or field of view is assumed, so they act on this agent differently.
3. **The lane centre at a look-ahead row** (``lookahead_row``, a fraction of the height): halfway between the two
   lines, or half a lane width from the one seen, the width in pixels learnt while both are seen.
4. **PD steering** on the centre's horizontal offset from the image centre (a fraction of the half-width); the
   speed drops while no line is found.
"""

from __future__ import annotations

import math

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.agents.pid import wheels_for

__all__ = ["HoughLaneAgent", "hough_line", "marking_masks"]

_N_THETA = 90


def marking_masks(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(yellow, white) boolean masks of an RGB uint8 image by HSV thresholds (see the module docstring)."""
    rgb = img.astype(np.float32) / 255.0
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    # elementwise over the three planes: exactly max(-1)/min(-1), without a reduction over a length-3 axis
    hi, lo = np.maximum(np.maximum(r, g), b), np.minimum(np.minimum(r, g), b)
    chroma = hi - lo
    sat = np.where(hi > 0, chroma / np.maximum(hi, 1e-6), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        hue_r = 60.0 * (g - b) / chroma  # where red is the largest channel
        hue_g = 60.0 * (2.0 + (b - r) / chroma)  # where green is
    hue = np.where(hi == r, hue_r, np.where(hi == g, hue_g, 240.0))
    yellow = (b == lo) & (sat > 0.45) & (hi > 0.45) & (hue >= 30.0) & (hue <= 70.0)
    white = (sat < 0.25) & (hi > 0.6)
    return yellow, white


def hough_line(u: np.ndarray, v: np.ndarray, diag: float, min_votes: int,
               min_tilt_deg: float = 20.0) -> tuple[float, float, int] | None:
    """The strongest line through pixels (u, v) as (θ [rad], ρ [px], votes), u cos θ + v sin θ = ρ; lines
    within ``min_tilt_deg`` of horizontal (stop lines, the road's far edge) are not considered."""
    if len(u) < min_votes:
        return None
    thetas = np.linspace(0.0, math.pi, _N_THETA, endpoint=False)
    keep = np.abs(thetas - math.pi / 2) > math.radians(min_tilt_deg)
    thetas = thetas[keep]
    n_rho = int(2 * diag) + 1
    rho = np.rint(np.outer(u, np.cos(thetas)) + np.outer(v, np.sin(thetas)) + diag).astype(np.int64)
    cells = rho + n_rho * np.arange(len(thetas))[None, :]
    acc = np.bincount(cells.ravel(), minlength=n_rho * len(thetas))
    best = int(acc.argmax())
    votes = int(acc[best])
    if votes < min_votes:
        return None
    t, rr = divmod(best, n_rho)
    return float(thetas[t]), float(rr - diag), votes


def _u_at(line: tuple[float, float, int], v: float | np.ndarray) -> float | np.ndarray:
    """Column [px] of the line at row(s) ``v`` [px] (the line is never horizontal: :func:`hough_line`)."""
    theta, rho, _ = line
    return (rho - v * math.sin(theta)) / math.cos(theta)


class HoughLaneAgent(Agent):
    """Camera-only lane following: HSV masks → Hough lines → lane centre at a look-ahead row → PD."""

    name = "hough"

    def __init__(self, speed: float = 0.25, lookahead_row: float = 0.7, roi_top: float = 0.4, k_p: float = 3.0,
                 k_d: float = 0.3, half_lane: float = 0.45, frame_dt: float = 1 / 15):
        if not 0.0 < roi_top < lookahead_row < 1.0:
            raise ValueError(f"need 0 < roi_top < lookahead_row < 1, got roi_top={roi_top}, "
                             f"lookahead_row={lookahead_row}")
        if speed <= 0 or half_lane <= 0:
            raise ValueError(f"speed and half_lane must be positive, got {speed}, {half_lane}")
        self.speed, self.lookahead_row, self.roi_top = speed, lookahead_row, roi_top
        self.k_p, self.k_d, self.frame_dt = k_p, k_d, frame_dt
        self.half_lane0 = half_lane  # half the lane's width at the look-ahead row, a fraction of the image width
        self.reset(0)

    def reset(self, seed: int, episode: str | None = None) -> None:
        self._half = self.half_lane0
        self._err: float | None = None
        self._lost = 0

    def lane_offset(self, img: np.ndarray) -> float | None:
        """The lane centre's horizontal offset at the look-ahead row, in half image widths (+ = right), or None."""
        step = max(1, img.shape[1] // 160)
        sub = img[::step, ::step]
        h, w = sub.shape[:2]
        top = int(self.roi_top * h)
        yellow, white = marking_masks(sub[top:])
        diag = math.hypot(w, h)
        vy, uy = np.nonzero(yellow)
        line_y = hough_line(uy.astype(float), vy + float(top), diag, min_votes=max(4, h // 20))
        vw, uw = np.nonzero(white)
        uw_f, vw_f = uw.astype(float), vw + float(top)
        if line_y is not None:
            right = uw_f > _u_at(line_y, vw_f) + 2.0
            uw_f, vw_f = uw_f[right], vw_f[right]
        line_w = hough_line(uw_f, vw_f, diag, min_votes=max(4, h // 15))
        row = self.lookahead_row * h
        half_px = self._half * w
        if line_y is not None and line_w is not None:
            u_y, u_w = _u_at(line_y, row), _u_at(line_w, row)
            if u_w > u_y:
                self._half = 0.9 * self._half + 0.1 * float(np.clip((u_w - u_y) / (2 * w), 0.15, 0.8))
            centre = 0.5 * (u_y + u_w)
        elif line_y is not None:
            centre = _u_at(line_y, row) + half_px
        elif line_w is not None:
            centre = _u_at(line_w, row) - half_px
        else:
            return None
        return float(np.clip((centre - 0.5 * w) / (0.5 * w), -3.0, 3.0))

    def act(self, obs: Observation) -> np.ndarray:
        if obs.camera is None:
            raise ValueError(f"{self.name} needs camera frames")
        err = self.lane_offset(obs.camera)
        if err is None:
            self._lost += 1
            err = self._err if self._err is not None else 0.0
            d_err = 0.0
        else:
            self._lost = 0
            d_err = 0.0 if self._err is None else (err - self._err) / self.frame_dt
        self._err = err
        speed = self.speed if self._lost < 3 else 0.3 * self.speed
        return wheels_for(speed, -(self.k_p * err + self.k_d * d_err))
