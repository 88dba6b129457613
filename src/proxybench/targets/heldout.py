"""Held-out targets: simulated stand-ins whose differences from the proxies are *structural*, with hidden truths.

The built-in reality model is the proxy plus a fixed set of knobs, and its calibrated θ sits at the centre
of every default sweep, so an experiment against it can hardly fail. A held-out target is drawn from a
seed into a different regime each time:

- its θ in the proxies' family (trim, camera pitch; also gain, latency, exposure, camera height) is drawn
  *off-grid* around the nominal calibration;
- its differences from the proxies are ones no proxy θ expresses: motors with unequal response curves, a
  motor dead-band and saturation, wheel slip growing with speed and turn rate, latency with jitter of a
  random distribution (uniform to spiky), a camera with yaw and roll, a lens of another model (equidistant
  fisheye where the proxies calibrate a plumb-bob one) or off its calibration, other light, paint, grain,
  vignetting and sensor noise.

An experiment gets each one as a black box, a :class:`HeldOutTarget`: it can run agents on it, but its
``truth()`` is empty, its ``TargetRun`` carries no θ, and its label and statement name no value. Only
:meth:`HeldOutTarget.reveal` gives the drawn θ, for scoring once every episode has run.

>>> t = heldout_targets(2, seed=5)
>>> [x.name for x in t], t[0].truth(), "trim" in t[0].info().statement
(['heldout-0', 'heldout-1'], {}, False)
>>> -0.15 <= t[0].reveal()["trim"] <= 0.15
True
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from proxybench.domain.kinds import DomainKind
from proxybench.domain.params import DUCKIEBOT_DISTORTION, DUCKIEBOT_INTRINSICS, DomainParams
from proxybench.runner.jobs import DomainSpec
from proxybench.targets.spec import TargetInfo, TargetRun, _LiveTarget

__all__ = ["FAMILY_PARAMS", "HeldOutTarget", "draw_heldout", "heldout_targets"]

#: the θ a held-out target shares with the proxies (its hidden truth), drawn uniformly in these ranges:
#: around the nominal calibration, never on a grid
FAMILY_PARAMS: dict[str, tuple[float, float]] = {
    "trim": (-0.15, 0.15),
    "camera_pitch": (16.65, 21.65),
    "gain": (0.92, 1.08),
    "command_delay": (0.07, 0.13),
    "blur_time": (0.02, 0.08),
    "camera_height": (0.104, 0.112),
}


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _lens(rng: np.random.Generator) -> dict[str, Any]:
    """Half the targets have an equidistant (Kannala-Brandt) fisheye, half a plumb-bob one off its
    calibration; both with intrinsics a few per cent off. k1 ≈ 0.12, k2 ≈ −0.044 is the equidistant lens
    closest to the Duckiebot's plumb-bob calibration (least squares over the image)."""
    fx, fy, cx, cy = DUCKIEBOT_INTRINSICS
    scale = _u(rng, 0.96, 1.04)
    intr = (fx * scale, fy * scale * _u(rng, 0.99, 1.01), cx + _u(rng, -8, 8), cy + _u(rng, -8, 8))
    if rng.uniform() < 0.5:
        return {"lens_model": "equidistant", "intrinsics": intr,
                "distortion": (_u(rng, 0.06, 0.18), _u(rng, -0.08, 0.0), 0.0, 0.0, 0.0)}
    k1, k2, p1, p2, k3 = DUCKIEBOT_DISTORTION
    return {"lens_model": "plumb_bob", "intrinsics": intr,
            "distortion": (k1 + _u(rng, -0.04, 0.04), k2 + _u(rng, -0.01, 0.01), p1, p2, k3)}


def draw_heldout(seed: int, index: int, ranges: dict[str, tuple[float, float]] | None = None) -> dict[str, Any]:
    """θ of held-out target ``index`` of the family seeded ``seed`` (every DomainParams field it changes).

    ``ranges``: where the θ it shares with the proxies is drawn (default :data:`FAMILY_PARAMS`; the validation
    study draws wider and off-centre). The draw is a pure function of (seed, index, ranges), so a family is
    reproducible by whoever holds the seed.
    """
    rng = np.random.default_rng([seed, index, 0x4E1D])
    theta = {name: _u(rng, lo, hi) for name, (lo, hi) in (ranges or FAMILY_PARAMS).items()}
    theta = {**{n: (lo + hi) / 2 for n, (lo, hi) in FAMILY_PARAMS.items()}, **theta}
    jitter, shape = _u(rng, 0.0, 0.06), _u(rng, 1.0, 4.0)
    mean_extra = jitter / (shape + 1.0)  # E[jitter · U^shape]: keep the *mean* latency at the drawn value
    effects: dict[str, Any] = {
        "command_delay": max(theta["command_delay"] - mean_extra, 0.0),
        "delay_jitter": jitter,
        "delay_jitter_shape": shape,
        "motor_gamma_left": math.exp(_u(rng, -0.25, 0.25)),
        "motor_gamma_right": math.exp(_u(rng, -0.25, 0.25)),
        "motor_deadband": _u(rng, 0.0, 0.08),
        "motor_saturation": _u(rng, 0.85, 1.0),
        "slip_speed": _u(rng, 0.0, 0.5),
        "slip_turn": _u(rng, 0.0, 0.15),
        "camera_yaw": _u(rng, -3.0, 3.0),
        "camera_roll": _u(rng, -3.0, 3.0),
        "fisheye": True,
        **_lens(rng),
        "light_rgb": tuple(_u(rng, 0.85, 1.15) for _ in range(3)),
        "brightness": _u(rng, -12.0, 12.0),
        "contrast": _u(rng, 0.9, 1.1),
        "noise_std": _u(rng, 0.0, 4.0),
        "vignetting": _u(rng, 0.0, 0.3),
        "texture_seed": int(rng.integers(1, 1_000_000)),
        "texture_noise": _u(rng, 0.03, 0.12),
        "road_rgb": tuple(v + _u(rng, -10, 10) for v in DomainParams().road_rgb),
        "white_rgb": tuple(min(v + _u(rng, -20, 10), 255.0) for v in DomainParams().white_rgb),
        "yellow_rgb": tuple(min(max(v + _u(rng, -15, 15), 0.0), 255.0) for v in DomainParams().yellow_rgb),
    }
    out = {**theta, **effects, "command_delay_mean": theta["command_delay"]}
    DomainParams.model_validate({k: v for k, v in out.items() if k != "command_delay_mean"})
    return out


class HeldOutTarget(_LiveTarget):
    """One held-out target, a black box to the experiment: runs agents, tells nothing of its θ until
    :meth:`reveal`. Simulated, and every statement it makes says so."""

    kind = DomainKind.REALITY_MODEL

    def __init__(self, seed: int, index: int, ranges: dict[str, tuple[float, float]] | None = None):
        self.name = f"heldout-{index}"
        self._drawn = draw_heldout(seed, index, ranges)

    def domain(self, image_size: tuple[int, int]) -> DomainSpec:
        w, h = image_size
        params = {k: v for k, v in self._drawn.items() if k != "command_delay_mean"}
        return DomainSpec(self.name, DomainParams.model_validate({**params, "image_width": w, "image_height": h}),
                          kind=DomainKind.REALITY_MODEL)

    def truth(self) -> dict[str, float]:
        return {}  # hidden: an experiment must not see it before scoring

    def reveal(self) -> dict[str, Any]:
        """The drawn θ and effects (for scoring, after every episode ran). ``command_delay`` is the *mean*
        latency (the fixed part plus the mean jitter), the value a proxy's fixed delay should match."""
        out = dict(self._drawn)
        out["command_delay_fixed"] = out["command_delay"]
        out["command_delay"] = out.pop("command_delay_mean")
        return out

    def info(self) -> TargetInfo:
        return TargetInfo(
            DomainKind.REALITY_MODEL, True, f"{self.name} (held-out, simulated)",
            f"SIMULATED: {self.name} is a held-out stand-in drawn from a hidden seed, with structural differences "
            "from the proxies (unequal motor response curves, dead-band and saturation, wheel slip, latency "
            "jitter, camera yaw and roll, another lens, other light and paint) and a θ the experiment does not "
            "see until scoring. No real robot was involved.", {"name": self.name})

    def run(self, agents, **kwargs) -> TargetRun:
        run = super().run(agents, **kwargs)
        run.params = None  # nothing of the hidden θ reaches the experiment (POD, which needs it, is skipped)
        return run


def heldout_targets(n: int, seed: int, ranges: dict[str, tuple[float, float]] | None = None,
                    indices: list[int] | None = None) -> list[HeldOutTarget]:
    """``n`` targets of the held-out family seeded ``seed`` (θ drawn in ``ranges``): the first ``n``, or the draws
    ``indices`` (a stratified study keeps the draws that fill its strata)."""
    if n < 1:
        raise ValueError(f"targets: need at least 1 held-out target, got {n}")
    return [HeldOutTarget(seed, i, ranges) for i in (range(n) if indices is None else indices[:n])]
