"""The compliance check a target must pass before a target job runs on it (else: ``host-error``).

A target is what the proxies stand in for: the *reality model* (``proxybench.domain.reality``, a simulated
stand-in with effects outside the proxy family), or a robot node started with ``--robot-cmd`` (a physical
robot's bridge, or a simulator served as a robot: what it is, it says itself, and reports carry it as
``domain_kind`` = ``robot-node/<kind>`` (``domain.kinds.robot_node_kind``), so a simulator behind the protocol
is never called a robot). The runner probes it (:func:`proxybench.runner.probe.probe`: one second of equal
forward commands, one frame); this module judges the probe. Three checks, each with a measured value and its bound:

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
from dataclasses import asdict, dataclass, field
from typing import Any

from proxybench.domain.kinds import DomainKind, robot_node_kind
from proxybench.domain.params import DomainParams
from proxybench.runner.jobs import DomainSpec
from proxybench.runner.probe import Probe, probe
from proxybench.tasks.benchmark import Benchmark

__all__ = [
    "CALIBRATION_TOLERANCES", "Check", "ComplianceReport", "check_calibration", "check_frame", "check_reality_model",
    "check_robot", "check_target", "judge",
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
    domain_kind: str  # a DomainKind, or robot_node_kind(what the node says) for a robot node
    checks: list[Check] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.checks)

    def failures(self) -> str:
        return "; ".join(f"{c.name}: {c.detail}" for c in self.checks if not c.ok)

    def to_dict(self) -> dict[str, Any]:
        return {"target": self.target, "domain_kind": str(self.domain_kind), "ok": self.ok,
                "checks": [asdict(c) for c in self.checks]}


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


def judge(bench: Benchmark, p: Probe, declared: dict[str, Any], *, robot: bool) -> list[Check]:
    """The three checks of what the probe ``p`` measured against ``bench``; ``declared``: the calibration
    the target says it has (a robot node's own words; the reality model's nominal calibration)."""
    spec = bench.domain_params()
    ok = p.moved >= MIN_RESPONSE_M and p.wall_s <= RESPONSE_TIMEOUT_S and all(map(math.isfinite, p.end))
    ended = f"; the episode ended early ({p.ended})" if p.ended else ""
    responds = Check("responds", ok, f"moved {p.moved:.3f} m in {p.seconds:.2f} s at PWM {_PWM} (need ≥ "
                                     f"{MIN_RESPONSE_M} m){ended}; setup and driving took {p.wall_s:.2f} s (limit "
                                     f"{RESPONSE_TIMEOUT_S:g} s)")
    camera = check_frame(p.frame or b"", spec.image_width, spec.image_height)
    if robot and camera.ok and not math.isclose(p.frame_rate, bench.frame_rate, rel_tol=1e-6):
        camera = Check("camera", False, f"the robot sends {p.frame_rate:g} frames/s; the benchmark runs at "
                                        f"{bench.frame_rate:g} Hz")
    calib = check_calibration(declared, spec) if declared else \
        Check("calibration", True, "the robot declares no calibration values; only its driving is checked")
    if p.heading_drift > MAX_STRAIGHT_DRIFT_RAD:
        calib = Check("calibration", False, f"heading drifted {p.heading_drift:.3f} rad in one second of equal "
                                            f"wheel commands (limit {MAX_STRAIGHT_DRIFT_RAD}); {calib.detail}")
    else:
        calib.detail += f"; straight-line drift {p.heading_drift:.3f} rad (limit {MAX_STRAIGHT_DRIFT_RAD})"
    return [responds, camera, calib]


def check_target(bench: Benchmark, domain: DomainSpec, *, seed: int = 0) -> tuple[ComplianceReport, Probe | None]:
    """Probe the target ``domain`` (the reality model, or a robot node) and judge it against ``bench``."""
    from proxybench.domain.reality import TRUTH
    from proxybench.protocol import RobotFailure

    robot = domain.kind is DomainKind.ROBOT
    if robot:
        report = ComplianceReport(f"robot node {domain.command!r}", robot_node_kind("unknown"))
    else:
        report = ComplianceReport("reality model (simulated stand-in, not a real robot)", domain.kind)
    try:
        p = probe(domain, bench.map, frame_rate=bench.frame_rate, seed=seed, pwm=_PWM, seconds=1.0)
    except RobotFailure as exc:
        report.checks.append(Check("responds", False, f"the robot node failed: {exc}"))
        return report, None
    if robot:
        report.domain_kind = robot_node_kind(p.kind)
        report.target = f"robot node {domain.command!r} (says it is: {p.kind})"
    report.checks += judge(bench, p, p.declared if robot else TRUTH, robot=robot)
    return report, p


def check_reality_model(bench: Benchmark, params: DomainParams, *, seed: int = 0) -> ComplianceReport:
    """Check the reality model instance ``params`` (as the target run will use it) against ``bench``."""
    return check_target(bench, DomainSpec("reality", params, DomainKind.REALITY_MODEL), seed=seed)[0]


def check_robot(bench: Benchmark, cmd: str, *, seed: int = 0, options: Any = None) -> ComplianceReport:
    """Check the robot node ``cmd`` (started with ``options``, a ``RobotNodeOptions``) against ``bench``."""
    return check_target(bench, DomainSpec.robot(cmd, frame_rate=bench.frame_rate, options=options), seed=seed)[0]
