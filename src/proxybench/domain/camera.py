"""The Duckiebot camera: pinhole or fisheye (plumb-bob or equidistant lens), mounted with pitch and
optionally yaw and roll, and the per-pixel ground-ray table.

The ground is flat and the camera is rigidly mounted, so where each pixel's ray meets the ground,
*in the robot's own frame*, depends on the camera parameters only. ``CameraTable`` precomputes it once
(with lens distortion folded in), and the renderer then only rotates and translates those points by
the robot pose each frame. Robot frame: x forward from the wheel axle, y to the left, z up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from proxybench.domain.params import DomainParams

__all__ = ["CameraModel", "CameraTable", "camera_table"]


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics and mounting of one camera. Angles in degrees, lengths in metres, sizes in pixels."""

    width: int
    height: int
    pitch: float
    mount_height: float
    forward: float
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, float, float, float, float] | None = None
    yaw: float = 0.0
    roll: float = 0.0
    lens: str = "plumb_bob"

    @staticmethod
    def from_params(p: DomainParams) -> CameraModel:
        if p.fisheye:
            # calibration at 640×480, scaled to this resolution
            sx, sy = p.image_width / 640.0, p.image_height / 480.0
            fx, fy, cx, cy = p.intrinsics
            return CameraModel(
                p.image_width, p.image_height, p.camera_pitch, p.camera_height, p.camera_forward,
                fx * sx, fy * sy, cx * sx, cy * sy, tuple(p.distortion), p.camera_yaw, p.camera_roll, p.lens_model,
            )
        fy = 0.5 * p.image_height / math.tan(math.radians(p.camera_fov_y) / 2)
        return CameraModel(
            p.image_width, p.image_height, p.camera_pitch, p.camera_height, p.camera_forward,
            fy, fy, 0.5 * p.image_width, 0.5 * p.image_height, None, p.camera_yaw, p.camera_roll,
        )

    @property
    def rows_are_lines(self) -> bool:
        """Every image row is all sky or one straight line on the ground: a pinhole camera without roll
        (yaw turns the camera about the vertical, so the horizon stays a row)."""
        return self.distortion is None and self.roll == 0.0

    def undistort(self, xd: np.ndarray, yd: np.ndarray, iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
        """Normalised distorted image coordinates → ideal pinhole ones (fixed-point iteration, as OpenCV)."""
        if self.distortion is None:
            return xd, yd
        if self.lens == "equidistant":
            return self._undistort_equidistant(xd, yd, iterations)
        k1, k2, p1, p2, k3 = self.distortion
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
            dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            x = (xd - dx) / radial
            y = (yd - dy) / radial
        return x, y

    def _undistort_equidistant(self, xd: np.ndarray, yd: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
        """The equidistant (Kannala-Brandt) fisheye, as OpenCV's ``fisheye`` module: the distorted radius is
        θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸), θ the ray's angle off the optical axis; Newton on θ."""
        k1, k2, k3, k4, _ = self.distortion
        rd = np.hypot(xd, yd)
        theta = rd.copy()
        for _ in range(iterations):
            t2 = theta * theta
            f = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - rd
            df = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            theta = np.clip(theta - f / df, 0.0, math.radians(89.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(rd > 1e-12, np.tan(theta) / rd, 1.0)
        return xd * scale, yd * scale

    def _distort_equidistant(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ideal pinhole normalised coordinates → distorted ones (equidistant model, the inverse of the above)."""
        k1, k2, k3, k4, _ = self.distortion
        r = np.hypot(x, y)
        theta = np.arctan(r)
        t2 = theta * theta
        rd = theta * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(r > 1e-12, rd / r, 1.0)
        return x * scale, y * scale

    def rays(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit-free ray directions in the robot frame for pixel coordinates (u right, v down)."""
        xn, yn = self.undistort((u - self.cx) / self.fx, (v - self.cy) / self.fy)
        if self.roll != 0.0:  # about the optical axis, before the pitch (skipped at 0: frames stay bit-identical)
            r = math.radians(self.roll)
            xn, yn = math.cos(r) * xn - math.sin(r) * yn, math.sin(r) * xn + math.cos(r) * yn
        a = math.radians(self.pitch)
        sa, ca = math.sin(a), math.cos(a)
        # camera axes in the robot frame: right = (0, -1, 0), down = (-sin a, 0, -cos a), forward = (cos a, 0, -sin a)
        rx = -yn * sa + ca
        ry = -xn
        rz = -yn * ca - sa
        if self.yaw != 0.0:  # about the robot's vertical axis, after the pitch
            w = math.radians(self.yaw)
            rx, ry = math.cos(w) * rx - math.sin(w) * ry, math.sin(w) * rx + math.cos(w) * ry
        return np.stack([rx, ry, rz], axis=-1)

    def ground_points(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Robot-frame (x, y) where each pixel ray meets the ground; NaN above the horizon."""
        d = self.rays(u, v)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d[..., 2] < -1e-9, self.mount_height / -d[..., 2], np.nan)
        return self.forward + t * d[..., 0], t * d[..., 1]

    def project(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel (u, v) of robot-frame ground points, pinhole part only (used by tests and agents)."""
        a = math.radians(self.pitch)
        sa, ca = math.sin(a), math.cos(a)
        px, py, pz = x - self.forward, y, -self.mount_height
        if self.yaw != 0.0:
            w = math.radians(self.yaw)
            px, py = math.cos(w) * px + math.sin(w) * py, -math.sin(w) * px + math.cos(w) * py
        zc = px * ca - pz * sa
        xc = -py
        yc = -px * sa - pz * ca
        if self.roll != 0.0:
            r = math.radians(self.roll)
            xc, yc = math.cos(r) * xc + math.sin(r) * yc, -math.sin(r) * xc + math.cos(r) * yc
        return self.fx * xc / zc + self.cx, self.fy * yc / zc + self.cy


@dataclass(frozen=True)
class CameraTable:
    """Per-pixel data the renderer needs, shape (H, W) each.

    - ``gx``, ``gy`` [m]: robot-frame ground hit of the pixel centre (0 where ``sky``).
    - ``footprint`` [m]: size of the pixel on the ground, for choosing a texture level.
    - ``sky`` [bool] and ``sky_mix`` [0..1]: above-horizon pixels and their sky-to-horizon blend.
    - ``vignette`` [0..1]: normalised distance from the image centre (squared).
    """

    model: CameraModel
    gx: np.ndarray
    gy: np.ndarray
    footprint: np.ndarray
    sky: np.ndarray
    sky_mix: np.ndarray
    vignette: np.ndarray


def _build_table(model: CameraModel) -> CameraTable:
    h, w = model.height, model.width
    v, u = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    gx, gy = model.ground_points(u, v)
    gx1, gy1 = model.ground_points(u + 1.0, v)
    gx2, gy2 = model.ground_points(u, v + 1.0)
    with np.errstate(invalid="ignore"):
        foot = np.fmax(np.hypot(gx1 - gx, gy1 - gy), np.hypot(gx2 - gx, gy2 - gy))
    sky = ~np.isfinite(gx)
    # pixels just above the horizon whose lower neighbour hits far away: footprint = inf
    foot = np.where(np.isfinite(foot), foot, np.inf)
    d = model.rays(u, v)
    elevation = np.arctan2(d[..., 2], np.hypot(d[..., 0], d[..., 1]))
    sky_mix = np.clip(elevation / math.radians(30.0), 0.0, 1.0)
    r2 = ((u - w / 2) / (w / 2)) ** 2 + ((v - h / 2) / (h / 2)) ** 2
    return CameraTable(
        model,
        np.where(sky, 0.0, gx).astype(np.float64),
        np.where(sky, 0.0, gy).astype(np.float64),
        foot.astype(np.float64),
        sky,
        sky_mix.astype(np.float32),
        (r2 / 2.0).astype(np.float32),
    )


@lru_cache(maxsize=64)
def _cached_table(model: CameraModel) -> CameraTable:
    return _build_table(model)


def camera_table(params: DomainParams) -> CameraTable:
    """The (cached) per-pixel table for a domain's camera."""
    return _cached_table(CameraModel.from_params(params))
