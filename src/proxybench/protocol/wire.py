"""The bytes on the wire: zuper-nodes "z2" envelopes and the AIDO agent messages.

Each direction is a stream of CBOR maps back to back, with no length prefix, read by
:class:`~.cbor_stream.CborStream` (re-exported here with its errors). Encoders reproduce what
the recorded AIDO node and caller send, byte for byte: envelopes keep the order ``compat, topic, data,
timing`` / ``control, data``; data and timing *written by a node* are maps in canonical CBOR key order
(shorter keys first, as the zuper serialiser sorts them); floats are always 8-byte CBOR floats, because the
real node rejects an int where a float is declared. The per-step messages are assembled from byte pieces
encoded once (the tests hold them equal to cbor2's encoding of the dicts they stand for).
"""

from __future__ import annotations

import functools
import math
import struct
import time
from dataclasses import dataclass
from typing import Any

import cbor2
import numpy as np

from proxybench.protocol.cbor_stream import (
    CborStream,
    GarbageError,
    NotAMapError,
    TruncatedError,
    WireError,
    item_end,
)
from proxybench.untrusted import short_repr

__all__ = [
    "COMPAT", "CTRL_ABORTED", "CTRL_CAPABILITIES", "CTRL_NOT_UNDERSTOOD", "CTRL_OVER", "CTRL_UNDERSTOOD",
    "ENV_DATA_IN", "ENV_DATA_OUT", "BadMessageError", "CborStream", "Control", "GarbageError", "MessageTypeError",
    "NotAMapError", "Topic", "TruncatedError", "WireError", "canonical", "decode_message", "encode_commands",
    "encode_control", "encode_episode_start", "encode_get_commands", "encode_node_timing", "encode_observations",
    "encode_seed", "encode_topic", "item_end", "node_timing", "observations_data", "parse_commands",
    "parse_episode_start", "parse_get_commands", "parse_observations", "parse_seed", "timespec_seconds",
]

ENV_DATA_IN = "AIDONODE_DATA_IN"
ENV_DATA_OUT = "AIDONODE_DATA_OUT"
COMPAT = ["z2"]
CTRL_CAPABILITIES = "capabilities"
CTRL_UNDERSTOOD = "understood"
CTRL_NOT_UNDERSTOOD = "not-understood"
CTRL_OVER = "over"
CTRL_ABORTED = "aborted"
CONTROL_CODES = frozenset({CTRL_CAPABILITIES, CTRL_UNDERSTOOD, CTRL_NOT_UNDERSTOOD, CTRL_OVER, CTRL_ABORTED})
CAPABILITIES = {"z2": {"protocol-reflection": True}}
#: the LED colours the recorded node sends with every command (all blue)
DEFAULT_LEDS = {k: {"b": 1.0, "g": 0.0, "r": 0.0} for k in ("center", "back_left", "back_right", "front_left",
                                                             "front_right")}


# ---------------------------------------------------------------------------------------------- errors
class BadMessageError(WireError):
    reason = "bad-message"


class MessageTypeError(ValueError):
    """A message's data does not have the declared types (e.g. an int where a float is declared)."""


# ------------------------------------------------------------------------------------------ envelopes
@dataclass(slots=True)
class Control:
    """``{"control": code, "data": data}``."""

    code: str
    data: Any = None


@dataclass(slots=True)
class Topic:
    """``{"compat": [...], "topic": topic, "data": data, "timing": timing}``; ``z2`` False: skip it."""

    topic: str
    data: Any
    timing: Any = None
    z2: bool = True


def encode_control(code: str, data: Any = None) -> bytes:
    return cbor2.dumps({"control": code, "data": data})


def encode_topic(topic: str, data: Any, timing: Any = None) -> bytes:
    return cbor2.dumps({"compat": COMPAT, "topic": topic, "data": data, "timing": timing})


# The per-step messages are assembled from cached byte pieces instead of building dicts for cbor2 (which
# costs ~3 µs per call however small the message): the same bytes, 3-5x faster. The tests compare every
# piece-built message with cbor2's encoding of the dict it stands for.
_dumps = cbor2.dumps
_DOUBLE = struct.Struct(">d").pack
_NO_TIMING = _dumps("timing") + _dumps(None)
_TIMING = _dumps("timing")


def _float(x: float) -> bytes:
    """cbor2's encoding of a float: an 8-byte float, except NaN and ±inf, which cbor2 writes as half floats."""
    return b"\xfb" + _DOUBLE(x) if math.isfinite(x) else _dumps(x)


def _head(major: int, n: int) -> bytes:
    """The CBOR header of major type ``major`` with argument ``n`` (0 ≤ n < 2⁶⁴), shortest form."""
    m = major << 5
    if n < 24:
        return bytes((m | n,))
    if n < 0x100:
        return bytes((m | 24, n))
    if n < 0x10000:
        return bytes((m | 25,)) + n.to_bytes(2, "big")
    if n < 0x100000000:
        return bytes((m | 26,)) + n.to_bytes(4, "big")
    return bytes((m | 27,)) + n.to_bytes(8, "big")


def _topic_head(topic: str) -> bytes:
    """The envelope up to its data: ``{"compat": ["z2"], "topic": topic, "data": ``."""
    return b"\xa4" + _dumps("compat") + _dumps(COMPAT) + _dumps("topic") + _dumps(topic) + _dumps("data")


def decode_message(obj: dict) -> Control | Topic:
    """The envelope of a decoded map; raises :class:`BadMessageError` when it is neither kind."""
    if "control" in obj:
        code = obj["control"]
        if not isinstance(code, str):
            raise BadMessageError(f"control code is not a string: {code!r}")
        return Control(code, obj.get("data"))
    topic = obj.get("topic")
    if not isinstance(topic, str) or "data" not in obj:
        raise BadMessageError(f"neither a control nor a topic message: keys {sorted(map(str, obj))}")
    compat = obj.get("compat")
    z2 = isinstance(compat, list) and "z2" in compat
    return Topic(topic, obj["data"], obj.get("timing"), z2)


@functools.lru_cache(maxsize=4096)
def _canonical_key(k: Any) -> tuple[int, bytes]:
    return (len(k.encode()), k.encode()) if isinstance(k, str) else (0, b"")


def canonical(value: Any) -> Any:
    """``value`` with every map's keys in canonical CBOR order (length first), as the zuper node sends."""
    if isinstance(value, dict):
        return {k: canonical(value[k]) for k in sorted(value, key=_canonical_key)}
    if isinstance(value, list):
        return [canonical(v) if isinstance(v, dict | list) else v for v in value]
    return value


# ------------------------------------------------------------------------------------------- timing
def _timespec(ns: int) -> dict:
    # the zuper library puts nanoseconds in the field called "us"; reproduce it
    return {"s": ns // 1_000_000_000, "us": ns % 1_000_000_000}


def node_timing(node: str, start_ns: int, end_ns: int | None = None) -> dict:
    """The ``timing`` a node attaches to its outputs: processed by ``node`` from ``start`` to ``end``."""
    end_ns = time.time_ns() if end_ns is None else end_ns
    spec = {"time": _timespec(start_ns), "clock": "vm", "frame": "epoch", "time2": _timespec(end_ns)}
    return {"processed": {node: spec}}


@functools.lru_cache(maxsize=64)
def _timing_pieces(node: str) -> tuple[bytes, bytes, bytes]:
    head = b"\xa1" + _dumps("processed") + b"\xa1" + _dumps(node) + b"\xa4" + _dumps("time")
    return head, _dumps("clock") + _dumps("vm") + _dumps("frame") + _dumps("epoch") + _dumps("time2"), \
        b"\xa2" + _dumps("s")


def _encode_timespec(ns: int, s_key: bytes) -> bytes:
    if not 0 <= ns < 1 << 64:
        return _dumps(_timespec(ns))
    return s_key + _head(0, ns // 1_000_000_000) + _US_KEY + _head(0, ns % 1_000_000_000)


_US_KEY = _dumps("us")


def encode_node_timing(node: str, start_ns: int, end_ns: int | None = None) -> bytes:
    """``cbor2.dumps(node_timing(node, start_ns, end_ns))``, built from cached pieces."""
    end_ns = time.time_ns() if end_ns is None else end_ns
    head, middle, s_key = _timing_pieces(node)
    return b"".join((head, _encode_timespec(start_ns, s_key), middle, _encode_timespec(end_ns, s_key)))


def timespec_seconds(spec: dict) -> float:
    """Seconds of a time spec ``{"s", "us"}``, read as nanoseconds when ``us`` ≥ 10⁶ (the library bug)
    and as microseconds otherwise; so a nanosecond value under 1 ms reads 1000× too large."""
    s, sub = spec["s"], spec["us"]
    return s + (sub * 1e-9 if sub >= 1_000_000 else sub * 1e-6)


# ------------------------------------------------------------------------------------ typed messages
def _is_float(x: Any) -> bool:
    return type(x) is float


#: an int beyond this is not a number a message carries (2**1024 made float() and isfinite() raise OverflowError
#: in the caller, which killed the evaluator's worker instead of failing the agent)
_MAX_INT = 2**53


def _is_number(x: Any) -> bool:
    return type(x) is float or (type(x) is int and -_MAX_INT <= x <= _MAX_INT)


def _need(data: Any, key: str, check, what: str, topic: str) -> Any:
    if not isinstance(data, dict) or key not in data:
        raise MessageTypeError(f"{topic}: missing field {key!r}")
    value = data[key]
    if not check(value):
        raise MessageTypeError(f"{topic}: field {key!r} must be {what}, got {type(value).__name__} "
                               f"{short_repr(value)}")
    return value


def encode_seed(seed: int) -> bytes:
    return encode_topic("seed", int(seed))


def parse_seed(data: Any) -> int:
    if type(data) is not int:
        raise MessageTypeError(f"seed must be an integer, got {type(data).__name__}")
    return data


def encode_episode_start(episode_name: str, yaml_payload: str = "{}") -> bytes:
    return encode_topic("episode_start", {"episode_name": str(episode_name), "yaml_payload": str(yaml_payload)})


def parse_episode_start(data: Any) -> tuple[str, str]:
    name = _need(data, "episode_name", lambda v: type(v) is str, "a string", "episode_start")
    payload = data.get("yaml_payload", "{}")
    if type(payload) is not str:
        raise MessageTypeError("episode_start: field 'yaml_payload' must be a string")
    return name, payload


def observations_data(jpg: bytes, timestamp: float, odometry: tuple[float, float] | None,
                      resolution: float | None, extras: dict | None = None) -> dict[str, Any]:
    """The data of an ``observations`` message (also a robot node's ``robot_observations.observations``);
    missing odometry is sent as NaN (floats stay floats)."""
    t = float(timestamp)
    left, right = (math.nan, math.nan) if odometry is None else (float(odometry[0]), float(odometry[1]))
    odo = {"resolution_rad": math.nan if resolution is None else float(resolution), "axis_left_rad": left,
           "axis_right_rad": right, "timestamp": t}
    data: dict[str, Any] = {"camera": {"jpg_data": bytes(jpg), "timestamp": t}, "odometry": odo}
    if extras is not None:
        data["proxybench"] = extras
    return data


_OBS_HEAD = (_topic_head("observations"), _dumps("camera") + b"\xa2" + _dumps("jpg_data"))
_OBS_KEYS = tuple(_dumps(k) for k in ("timestamp", "odometry", "resolution_rad", "axis_left_rad", "axis_right_rad",
                                      "proxybench"))


def encode_observations(jpg: bytes, timestamp: float, odometry: tuple[float, float] | None,
                        resolution: float | None, extras: dict | None = None) -> bytes:
    """An ``observations`` message (see :func:`observations_data`), the same bytes as
    ``encode_topic("observations", observations_data(...))``."""
    t = _float(float(timestamp))
    left, right = (math.nan, math.nan) if odometry is None else (float(odometry[0]), float(odometry[1]))
    k_stamp, k_odo, k_res, k_left, k_right, k_extras = _OBS_KEYS
    parts = [_OBS_HEAD[0], b"\xa2" if extras is None else b"\xa3", _OBS_HEAD[1], _head(2, len(jpg)), jpg,
             k_stamp, t, k_odo, b"\xa4", k_res, _float(math.nan if resolution is None else float(resolution)),
             k_left, _float(left), k_right, _float(right), k_stamp, t]
    if extras is not None:
        parts += [k_extras, _dumps(extras)]
    parts.append(_NO_TIMING)
    return b"".join(parts)


@dataclass(slots=True)
class ObservationsData:
    """A decoded ``observations`` message (the JPEG still encoded)."""

    jpg: bytes
    timestamp: float
    odometry: tuple[float, float] | None
    resolution: float | None
    extras: dict | None


def parse_observations(data: Any) -> ObservationsData:
    """Checks types as strictly as the real node: both maps present, every float a CBOR float."""
    cam = _need(data, "camera", lambda v: isinstance(v, dict), "a map", "observations")
    odo = _need(data, "odometry", lambda v: isinstance(v, dict), "a map", "observations")
    jpg = _need(cam, "jpg_data", lambda v: type(v) is bytes, "bytes", "observations.camera")
    stamp = _need(cam, "timestamp", _is_float, "a float", "observations.camera")
    values = [_need(odo, k, _is_float, "a float", "observations.odometry")
              for k in ("resolution_rad", "axis_left_rad", "axis_right_rad", "timestamp")]
    extras = data.get("proxybench")
    if extras is not None and not isinstance(extras, dict):
        raise MessageTypeError("observations: field 'proxybench' must be a map")
    odometry = None if math.isnan(values[1]) or math.isnan(values[2]) else (values[1], values[2])
    resolution = None if math.isnan(values[0]) else values[0]
    return ObservationsData(jpg, stamp, odometry, resolution, extras)


_GET_COMMANDS_HEAD = _topic_head("get_commands") + b"\xa1" + _dumps("at_time")


def encode_get_commands(at_time: float) -> bytes:
    """``encode_topic("get_commands", {"at_time": float(at_time)})``, from cached pieces."""
    return _GET_COMMANDS_HEAD + _float(float(at_time)) + _NO_TIMING


def parse_get_commands(data: Any) -> float:
    return _need(data, "at_time", _is_float, "a float", "get_commands")


_COMMANDS_HEAD = _topic_head("commands") + b"\xa2" + _dumps("LEDS") + _dumps(DEFAULT_LEDS) + _dumps("wheels") + \
    b"\xa2" + _dumps("motor_left")
_MOTOR_RIGHT = _dumps("motor_right")


def encode_commands(left: float, right: float, timing: dict | bytes | None = None) -> bytes:
    """A ``commands`` message as the recorded node writes it (canonical key order, blue LEDs); the same bytes
    as ``encode_topic("commands", {"LEDS": DEFAULT_LEDS, "wheels": {...}}, timing)``. ``timing`` may come
    already encoded (:func:`encode_node_timing`)."""
    tail = _NO_TIMING if timing is None else _TIMING + (timing if isinstance(timing, bytes) else _dumps(timing))
    return b"".join((_COMMANDS_HEAD, _float(float(left)), _MOTOR_RIGHT, _float(float(right)), tail))


def parse_commands(data: Any) -> np.ndarray:
    """Wheel PWM (left, right); raises :class:`MessageTypeError` unless both are finite numbers in [-1, 1].

    Ints are accepted (they are exact numbers); bools, NaN and infinities are not.
    """
    wheels = _need(data, "wheels", lambda v: isinstance(v, dict), "a map", "commands")
    out = np.empty(2)
    for i, key in enumerate(("motor_left", "motor_right")):
        v = _need(wheels, key, _is_number, "a number", "commands.wheels")
        if not math.isfinite(v) or not -1.0 <= v <= 1.0:
            raise MessageTypeError(f"commands.wheels: {key} = {short_repr(v)} is not a finite number in [-1, 1]")
        out[i] = v
    return out
