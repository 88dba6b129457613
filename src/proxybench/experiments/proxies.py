"""Proxy instances and the neutral defaults of sweeps and searches.

A proxy is the plain simulator (no effects outside its family) at the **nominal calibration** of a DB18
Duckiebot — factory camera intrinsics and fisheye distortion, camera pitch 19.15°, height 0.108 m,
vertical field of view 75°, no wheel trim, unit gain, 0.10 s actuation latency, 0.05 s exposure — with
the swept or searched parameters changed. Sweeps and search ranges default to values *around this
nominal calibration*, which is all a lab knows before it measures: they never come from a target's
truth. (The built-in reality model was given the nominal values as its calibrated truth, so against
that one target the defaults happen to be centred on the truth; against recorded and robot targets
nothing is known. Set your own ranges with ``sweep:`` / ``search.space:`` in the experiment file.)
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from pydantic import ValidationError

from proxybench.domain.params import NOMINAL_CALIBRATION, DomainParams, unit_of
from proxybench.runner.jobs import DomainSpec

__all__ = ["DEFAULT_SEARCH", "DEFAULT_SWEEP", "NOMINAL", "param_label", "proxy_domain", "proxy_params"]

#: the nominal calibration every proxy starts from (see the module docstring)
NOMINAL: dict[str, Any] = NOMINAL_CALIBRATION

#: predictivity sweep: trim over its physical range in 7 steps (figure 3.3) and three values around the
#: nominal value of each other parameter (figure 3.4)
DEFAULT_SWEEP: dict[str, tuple[float, ...]] = {
    "trim": tuple(float(v) for v in np.round(np.linspace(-0.3, 0.3, 7), 3)),
    "command_delay": (0.05, 0.10, 0.15),
    "blur_time": (0.0, 0.05, 0.10),
    "camera_pitch": (15.0, 19.15, 23.0),
}

#: optimisation search space: trim over ±0.3 and camera pitch over 12…26°
DEFAULT_SEARCH: dict[str, tuple[float, float]] = {"trim": (-0.3, 0.3), "camera_pitch": (12.0, 26.0)}


def proxy_params(image_size: tuple[int, int], fixed: dict[str, Any] | None = None, **changes: Any) -> DomainParams:
    """A proxy instance: the nominal calibration, then ``fixed`` (the experiment's proxy θ), then ``changes``."""
    w, h = image_size
    return DomainParams.model_validate({**NOMINAL, **(fixed or {}), **changes, "image_width": w, "image_height": h})


def proxy_domain(image_size: tuple[int, int], fixed: dict[str, Any], theta: Mapping[str, Any], field: str,
                 nominal_label: str) -> DomainSpec:
    """θ on top of ``fixed`` (the experiment's proxy θ) and the nominal calibration, named by θ (``nominal_label``
    when θ is empty); a bad name or value is a ConfigError naming ``field``."""
    from proxybench.experiments.study import ConfigError
    from proxybench.untrusted import problems

    try:
        params = proxy_params(image_size, {**fixed, **theta})
    except ValidationError as exc:
        raise ConfigError(problems(exc, field)) from None
    return DomainSpec(", ".join(f"{k}={v}" for k, v in theta.items()) if theta else nominal_label, params)


def param_label(name: str) -> str:
    """``name [unit]`` for axis labels."""
    unit = unit_of(name) if name in DomainParams.model_fields else ""
    return f"{name} [{unit}]" if unit else name
