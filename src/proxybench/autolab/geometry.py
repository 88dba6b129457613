"""Frames and poses of the Autolab's localisation: 4 × 4 homogeneous transforms in the map frame.

Frames: the **map** (x east, y north, z up: duckietown-world's); a watchtower's **camera** (OpenCV's: x right,
y down, z along the optical axis); a **tag** (``domain.apriltags``: x to the printed marker's right, y to its
top, z out of its face); a **robot** (x forward, y left, z up, on the ground below its wheel axle; its roof tag
is this frame raised by ``objects.ROOF_TAG_Z``). ``T_a_b`` maps points of frame b into frame a.

A watchtower's extrinsics are its position and (yaw [rad] of its optical axis on the ground, pitch [deg] down
from the horizontal, roll [deg] about the optical axis), exactly as the renderer mounts a camera
(``domain.camera.CameraModel.rays``), so ``camera_pose`` and the renderer agree (tested).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["camera_pose", "planar", "pose_from_planar", "tag_corners"]


def camera_pose(x: float, y: float, z: float, yaw: float, pitch_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """T_map_camera of a camera at (x, y, z) [m] with yaw [rad], pitch and roll [deg] (see the module)."""
    a, r = math.radians(pitch_deg), math.radians(roll_deg)
    sa, ca = math.sin(a), math.cos(a)
    # the camera's right, down and forward axes before roll, in a frame turned to ``yaw`` (x ahead, y left)
    basis = np.array([[0.0, -sa, ca], [-1.0, 0.0, 0.0], [0.0, -ca, -sa]])
    roll = np.array([[math.cos(r), -math.sin(r), 0.0], [math.sin(r), math.cos(r), 0.0], [0.0, 0.0, 1.0]])
    turn = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    out = np.eye(4)
    out[:3, :3] = turn @ basis @ roll
    out[:3, 3] = (x, y, z)
    return out


def pose_from_planar(x: float, y: float, theta: float, z: float = 0.0) -> np.ndarray:
    """T_map_frame of a frame at (x, y, z) turned by ``theta`` [rad] about the vertical."""
    out = np.eye(4)
    c, s = math.cos(theta), math.sin(theta)
    out[:2, :2] = [[c, -s], [s, c]]
    out[:3, 3] = (x, y, z)
    return out


def planar(T: np.ndarray) -> tuple[float, float, float]:
    """(x, y, θ) of a pose: its position and the heading of its x axis on the ground."""
    return float(T[0, 3]), float(T[1, 3]), math.atan2(T[1, 0], T[0, 0])


def tag_corners(size: float) -> np.ndarray:
    """(4, 3) corners of a tag's black square of edge ``size`` [m] in the tag frame, in OpenCV ArUco's order:
    top left, top right, bottom right, bottom left of the printed marker."""
    h = 0.5 * size
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
