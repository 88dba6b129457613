"""The compliance check a target must pass before a target job runs on it (else: ``host-error``).

A target is what the proxies stand in for. Here it is the *reality model* (``proxybench.domain.reality``,
a simulated stand-in with effects outside the proxy family); it is never a real robot unless one is
attached through the robot protocol. Three checks, each with a measured value and its bound:

- **responds**: commanded forward (PWM 0.5 on both wheels for one second), the robot moves at least
  ``MIN_RESPONSE_M`` within ``RESPONSE_TIMEOUT_S`` of wall time;
- **camera**: a frame, sent as the agent would receive it, is a complete JPEG (SOI … EOI) that decodes to
  the benchmark's image size and is not blank (pixel spread above ``MIN_FRAME_STD``);
- **calibration**: the robot's declared calibration (trim, gain, camera mounting) is within
  ``CALIBRATION_TOLERANCES`` of the robot the benchmark describes, and it drives straight: the heading
  drifts at most ``MAX_STRAIGHT_DRIFT_RAD`` over that second of equal wheel commands.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from proxybench.domain.params import DomainParams
from proxybench.tasks.benchmark import Benchmark

__all__ = [
    "CALIBRATION_TOLERANCES", "Check", "ComplianceReport", "check_calibration", "check_frame", "check_reality_model",
]

#: |declared − benchmark| allowed per calibrated quantity [units of the DomainParams field]
CALIBRATION_TOLERANCES: dict[str, float] = {
    "trim": 0.1, "gain": 0.2, "wheel_distance": 0.01, "wheel_radius": 0.004,
    "camera_pitch": 3.0, "camera_height": 0.015, "camera_forward": 0.02,
}
MIN_RESPONSE_M = 0.05  # [m] in one second at PWM 0.5
RESPONSE_TIMEOUT_S = 10.0  # [s] of wall time for that second
MIN_FRAME_STD = 2.0  # [0..255]
MAX_STRAIGHT_DRIFT_RAD = 0.15  # [rad] over one second of equal wheel commands
_PWM = 0.5


@dataclass
class Check:
    name: str
    ok: bool
    detail: str


@dataclass
class ComplianceReport:
    """What was checked on which target; ``ok`` when every check passed."""

    target: str
    domain_kind: str
    checks: list[Check] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.checks)

    def failures(self) -> str:
        return "; ".join(f"{c.name}: {c.detail}" for c in self.checks if not c.ok)

    def to_dict(self) -> dict[str, Any]:
        return {"target": self.target, "domain_kind": self.domain_kind, "ok": self.ok,
                "checks": [asdict(c) for c in self.checks]}


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def check_frame(jpg: bytes, width: int, height: int) -> Check:
    """A camera frame as sent over the protocol: complete JPEG of ``width`` × ``height``, not blank."""
    from proxybench.protocol import jpeg

    if not (jpg[:2] == b"\xff\xd8" and jpg[-2:] == b"\xff\xd9"):
        return Check("camera", False, f"frame is not a complete JPEG ({len(jpg)} bytes, no SOI/EOI markers)")
    try:
        img = jpeg.decode(jpg)
    except Exception as exc:  # any decoder complaint means the same: an unusable frame
        return Check("camera", False, f"frame does not decode as JPEG ({exc})")
    if img.shape != (height, width, 3):
        return Check("camera", False, f"frame is {img.shape[1]}×{img.shape[0]}×{img.shape[2] if img.ndim > 2 else 1}; "
                                      f"the benchmark expects {width}×{height} RGB")
    spread = float(img.std())
    if spread < MIN_FRAME_STD:
        return Check("camera", False, f"frame is blank (pixel std {spread:.2f} < {MIN_FRAME_STD})")
    return Check("camera", True, f"{width}×{height} JPEG, {len(jpg)} bytes, pixel std {spread:.1f}")


def check_calibration(declared: dict[str, Any], spec: DomainParams) -> Check:
    """Declared calibration values against the benchmark's robot, field by field."""
    off = []
    for name, tol in CALIBRATION_TOLERANCES.items():
        if name in declared:
            diff = abs(float(declared[name]) - float(getattr(spec, name)))
            if diff > tol:
                off.append(f"{name} {declared[name]:g} vs {getattr(spec, name):g} (|Δ| {diff:.3g} > {tol:g})")
    if off:
        return Check("calibration", False, "outside the benchmark's spec: " + "; ".join(off))
    named = ", ".join(n for n in CALIBRATION_TOLERANCES if n in declared)
    return Check("calibration", True, f"{named} within tolerance of the benchmark's robot")


def check_reality_model(bench: Benchmark, params: DomainParams, *, seed: int = 0) -> ComplianceReport:
    """Check the reality model instance ``params`` (as the target run will use it) against ``bench``."""
    from proxybench.domain.reality import TRUTH
    from proxybench.domain.simulator import Simulator
    from proxybench.protocol import jpeg

    report = ComplianceReport("reality model (simulated stand-in, not a real robot)", "reality-model")
    spec = bench.domain_params()
    sim = Simulator(bench.map, params, n=1)
    t0 = time.monotonic()
    sim.reset(0, seed)
    start = sim.state[0, :3].copy()
    frames = max(1, round(bench.frame_rate))
    for _ in range(frames):
        sim.step(np.array([[_PWM, _PWM]]))
    end = sim.state[0, :3]
    wall = time.monotonic() - t0
    moved = float(np.hypot(*(end[:2] - start[:2])))
    ok = moved >= MIN_RESPONSE_M and wall <= RESPONSE_TIMEOUT_S and bool(np.all(np.isfinite(end)))
    report.checks.append(Check("responds", ok, f"moved {moved:.3f} m in {frames / bench.frame_rate:.2f} s at PWM "
                                               f"{_PWM} (need ≥ {MIN_RESPONSE_M} m), answered in {wall:.2f} s "
                                               f"(limit {RESPONSE_TIMEOUT_S:g} s)"))
    frame = sim.render()[0]
    report.checks.append(check_frame(jpeg.encode(frame), spec.image_width, spec.image_height))
    calib = check_calibration(TRUTH, spec)
    drift = abs(_wrap(float(end[2] - start[2])))
    if drift > MAX_STRAIGHT_DRIFT_RAD:
        calib = Check("calibration", False, f"heading drifted {drift:.3f} rad in one second of equal wheel "
                                            f"commands (limit {MAX_STRAIGHT_DRIFT_RAD}); " + calib.detail)
    else:
        calib.detail += f"; straight-line drift {drift:.3f} rad (limit {MAX_STRAIGHT_DRIFT_RAD})"
    report.checks.append(calib)
    return report
