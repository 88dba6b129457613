"""AIDO's robot and duckie states carry NumPy arrays: how zuper encodes them, and SE(2) poses and twists.

``DTSimRobotInfo.pose`` is the robot's SE(2) matrix ``[[cos θ, -sin θ, x], [sin θ, cos θ, y], [0, 0, 1]]``
and ``velocity`` its se(2) body twist ``[[0, -ω, v], [ω, 0, v_lat], [0, 0, 0]]`` (as duckietown-world's
dynamics report them), each written the way zuper-ipce writes a ``numpy.ndarray``: a map
``{data: raw bytes in C order, dtype: "float64", shape: [3, 3]}``.

>>> pose_of(parse_ndarray(ndarray_data(se2_matrix(1.0, 2.0, 0.5)), "pose", (3, 3)))
(1.0, 2.0, 0.5)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from proxybench.protocol.wire import MessageTypeError, _need

__all__ = ["ndarray_data", "parse_ndarray", "pose_of", "robot_info_data", "se2_matrix", "se2_twist"]

_NUMERIC_DTYPES = frozenset({"float64", "float32", "float16", "int64", "int32", "int16", "int8", "uint8"})


def _str(x: Any) -> bool:
    return type(x) is str


def _map(x: Any) -> bool:
    return isinstance(x, dict)


def ndarray_data(a: np.ndarray) -> dict:
    """A NumPy array as zuper-ipce encodes it: ``{data: bytes (C order), dtype: name, shape: [..]}``."""
    a = np.ascontiguousarray(a, dtype=np.dtype(a.dtype).newbyteorder("<"))
    return {"data": a.tobytes(), "dtype": a.dtype.name, "shape": list(a.shape)}


def parse_ndarray(data: Any, where: str, shape: tuple[int, ...]) -> np.ndarray:
    """The array of an encoded NumPy value (float64), checked to have ``shape`` and finite entries."""
    if not _map(data):
        raise MessageTypeError(f"{where} must be a NumPy array ({{data, dtype, shape}}), got {type(data).__name__}")
    raw = _need(data, "data", lambda d: isinstance(d, bytes | bytearray), "bytes", where)
    dtype = _need(data, "dtype", lambda d: _str(d) and d in _NUMERIC_DTYPES, f"one of {sorted(_NUMERIC_DTYPES)}",
                  where)
    got = _need(data, "shape", lambda v: isinstance(v, list) and all(type(n) is int and n >= 0 for n in v),
                "a list of sizes", where)
    if tuple(got) != shape:
        raise MessageTypeError(f"{where}: shape {got} is not {list(shape)}")
    dt = np.dtype(dtype).newbyteorder("<")
    if len(raw) != dt.itemsize * math.prod(shape):
        raise MessageTypeError(f"{where}: {len(raw)} data bytes do not make a {dtype} array of shape {got}")
    out = np.frombuffer(bytes(raw), dtype=dt).astype(np.float64).reshape(shape)
    if not np.all(np.isfinite(out)):
        raise MessageTypeError(f"{where}: entries must be finite")
    return out


def se2_matrix(x: float, y: float, theta: float) -> np.ndarray:
    """The SE(2) pose matrix ``[[cos, -sin, x], [sin, cos, y], [0, 0, 1]]`` (AIDO's robot pose)."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def se2_twist(v: float, omega: float, v_lateral: float = 0.0) -> np.ndarray:
    """The se(2) body velocity ``[[0, -ω, v], [ω, 0, v_lat], [0, 0, 0]]`` (AIDO's robot velocity)."""
    return np.array([[0.0, -omega, v], [omega, 0.0, v_lateral], [0.0, 0.0, 0.0]])


def pose_of(m: np.ndarray) -> tuple[float, float, float]:
    """(x [m], y [m], θ [rad]) of an SE(2) matrix."""
    return float(m[0, 2]), float(m[1, 2]), math.atan2(float(m[1, 0]), float(m[0, 0]))


def robot_info_data(pose: tuple[float, float, float], v: float, omega: float, pwm: Any, leds: dict) -> dict:
    """A ``DTSimRobotInfo``: pose (x [m], y [m], θ [rad]) as SE(2), (v [m/s], ω [rad/s]) as se(2), the PWM held."""
    return {"pose": ndarray_data(se2_matrix(*pose)), "velocity": ndarray_data(se2_twist(float(v), float(omega))),
            "pwm": {"motor_left": float(pwm[0]), "motor_right": float(pwm[1])}, "leds": leds}
