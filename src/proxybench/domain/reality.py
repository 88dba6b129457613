"""The reality model: a *simulated stand-in* for a real Duckiebot, used as the target domain.

There are no real robots on the machines this project runs on, so the target of the usefulness
experiments is this model unless a run says otherwise (the other targets are recorded real
trajectories and external robot processes on the protocol). It is the same simulator switched into a
regime that the default proxy family does not cover, so that an irreducible gap remains:

- wheel slip growing with speed and turn rate, a motor dead-band and saturation;
- actuation latency with jitter on top of the fixed delay;
- a fisheye lens that differs from its calibration (the proxies model the calibrated one), vignetting;
- different light, road colour and surface grain, sensor noise.

Its *calibrated* parameters — the values a proxy should recover — are ``TRUTH``. A proxy that matches
them still differs from the reality model in everything listed above.

>>> reality_params().trim, reality_params().fisheye
(0.0, True)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from proxybench.domain.params import NOMINAL_CALIBRATION, DomainParams

__all__ = ["GAP_EFFECTS", "TRUTH", "hardware_variation", "reality_params"]

#: the calibrated values of the parameters the proxy family shares with the reality model; a calibrated
#: proxy models the Duckiebot's fisheye lens with its factory calibration
TRUTH: dict[str, Any] = dict(NOMINAL_CALIBRATION)

#: effects outside the proxy family (the irreducible gap). The visual gap is kept modest: a stronger one
#: (a lens far from its calibration, darker corners, other paint) shifts the proxy that best predicts the
#: target away from the calibrated values (measured with the uncalibrated fisheye: trim +0.1 to +0.15,
#: pitch +2 to +4°), because a proxy parameter that handicaps camera agents then stands in for the
#: handicap that the look of reality causes them.
GAP_EFFECTS: dict[str, Any] = {
    "slip_speed": 0.35,
    "slip_turn": 0.08,
    "motor_deadband": 0.06,
    "motor_saturation": 0.92,
    # latency 0.085 s + U[0, 0.03] s: 0.10 s on average, the calibrated value
    "command_delay": 0.085,
    "delay_jitter": 0.03,
    # the lens itself differs from its calibration (focal length, centre, distortion)
    "intrinsics": (300.0, 304.0, 306.5, 229.0),
    "distortion": (-0.22, 0.036, 0.0008, -0.0009, 0.0),
    "vignetting": 0.1,
    "light_rgb": (0.97, 1.0, 1.03),
    "noise_std": 2.0,
    "texture_seed": 7,
}


def reality_params(**overrides: Any) -> DomainParams:
    """θ of the reality model (optionally with some fields changed, e.g. the image size)."""
    return DomainParams.model_validate({**TRUTH, **GAP_EFFECTS, **overrides})


def hardware_variation(rng: np.random.Generator, base: DomainParams | None = None) -> DomainParams:
    """One physical robot's deviation from the nominal build: trim, gain and camera mounting.

    Used to sample a fleet of simulated robots for repeatability studies (thesis ch. 5).
    """
    base = base or reality_params()
    return base.replace(
        trim=float(np.clip(base.trim + rng.normal(0.0, 0.04), -0.3, 0.3)),
        gain=float(np.clip(base.gain * rng.normal(1.0, 0.05), 0.5, 1.5)),
        camera_pitch=float(base.camera_pitch + rng.normal(0.0, 1.0)),
        camera_height=float(base.camera_height + rng.normal(0.0, 0.003)),
    )
