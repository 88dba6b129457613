"""A short probe of a domain before real work runs on it: one second of equal forward commands, one frame.

The evaluator checks a target before a target job (:mod:`proxybench.evaluator.compliance`): does it answer,
send usable camera frames, drive straight, say it is calibrated like the benchmark's robot? The probe is
the measuring half, the same for every kind of domain (the reality model, a simulator, a robot node): an
episode of the one engine (:func:`~proxybench.runner.rollout.rollout`) with an open-loop policy, whose
plant is built here like every other plant. The judging half (bounds, messages) stays with the evaluator.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from proxybench.domain.events import Termination
from proxybench.domain.kinds import DomainKind
from proxybench.protocol import jpeg
from proxybench.runner.jobs import DomainSpec
from proxybench.runner.plants import open_plant
from proxybench.runner.rollout import OpenLoopPolicy, rollout

__all__ = ["Probe", "probe"]


@dataclass(frozen=True)
class Probe:
    """What a domain showed under ``seconds`` of equal forward wheel commands from one start."""

    kind: str  # what the domain says it is: simulation, reality-model, or a robot node's own word
    frame_rate: float  # [Hz] the camera frames it sent per second
    frame: bytes | None  # its first camera frame as an agent receives it (JPEG), None if it sent none
    start: tuple[float, float, float]  # (x [m], y [m], θ [rad]) at t = 0
    end: tuple[float, float, float]  # the pose after the commands
    seconds: float  # [s] of commands actually driven (less when the episode ended early)
    wall_s: float  # [s] of wall time: starting the episode and driving it
    declared: dict[str, Any] = field(default_factory=dict)  # the calibration the domain declares, if any
    ended: Termination | None = None  # why the episode ended before the commands were spent, if it did
    ground_truth: bool = True  # whether it reports the true lane pose (privileged agents need it)

    @property
    def moved(self) -> float:
        """[m] straight-line distance from start to end."""
        return float(np.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1]))

    @property
    def heading_drift(self) -> float:
        """|Δθ| [rad] from start to end, wrapped to [0, π]."""
        return abs((self.end[2] - self.start[2] + np.pi) % (2 * np.pi) - np.pi)


def probe(domain: DomainSpec, map_name: str, *, frame_rate: float, seed: int = 0, pwm: float = 0.5,
          seconds: float = 1.0) -> Probe:
    """Drive ``domain`` on ``map_name`` with PWM ``pwm`` on both wheels for ``seconds`` from ``seed``'s start.

    ``frame_rate`` [Hz]: what a robot node is asked to step at (a simulated domain's comes from its θ).
    A robot node that fails raises :class:`~proxybench.protocol.RobotFailure`.
    """
    with open_plant(domain, map_name, frame_rate=frame_rate) as plant:
        return _drive(plant, seed, pwm, seconds, kind=None if domain.kind is DomainKind.ROBOT else domain.kind)


def _drive(plant, seed: int, pwm: float, seconds: float, kind: str | None = None) -> Probe:
    first: list[bytes | None] = []
    truth: list[bool] = []

    def keep_first(k: int, images, alive: np.ndarray, p) -> None:
        if k == 0:
            raw = getattr(p, "encoded_frame", None)
            first.append(raw(0) if raw is not None else (None if images is None or images[0] is None
                                                          else jpeg.encode(images[0])))
            truth.append(p.observation(0, None, True).lane_pose is not None)

    commands = np.full((int(seconds * 1000) + 1, 2), pwm)  # one row per frame, at any rate up to 1 kHz
    t0 = time.monotonic()
    traj = rollout(plant, OpenLoopPolicy(commands, 1, "probe"), [seed], seconds, camera=True, on_frame=keep_first)[0]
    wall = time.monotonic() - t0
    said = traj.meta
    declared = said.get("params") or {}
    pose = np.column_stack([traj["x"], traj["y"], traj["theta"]])
    ended = None if traj.termination is Termination.TIMEOUT else traj.termination
    return Probe(kind or said.get("source", "unknown"), float(plant.frame_rate), first[0] if first else None,
                 tuple(float(v) for v in pose[0]), tuple(float(v) for v in pose[-1]), float(traj.duration), wall,
                 declared if kind is None else {}, ended, bool(truth and truth[0]))
