"""gym-duckietown's parameters θ, under gym's own names, checked before gym ever sees them.

Three groups, each under the name gym-duckietown (6.1.34) or duckietown-world (6.4.3) gives it:

- ``Simulator(...)`` constructor arguments: frame rate and skip, camera size, domain randomisation, lens
  distortion, ... (``gym_duckietown.simulator.Simulator``);
- the DB18 dynamics gym builds at each reset (``duckietown_world.world_duckietown.pwm_dynamics``):
  ``delay`` (gym's reset uses 0.15 s), ``trim`` (``get_DB18_uncalibrated``: the right wheel's gain ×(1+trim),
  the left's ×(1−trim)), and the model coefficients ``u1 u2 u3 w1 w2 w3 uar ual war wal``;
- the camera pose gym sets at each reset: ``cam_height`` [m], ``cam_angle`` (pitch) [deg], ``cam_fov_y`` [deg].

Defaults are gym's own, except the camera: 160×120 here (gym's is 640×480), the size proxybench's
experiments use. ``seed`` (None: each episode's seed) seeds gym's random generator (domain randomisation).
A wrong name or value is a :class:`GymParamError` naming it, with the valid names or range.
"""

from __future__ import annotations

import difflib
import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

__all__ = ["DEFAULTS", "NOT_TAKEN", "PARAMS", "GymParamError", "GymParams", "describe_params", "gym_params",
           "load_param_file", "parse_param_items"]


class GymParamError(ValueError):
    """A gym-duckietown parameter that cannot be used; the message names it."""


@dataclass(frozen=True)
class Spec:
    """One parameter: its default, kind (bool, int, float, str, rgb, int?), bounds and meaning."""

    default: Any
    kind: str
    help: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()


_RGB = "three numbers in [0, 1]"
PARAMS: dict[str, Spec] = {
    # gym_duckietown.simulator.Simulator(...)
    "domain_rand": Spec(True, "bool", "domain randomisation at each reset (light, colours, textures, camera)"),
    "frame_rate": Spec(30.0, "float", "physics updates per second [Hz] (delta_time = 1/frame_rate)", 1.0, 1000.0),
    "frame_skip": Spec(1, "int", "physics updates per camera frame", 1, 100),
    "camera_width": Spec(160, "int", "camera image width [px] (gym's default: 640)", 8, 2048),
    "camera_height": Spec(120, "int", "camera image height [px] (gym's default: 480)", 6, 2048),
    "distortion": Spec(False, "bool", "fish-eye lens distortion of the camera image"),
    "camera_rand": Spec(False, "bool", "randomised camera calibration (with distortion only, as in gym)"),
    "dynamics_rand": Spec(False, "bool", "random trim drawn at each reset (normal, σ 0.02), added to trim"),
    "max_steps": Spec(None, "int?", "gym's own step limit (an episode end); default: the caller's episode length",
                      1, 10**9),
    "robot_speed": Spec(1.2, "float", "gym's nominal speed [m/s] (wheel velocities it reports; not the motion)",
                        0.0, 10.0),
    "num_tris_distractors": Spec(12, "int", "random triangles on the floor around the map", 0, 1000),
    "color_ground": Spec((0.15, 0.15, 0.15), "rgb", "ground colour (RGB in [0, 1])"),
    "color_sky": Spec((0.45, 0.82, 1.0), "rgb", "sky colour (RGB in [0, 1])"),
    "style": Spec("photos", "str", "tile textures", choices=("photos", "synthetic")),
    "enable_leds": Spec(False, "bool", "draw the robots' LEDs"),
    "draw_curve": Spec(False, "bool", "draw the lane curves (debugging)"),
    "draw_bbox": Spec(False, "bool", "draw bounding boxes (debugging; turns distortion off)"),
    "seed": Spec(None, "int?", "gym's random seed for every episode; default: each episode's seed", 0, 2**32 - 1),
    # duckietown_world DB18 dynamics (get_DB18_uncalibrated, DynamicModelParameters)
    "delay": Spec(0.15, "float", "command delay [s]: the command stamped nearest to t − delay acts", 0.0, 2.0),
    "trim": Spec(0.0, "float", "wheel trim: right wheel gain ×(1+trim), left ×(1−trim)", -0.99, 0.99),
    "u1": Spec(5.0, "float", "longitudinal damping [1/s]", -1e3, 1e3),
    "u2": Spec(0.0, "float", "longitudinal coupling to ω", -1e3, 1e3),
    "u3": Spec(0.0, "float", "longitudinal term in ω²", -1e3, 1e3),
    "w1": Spec(4.0, "float", "angular damping [1/s]", -1e3, 1e3),
    "w2": Spec(0.0, "float", "angular coupling to v", -1e3, 1e3),
    "w3": Spec(0.0, "float", "angular term in v·ω", -1e3, 1e3),
    "uar": Spec(1.5, "float", "right PWM → longitudinal acceleration", -1e3, 1e3),
    "ual": Spec(1.5, "float", "left PWM → longitudinal acceleration", -1e3, 1e3),
    "war": Spec(15.0, "float", "right PWM → angular acceleration (before trim)", -1e3, 1e3),
    "wal": Spec(15.0, "float", "left PWM → angular acceleration (before trim)", -1e3, 1e3),
    # the camera pose gym's reset sets (then randomises with domain_rand / camera_rand)
    "cam_height": Spec(0.108, "float", "camera height above the floor [m]", 0.01, 1.0),
    "cam_angle": Spec(19.15, "float", "camera pitch down [deg]", -90.0, 90.0),
    "cam_fov_y": Spec(75.0, "float", "vertical field of view [deg]", 1.0, 179.0),
}
DEFAULTS: dict[str, Any] = {k: s.default for k, s in PARAMS.items()}

#: gym names the node does not take, and why
NOT_TAKEN = {
    "map_name": "the map is --map, or the one the caller sends (set_map)",
    "user_tile_start": "the caller gives each episode's start pose",
    "accept_start_angle_deg": "the caller gives each episode's start pose (gym's random spawn is not used)",
    "randomize_maps_on_reset": "the map is the caller's",
    "full_transparency": "it changes only gym's info dict, which the robot protocol does not carry",
    "gain": "DuckietownEnv's velocity → PWM conversion; the robot protocol sends PWM (use the DB18's uar/ual/war/wal)",
    "k": "DuckietownEnv's velocity → PWM conversion; the robot protocol sends PWM",
    "radius": "DuckietownEnv's velocity → PWM conversion; the robot protocol sends PWM",
    "limit": "DuckietownEnv's velocity → PWM conversion; the robot protocol sends PWM",
}


def _check(name: str, raw: Any) -> Any:
    """``raw`` as parameter ``name`` takes it, or a GymParamError naming both."""
    if name not in PARAMS:
        if name in NOT_TAKEN:
            raise GymParamError(f"parameter {name!r}: not taken by the gym node: {NOT_TAKEN[name]}")
        close = difflib.get_close_matches(name, list(PARAMS), n=3)
        hint = f"did you mean {' or '.join(map(repr, close))}? " if close else ""
        raise GymParamError(f"unknown parameter {name!r}; {hint}valid: {', '.join(PARAMS)}")
    s = PARAMS[name]
    bad = f"parameter {name}={raw!r}:"
    if s.kind == "bool":
        if type(raw) is not bool:
            raise GymParamError(f"{bad} must be true or false")
        return raw
    if s.kind == "str":
        if raw not in s.choices:
            raise GymParamError(f"{bad} must be one of {', '.join(s.choices)}")
        return raw
    if s.kind == "rgb":
        if not (isinstance(raw, list | tuple) and len(raw) == 3 and all(_number(v) and 0 <= v <= 1 for v in raw)):
            raise GymParamError(f"{bad} must be {_RGB}, e.g. [0.15, 0.15, 0.15]")
        return tuple(float(v) for v in raw)
    if s.kind == "int?" and raw is None:
        return None
    if s.kind in ("int", "int?"):
        if type(raw) is not int:
            raise GymParamError(f"{bad} must be an integer in [{s.low:g}, {s.high:g}]")
    elif not _number(raw):
        raise GymParamError(f"{bad} must be a number in [{s.low:g}, {s.high:g}]")
    if not (s.low <= raw <= s.high):
        raise GymParamError(f"{bad} out of range [{s.low:g}, {s.high:g}]")
    return raw if s.kind != "float" else float(raw)


def _number(v: Any) -> bool:
    return type(v) in (int, float) and math.isfinite(v)


@dataclass(frozen=True)
class GymParams:
    """θ of a gym node: every parameter (defaults filled in), whether it is hidden, and the nonce mixed into
    its hash (so that a hidden low-entropy θ such as ``trim: 0.1`` cannot be guessed from the hash)."""

    values: dict[str, Any]
    hidden: bool = False
    nonce: str = ""

    @property
    def changed(self) -> dict[str, Any]:
        return {k: v for k, v in self.values.items() if v != DEFAULTS[k]}

    @property
    def sha256(self) -> str:
        """Hash of θ (all parameters) and the nonce: what a report shows of a hidden θ."""
        text = json.dumps({"params": _json(self.values), "nonce": self.nonce}, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    def public(self) -> dict[str, Any]:
        """What the node reports: θ, or only its hash when hidden."""
        return {"hidden": True, "sha256": self.sha256} if self.hidden else _json(self.values)


def _json(values: dict[str, Any]) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in values.items()}


def parse_param_items(items: list[str]) -> dict[str, Any]:
    """``NAME=VALUE`` items (values read as YAML) → checked values; a bad one is a GymParamError."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise GymParamError(f"--param {item!r} is not NAME=VALUE")
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError as exc:
            raise GymParamError(f"--param {item!r}: the value is not valid YAML ({exc})") from None
        out[key.strip()] = _check(key.strip(), value)
    return out


def load_param_file(path: str | Path) -> tuple[dict[str, Any], str]:
    """(checked values, nonce) of a YAML parameter file: ``NAME: VALUE`` lines and an optional ``nonce``."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise GymParamError(f"--param-file {path}: cannot read it ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        raise GymParamError(f"--param-file {path}: not valid YAML ({exc})") from None
    data = {} if data is None else data
    if not isinstance(data, dict):
        raise GymParamError(f"--param-file {path}: expected a mapping NAME: VALUE, got {type(data).__name__}")
    nonce = data.pop("nonce", "")
    if not isinstance(nonce, str):
        raise GymParamError(f"--param-file {path}: nonce must be a string")
    try:
        return {str(k): _check(str(k), v) for k, v in data.items()}, nonce
    except GymParamError as exc:
        raise GymParamError(f"--param-file {path}: {exc}") from None


def gym_params(items: list[str], param_file: str | Path | None = None, secret: bool = False) -> GymParams:
    """θ from ``--param`` items on top of ``--param-file``; ``secret`` hides it (then only the file may give
    it: a value on the command line would be seen by whoever sees the command)."""
    if secret and items:
        raise GymParamError("--secret: give the parameters in --param-file (a --param is visible in the command)")
    if secret and param_file is None:
        raise GymParamError("--secret needs --param-file FILE with the hidden parameters")
    values, nonce = load_param_file(param_file) if param_file is not None else ({}, "")
    if secret and len(nonce) < 16:  # without one, the hash a report shows of a hidden θ is a brute-force away
        raise GymParamError(f"--param-file {param_file}: --secret needs a random `nonce:` of 16 characters or more in "
                            "the file (e.g. `nonce: " + "0" * 4 + "…`, from `python3 -c 'import secrets; "
                            "print(secrets.token_hex(16))'`); a hidden θ's hash without one can be brute-forced")
    values.update(parse_param_items(items))
    return GymParams({**DEFAULTS, **values}, secret, nonce)


def describe_params() -> str:
    """One line per parameter: name, default, meaning; then the gym names the node does not take."""
    lines = [f"{k:22} {json.dumps(_json({k: s.default})[k]):>20}  {s.help}" for k, s in PARAMS.items()]
    lines += ["", "not taken:"] + [f"{k:22} {why}" for k, why in NOT_TAKEN.items()]
    return "\n".join(lines)
