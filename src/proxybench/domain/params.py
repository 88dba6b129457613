"""Domain parameters θ (every tunable of the simulated Duckiebot world) and domain families Θ.

``DomainParams`` is frozen and rejects unknown keys, so a misspelled parameter in a sweep or a
benchmark file is an error, not a silently ignored setting. ``ParamSpace`` describes a family: a base
instance plus distributions for some fields, sampled with a seeded generator.

>>> p = DomainParams(trim=0.1)
>>> p.replace(command_delay=0.1).command_delay
0.1
>>> space = ParamSpace.from_dict({"trim": {"uniform": [-0.2, 0.2]}, "light_rgb": {"uniform": [0.8, 1.2]}})
>>> q = space.sample(np.random.default_rng(0))
>>> -0.2 <= q.trim <= 0.2 and q.camera_pitch == p.camera_pitch
True
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

__all__ = [
    "DUCKIEBOT_DISTORTION", "DUCKIEBOT_INTRINSICS", "DUCKIEBOT_RGB", "DUCKIE_RGB", "NOMINAL_CALIBRATION",
    "DomainParams", "ParamSpace", "ParamSpaceError", "bounds_of", "check_image_size",
    "closest_parameter", "describe_params", "unit_of", "unknown_parameter",
]

RGB = tuple[float, float, float]
Unit = Annotated[float, Field(ge=0.0)]

#: Duckiebot camera calibration at 640×480 (fx, fy, cx, cy) and plumb-bob coefficients (k1, k2, p1, p2, k3).
DUCKIEBOT_INTRINSICS = (305.5718893575089, 308.8338858195428, 303.0797142544728, 231.8845403702499)
DUCKIEBOT_DISTORTION = (-0.2, 0.0305, 0.0005859930422629722, -0.0006697840226199427, 0.0)
#: default colours of duckies and duckiebots (objects, pedestrians, NPC robots), sRGB 0..255
DUCKIE_RGB = (240.0, 200.0, 20.0)
DUCKIEBOT_RGB = (30.0, 40.0, 90.0)
#: the DB18's nominal calibration: factory camera intrinsics and lens, 19.15° pitch, no trim, 0.10 s latency.
#: Every proxy starts from it (``experiments.proxies.NOMINAL``); the built-in reality model's calibrated
#: values were set to it (``domain.reality.TRUTH``)
NOMINAL_CALIBRATION: dict[str, Any] = {
    "trim": 0.0,
    "gain": 1.0,
    "command_delay": 0.10,
    "blur_time": 0.05,
    "camera_pitch": 19.15,
    "camera_height": 0.108,
    "camera_fov_y": 75.0,
    "fisheye": True,
    "intrinsics": DUCKIEBOT_INTRINSICS,
    "distortion": DUCKIEBOT_DISTORTION,
}


class DomainParams(BaseModel):
    """Parameters θ of one domain instance. Units are in each field's description.

    Structural fields (image size, rates) must be equal across the robots of one batch; the rest may
    differ per robot and per episode (domain randomisation).
    """

    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True)

    # --- dynamics (DB18) ---
    dynamics: Literal["dynamic", "kinematic"] = Field(
        "dynamic", description="'dynamic': AIDO's first-order velocity model; 'kinematic': wheel speed = PWM × max"
    )
    trim: float = Field(
        0.0, ge=-1.0, le=1.0,
        description="wheel imbalance: right wheel gain 1+trim, left 1−trim; positive trim drifts the robot left "
                    "(counter-clockwise) under equal commands [-]")
    gain: float = Field(1.0, gt=0.0, le=5.0, description="multiplier on both wheel commands [-]")
    v_decay: float = Field(5.0, gt=0.0, description="linear velocity decay a_v [1/s] (dv/dt = -a_v v + b_v (R+L))")
    v_gain: float = Field(1.5, gt=0.0, description="linear input gain b_v [m/s² per unit PWM]")
    w_decay: float = Field(4.0, gt=0.0, description="yaw-rate decay a_w [1/s] (dω/dt = -a_w ω + b_w (R-L))")
    w_gain: float = Field(15.0, gt=0.0, description="yaw-rate input gain b_w [rad/s² per unit PWM]")
    kinematic_max_speed: float = Field(0.6, gt=0.0, description="wheel speed at PWM 1, kinematic model [m/s]")
    wheel_distance: float = Field(0.102, gt=0.0, description="distance between the wheels [m]")
    wheel_radius: float = Field(0.0318, gt=0.0, description="wheel radius, for odometry [m]")
    encoder_resolution: float = Field(2 * math.pi / 135, gt=0.0, description="wheel encoder step [rad]")
    command_delay: float = Field(0.05, ge=0.0, le=2.0, description="age of the command being applied [s]")
    delay_jitter: float = Field(0.0, ge=0.0, le=1.0, description="extra random latency, uniform in [0, this] [s]")
    delay_jitter_shape: float = Field(
        1.0, ge=1.0, le=16.0,
        description="latency distribution: extra = delay_jitter · U^shape; 1 uniform, > 1 mostly short with rare "
                    "long delays (spikes) [-]")
    motor_deadband: float = Field(0.0, ge=0.0, lt=1.0, description="|PWM| below this does not move the wheel [-]")
    motor_saturation: float = Field(1.0, gt=0.0, le=1.0, description="|PWM| is clipped to this [-]")
    slip_speed: float = Field(0.0, ge=0.0, description="wheel slip growth with speed [1/(m/s)]")
    slip_turn: float = Field(0.0, ge=0.0, description="wheel slip growth with yaw rate [1/(rad/s)]")
    motor_gamma_left: float = Field(
        1.0, ge=0.25, le=4.0,
        description="left motor response curve: drive = |PWM'|^γ after dead-band and saturation; unequal left and "
                    "right curves make an imbalance that changes with speed, which trim cannot cancel [-]")
    motor_gamma_right: float = Field(1.0, ge=0.25, le=4.0, description="right motor response curve (as left) [-]")

    # --- timing ---
    physics_rate: float = Field(60.0, gt=0.0, le=10000.0, description="physics steps per second [Hz]")
    frame_rate: float = Field(15.0, gt=0.0, description="camera frames (and agent decisions) per second [Hz]")

    # --- camera ---
    image_width: int = Field(640, ge=8, le=4096, description="image width [px]")
    image_height: int = Field(480, ge=8, le=4096, description="image height [px]")
    camera_pitch: float = Field(19.15, ge=-60.0, le=89.0, description="camera tilt below horizontal [deg]")
    camera_height: float = Field(0.108, gt=0.0, description="camera height above the ground [m]")
    camera_forward: float = Field(0.066, description="camera position ahead of the wheel axle [m]")
    camera_yaw: float = Field(0.0, ge=-45.0, le=45.0, description="camera turned left of the robot's heading [deg]")
    camera_roll: float = Field(
        0.0, ge=-45.0, le=45.0,
        description="camera rotated about its optical axis, clockwise as seen from behind [deg]")
    camera_fov_y: float = Field(75.0, gt=1.0, lt=179.0, description="vertical field of view, pinhole model [deg]")
    fisheye: bool = Field(False, description="use the calibrated Duckiebot intrinsics and lens distortion")
    intrinsics: tuple[float, float, float, float] = Field(
        DUCKIEBOT_INTRINSICS, description="fx, fy, cx, cy at 640×480 [px], scaled to the image size"
    )
    distortion: tuple[float, float, float, float, float] = Field(
        DUCKIEBOT_DISTORTION, description="plumb-bob k1, k2, p1, p2, k3; equidistant lens: k1, k2, k3, k4, unused [-]"
    )
    lens_model: Literal["plumb_bob", "equidistant"] = Field(
        "plumb_bob", description="fisheye lens model: OpenCV's plumb-bob (radial-tangential, the Duckiebot "
                                 "calibration) or the equidistant (Kannala-Brandt) fisheye model")
    blur_time: float = Field(0.05, ge=0.0, le=1.0, description="exposure averaged for motion blur [s]")
    blur_samples: int = Field(3, ge=1, le=32, description="sub-frames averaged when blur_time > 0 [-]")
    texture_size: int = Field(256, ge=16, le=2048, description="texels per tile edge of the road textures [-]")

    # --- light and appearance (colours are sRGB 0..255) ---
    light_rgb: RGB = Field((1.0, 1.0, 1.0), description="per-channel light gain [-]")
    brightness: float = Field(0.0, ge=-255.0, le=255.0, description="added to every channel [0..255]")
    contrast: float = Field(1.0, ge=0.0, le=10.0, description="scales around mid-grey [-]")
    noise_std: float = Field(0.0, ge=0.0, le=128.0, description="per-pixel sensor noise std [0..255]")
    vignetting: float = Field(0.0, ge=0.0, le=1.0, description="darkening at the image corners [-]")
    texture_noise: float = Field(0.06, ge=0.0, le=1.0, description="surface grain: texel brightness spread [-]")
    texture_seed: int = Field(0, ge=0, description="seed of the surface texture pattern")
    road_rgb: RGB = Field((52.0, 52.0, 56.0), description="colour of the asphalt of road tiles [0..255]")
    white_rgb: RGB = Field((235.0, 235.0, 235.0), description="colour of the white lane markings [0..255]")
    yellow_rgb: RGB = Field((240.0, 200.0, 30.0), description="colour of the yellow centre line [0..255]")
    red_rgb: RGB = Field((215.0, 35.0, 35.0), description="colour of the red stop lines [0..255]")
    grass_rgb: RGB = Field((70.0, 135.0, 60.0), description="colour of the grass tiles [0..255]")
    floor_rgb: RGB = Field((150.0, 125.0, 100.0), description="colour of the floor tiles [0..255]")
    asphalt_rgb: RGB = Field((90.0, 90.0, 95.0), description="colour of the asphalt tiles [0..255]")
    outside_rgb: RGB = Field((120.0, 110.0, 100.0), description="colour of the ground outside the map [0..255]")
    sky_rgb: RGB = Field((160.0, 190.0, 225.0), description="colour of the sky at the zenith [0..255]")
    horizon_rgb: RGB = Field((215.0, 220.0, 225.0), description="colour of the sky at the horizon [0..255]")

    # --- objects and other road users (the defaults add nothing and change nothing) ---
    duckie_rgb: RGB = Field(DUCKIE_RGB, description="colour of duckies: map objects, extras, pedestrians [0..255]")
    duckiebot_rgb: RGB = Field(DUCKIEBOT_RGB, description="colour of duckiebot objects and NPC robots [0..255]")
    extra_duckies: int = Field(0, ge=0, le=100, description="duckies added beside the road, placed by object_seed [-]")
    object_seed: int = Field(0, ge=0, description="seed of where the extra duckies stand")
    npc_speed_scale: float = Field(
        1.0, ge=0.0, le=3.0, description="multiplies NPC robots' wheel commands and pedestrians' speeds [-]"
    )

    @model_validator(mode="before")
    @classmethod
    def _known_names(cls, data: Any) -> Any:
        """An unknown name is an error that lists the valid ones (with units) and the likely meant one."""
        if isinstance(data, Mapping):
            for name in data:
                if name not in cls.model_fields:
                    raise ValueError(unknown_parameter(str(name)))
        return data

    @model_validator(mode="after")
    def _check_rates(self) -> DomainParams:
        ratio = self.physics_rate / self.frame_rate
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError(
                f"physics_rate ({self.physics_rate:g} Hz) must be a whole multiple of frame_rate "
                f"({self.frame_rate:g} Hz), so that every frame falls on a physics step"
            )
        return self

    # --- derived quantities ---
    @property
    def physics_dt(self) -> float:
        """Physics step [s]."""
        return 1.0 / self.physics_rate

    @property
    def substeps(self) -> int:
        """Physics steps per camera frame."""
        return round(self.physics_rate / self.frame_rate)

    @property
    def delay_ticks(self) -> int:
        """Command delay in physics steps (rounded to the nearest step)."""
        return round(self.command_delay * self.physics_rate)

    @property
    def jitter_ticks(self) -> int:
        return round(self.delay_jitter * self.physics_rate)

    def replace(self, **changes: Any) -> DomainParams:
        """A validated copy with some fields changed."""
        return DomainParams.model_validate({**self.model_dump(), **changes})

    @classmethod
    def field_names(cls) -> list[str]:
        return list(cls.model_fields)


STRUCTURAL_FIELDS = ("image_width", "image_height", "physics_rate", "frame_rate")


def unit_of(name: str) -> str:
    """The unit of a θ field: the last ``[...]`` of its description ("" where it states none)."""
    found = re.findall(r"\[([^\[\]]+)\]", DomainParams.model_fields[name].description or "")
    return found[-1] if found else ""


def bounds_of(name: str) -> tuple[float | None, float | None]:
    """(lowest, highest) value a θ field accepts (None: unbounded on that side)."""
    lo = hi = None
    for m in DomainParams.model_fields[name].metadata:
        lo = getattr(m, "ge", None) if getattr(m, "ge", None) is not None else getattr(m, "gt", lo)
        hi = getattr(m, "le", None) if getattr(m, "le", None) is not None else getattr(m, "lt", hi)
    return lo, hi


def check_image_size(size: tuple[int, int]) -> tuple[int, int]:
    """A camera's (width, height) if θ accepts it (``image_width`` / ``image_height``), else a ValueError saying
    the bounds: for settings that name an image size before any θ is made (a study's, a watchtower's)."""
    (w_lo, w_hi), (h_lo, h_hi) = bounds_of("image_width"), bounds_of("image_height")
    if not (w_lo <= size[0] <= w_hi and h_lo <= size[1] <= h_hi):
        raise ValueError(f"width and height must be within {w_lo}…{w_hi} px, got {size[0]}×{size[1]}")
    return size


def describe_params() -> list[dict[str, Any]]:
    """Every θ field: name, unit, default, accepted range and meaning (``proxybench params`` prints them)."""
    rows = []
    for name, f in DomainParams.model_fields.items():
        lo, hi = bounds_of(name)
        unit = unit_of(name)
        desc = (f.description or "").replace(f" [{unit}]", "") if unit else (f.description or "")
        rows.append({"name": name, "unit": unit, "default": f.default, "low": lo, "high": hi, "description": desc})
    return rows


#: words people use for a θ field that no spelling distance finds
_SYNONYMS = {"delay": "command_delay", "latency": "command_delay", "blur": "blur_time", "motion_blur": "blur_time",
             "fov": "camera_fov_y", "width": "image_width", "height": "image_height", "resolution": "image_width",
             "fps": "frame_rate", "pitch": "camera_pitch", "tilt": "camera_pitch"}


def closest_parameter(name: str) -> str | None:
    """The θ field a misspelled or differently named ``name`` most likely means: one sharing a word with it
    (``motion_blur`` → ``blur_time``), else the closest spelling; None when nothing is close."""
    import difflib

    if name.lower() in _SYNONYMS:
        return _SYNONYMS[name.lower()]
    names = list(DomainParams.model_fields)
    words = set(name.lower().split("_"))
    sharing = [n for n in names if words & set(n.split("_"))]
    if sharing:
        return max(sharing, key=lambda n: (len(words & set(n.split("_"))),
                                           difflib.SequenceMatcher(None, name, n).ratio()))
    close = difflib.get_close_matches(name, names, n=1, cutoff=0.6)
    return close[0] if close else None


def unknown_parameter(name: str) -> str:
    """The message for a θ name that does not exist: the likely meant one and every valid name with its unit."""
    guess = closest_parameter(name)
    hint = f" (did you mean {guess!r}?)" if guess else ""
    valid = ", ".join(f"{n} [{unit_of(n)}]" if unit_of(n) else n for n in DomainParams.model_fields)
    return f"unknown domain parameter {name!r}{hint}; valid: {valid} (`proxybench params` describes each)"


class ParamSpaceError(ValueError):
    """A domain family description is invalid; the message names the parameter at fault."""


_DIST_KINDS = ("uniform", "loguniform", "normal", "choice")


class ParamSpace:
    """A family S_Θ: a base ``DomainParams`` and a distribution for each randomised field.

    Distributions are written as one-key mappings: ``{"uniform": [lo, hi]}``, ``{"loguniform": [lo, hi]}``,
    ``{"normal": [mean, std]}`` or ``{"choice": [v1, v2, ...]}``. For colour / RGB fields each channel
    is drawn independently from the same distribution. Integer fields (counts such as ``extra_duckies``)
    take the nearest integer of a continuous draw.
    """

    def __init__(self, base: DomainParams | None = None, dists: Mapping[str, Mapping[str, Any]] | None = None):
        self.base = base or DomainParams()
        self.dists: dict[str, tuple[str, list[Any]]] = {}
        for name, spec in (dists or {}).items():
            self.dists[name] = self._check(name, spec)
        # fail now, not at the first sample, if a drawn value could never validate
        self.sample(np.random.default_rng(0))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], base: DomainParams | None = None) -> ParamSpace:
        return cls(base, d)

    def _check(self, name: str, spec: Any) -> tuple[str, list[Any]]:
        if name not in DomainParams.model_fields:
            raise ParamSpaceError(unknown_parameter(name))
        if name in STRUCTURAL_FIELDS:
            raise ParamSpaceError(f"{name!r} is structural (shared by a whole batch) and cannot be randomised")
        if not isinstance(spec, Mapping) or len(spec) != 1:
            raise ParamSpaceError(f"{name}: expected one of {{{', '.join(_DIST_KINDS)}: ...}}, got {spec!r}")
        (kind, args), = spec.items()
        if kind not in _DIST_KINDS:
            raise ParamSpaceError(f"{name}: unknown distribution {kind!r} (one of {', '.join(_DIST_KINDS)})")
        args = list(args) if isinstance(args, (list, tuple)) else [args]
        if kind != "choice":
            if len(args) != 2 or not all(isinstance(a, (int, float)) and math.isfinite(a) for a in args):
                raise ParamSpaceError(f"{name}: {kind} takes two finite numbers, got {args!r}")
            if kind in ("uniform", "loguniform") and args[0] > args[1]:
                raise ParamSpaceError(f"{name}: {kind} low {args[0]} is above high {args[1]}")
            if kind == "loguniform" and args[0] <= 0:
                raise ParamSpaceError(f"{name}: loguniform bounds must be positive")
            if kind == "normal" and args[1] < 0:
                raise ParamSpaceError(f"{name}: normal std must be >= 0")
        elif not args:
            raise ParamSpaceError(f"{name}: choice needs at least one value")
        return kind, args

    @staticmethod
    def _draw(rng: np.random.Generator, kind: str, args: list[Any]) -> Any:
        if kind == "uniform":
            return float(rng.uniform(args[0], args[1]))
        if kind == "loguniform":
            return float(math.exp(rng.uniform(math.log(args[0]), math.log(args[1]))))
        if kind == "normal":
            return float(rng.normal(args[0], args[1]))
        return args[int(rng.integers(len(args)))]

    def sample(self, rng: np.random.Generator) -> DomainParams:
        """One domain instance θ ~ Θ. Fields are drawn in sorted order, so a seed fixes the result."""
        changes: dict[str, Any] = {}
        for name in sorted(self.dists):
            kind, args = self.dists[name]
            current = getattr(self.base, name)
            if isinstance(current, tuple) and kind != "choice":
                changes[name] = tuple(self._draw(rng, kind, args) for _ in current)
            else:
                changes[name] = self._draw(rng, kind, args)
            if type(current) is int and kind != "choice":
                changes[name] = round(changes[name])
        try:
            return self.base.replace(**changes)
        except ValidationError as exc:
            raise ParamSpaceError(f"a sampled instance is invalid: {exc}") from exc

    def to_dict(self) -> dict[str, Any]:
        return {name: {kind: args} for name, (kind, args) in self.dists.items()}
