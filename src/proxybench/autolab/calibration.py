"""A watchtower's calibration file: intrinsics (as ROS ``camera_info`` writes them) and extrinsics in the map frame.

``<log>/watchtowers/<name>/calibration.yaml``::

    format: proxybench-watchtower-calibration/1
    name: wt01
    image_width: 640
    image_height: 480
    camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob          # or equidistant (k1..k4 and a 0)
    distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}
    extrinsics: {position: [x, y, z], yaw: 90.0, pitch: 89.0, roll: 0.0}   # [m], [deg]: geometry.camera_pose
    uncertainty: {position: 0.005, angle: 0.3}                            # 1σ [m], [deg]: the pose graph's prior

In simulation the file is what the lab's calibration gave: the layout's truth plus the watchtower's own error
drawn from the layout's ``calibration_error`` (``draw_calibrations``); its streams' clocks are off by a drawn
offset the file does not know.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, model_validator

from proxybench.autolab.geometry import camera_pose
from proxybench.autolab.watchtowers import Layout, LayoutError, Watchtower, ground_objects, read_model

__all__ = ["CALIBRATION_FORMAT", "Calibration", "Extrinsics", "draw_calibrations", "load_calibration",
           "stream_spec", "write_calibration"]

CALIBRATION_FORMAT = "proxybench-watchtower-calibration/1"


class _Matrix(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    rows: int
    cols: int
    data: list[float]

    @model_validator(mode="after")
    def _shape(self) -> _Matrix:
        if len(self.data) != self.rows * self.cols or not all(math.isfinite(v) for v in self.data):
            raise ValueError(f"data must hold {self.rows}×{self.cols} finite numbers, got {len(self.data)}")
        return self


class Extrinsics(BaseModel):
    """The camera's optical centre [m] and orientation (yaw, pitch, roll [deg]) in the map frame."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: tuple[float, float, float]
    yaw: float
    pitch: float = Field(ge=-90.0, le=90.0)
    roll: float = Field(0.0, ge=-180.0, le=180.0)


class Uncertainty(BaseModel):
    """1σ of the extrinsics: the pose graph's prior on the watchtower's pose."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: float = Field(0.01, gt=0.0, description="[m], each axis")
    angle: float = Field(1.0, gt=0.0, description="[deg], each")


class Calibration(BaseModel):
    """What the lab knows of one watchtower's camera."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: Literal["proxybench-watchtower-calibration/1"] = CALIBRATION_FORMAT
    name: str
    image_width: int = Field(ge=8, le=8192)
    image_height: int = Field(ge=8, le=8192)
    camera_matrix: _Matrix
    distortion_model: Literal["plumb_bob", "equidistant", "none"] = "plumb_bob"
    distortion_coefficients: _Matrix = _Matrix(rows=1, cols=5, data=[0.0] * 5)
    extrinsics: Extrinsics
    uncertainty: Uncertainty = Uncertainty()

    @model_validator(mode="after")
    def _k(self) -> Calibration:
        if (self.camera_matrix.rows, self.camera_matrix.cols) != (3, 3):
            raise ValueError("camera_matrix must be 3×3")
        k = self.camera_matrix.data
        if k[0] <= 0 or k[4] <= 0:
            raise ValueError("camera_matrix: fx and fy must be positive")
        if len(self.distortion_coefficients.data) not in (4, 5, 8):
            raise ValueError("distortion_coefficients: 4, 5 or 8 numbers")
        return self

    @property
    def K(self) -> np.ndarray:
        return np.array(self.camera_matrix.data, dtype=np.float64).reshape(3, 3)

    @property
    def D(self) -> np.ndarray:
        return np.array(self.distortion_coefficients.data, dtype=np.float64)

    def pose(self) -> np.ndarray:
        """T_map_camera as calibrated."""
        e = self.extrinsics
        return camera_pose(*e.position, math.radians(e.yaw), e.pitch, e.roll)


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration file; :class:`LayoutError` naming the file and field otherwise."""
    path = Path(path)
    if not os.path.lexists(path):
        raise LayoutError(f"{path}: missing: every watchtower needs its calibration (intrinsics and extrinsics)")
    return read_model(path, Calibration, CALIBRATION_FORMAT, follow_links=False)  # a lab's file: a link is refused


def write_calibration(path: str | Path, cal: Calibration) -> Path:
    path = Path(path)
    path.write_text(yaml.safe_dump(cal.model_dump(mode="json"), sort_keys=False))
    return path


def _intrinsics(w: Watchtower) -> tuple[float, float, float, float]:
    return w.camera().intrinsics()


def draw_calibrations(layout: Layout) -> tuple[dict[str, Calibration], dict[str, float]]:
    """(calibration per watchtower, clock offset [s] per watchtower): the truth plus errors drawn from the
    layout's ``calibration_error`` (one stream of draws per watchtower, from its seed and name)."""
    err = layout.calibration_error
    cals, clocks = {}, {}
    for w in layout.watchtowers:
        rng = np.random.default_rng(np.random.SeedSequence([err.seed, *w.name.encode()]))
        fx, fy, cx, cy = _intrinsics(w)
        cx, cy = cx - 0.5, cy - 0.5  # the renderer's pixel centres are at +0.5, OpenCV's (and camera_info's) at 0
        f = 1.0 + err.focal * rng.standard_normal()
        dcx, dcy = err.principal * rng.standard_normal(2)
        pos = np.asarray(w.position) + err.position * rng.standard_normal(3)
        dyaw, dpitch, droll = err.angle * rng.standard_normal(3)
        clocks[w.name] = float(err.clock * rng.standard_normal())
        model = "none" if w.intrinsics is None or w.distortion is None else w.lens
        cals[w.name] = Calibration(
            name=w.name, image_width=w.resolution[0], image_height=w.resolution[1],
            camera_matrix=_Matrix(rows=3, cols=3, data=[fx * f, 0.0, cx + dcx, 0.0, fy * f, cy + dcy, 0.0, 0.0, 1.0]),
            distortion_model=model,
            distortion_coefficients=_Matrix(rows=1, cols=5, data=list(w.distortion or (0.0,) * 5)),
            extrinsics=Extrinsics(position=tuple(float(v) for v in pos), yaw=w.yaw + dyaw,
                                  pitch=float(np.clip(w.pitch + dpitch, -90, 90)), roll=w.roll + droll),
            uncertainty=Uncertainty(position=max(err.position, 1e-3), angle=max(err.angle, 0.05)))
    return cals, clocks


def stream_spec(layout: Layout, image_format: str = "jpg"):
    """The runner's ``StreamSpec`` of a layout: its true cameras, rates, drawn clock offsets and ground tags."""
    from proxybench.runner.streams import StreamSpec

    _, clocks = draw_calibrations(layout)
    return StreamSpec(tuple(w.camera() for w in layout.watchtowers), tuple(w.frame_rate for w in layout.watchtowers),
                      tuple(clocks[w.name] for w in layout.watchtowers), ground_objects(layout), image_format)
