"""Episodes on a DTPS robot (a real Duckiebot or a Duckiematrix robot), through the bridge's client role.

:class:`DtpsRobot` is the connection a batch of episodes shares; :class:`DtpsPlant` makes it a plant of the
episode engine (:func:`~proxybench.runner.rollout.rollout`, the ``Plant`` protocol), like
:class:`~proxybench.runner.robot_episode.RobotPlant` for robot nodes. A DTPS robot runs on its own clock,
so the plant runs in real time: frame k is the newest camera frame at T0 + k/rate (T0: when the agent gave
its first command, so that an agent loading for a while does not eat the episode), the agent's command is
published at once and held until T0 + (k+1)/rate, and the newest pose then is the trajectory's sample
(t = (k+1)/rate). Frames the agent answered too late to keep that pace are counted (``late_frames``, with the
worst lag ``max_lag_s``), and a run falling behind says so on stderr (:class:`~proxybench.dtps.lateness.Lateness`:
rate-limited, once per episode and when it gets worse).

Each episode starts by the options' reset mode (:class:`~proxybench.dtps.robot_options.DtpsRobotOptions`):
an operator prompt, ``state/reset``, or a start pose recorded beforehand; the trajectory starts where the
robot then *is* (its pose source says so), and the start asked for is kept in the metadata beside it.
proxybench applies its own ending rule to the pose: off the road (the robot centre left the drivable
area) ends the episode as in simulation. Collisions are not detected (a robot's bumps are not reported).
A privileged agent is refused: a DTPS robot gives no true lane pose.

The robot hears (0, 0) whenever an episode ends, fails or is aborted, and from the bridge's watchdog when
commands stop coming; a lost connection ends the episode as a ``connection-lost`` robot failure.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from proxybench.agents.base import Observation
from proxybench.domain.events import Event, Termination
from proxybench.domain.lane_pose import point_on_road
from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import Map, load_map
from proxybench.domain.simulator import start_pose
from proxybench.dtps.lateness import Lateness
from proxybench.dtps.operator import Operator, PlaceRequest, TerminalOperator
from proxybench.dtps.robot_link import TICKS_PER_TURN, DtpsRobotLink
from proxybench.dtps.robot_options import DtpsAddress, DtpsRobotOptions
from proxybench.protocol import jpeg
from proxybench.protocol.failures import RobotFailure
from proxybench.runner.robot_episode import RobotLacksGroundTruth

__all__ = ["DtpsPlant", "DtpsRobot"]

_SETTLE_S = 0.3  # [s] after a reset or a placement: the pose must be newer than this


class DtpsRobot:
    """The DTPS robot at ``address`` driven at ``frame_rate`` [Hz] with ``options``; ``operator``: who answers
    the reset prompt (default: the terminal, or ``options.reset_input``). Close it to end the bridge (the robot
    is sent (0, 0), delivered within ``stop_grace`` if the connection comes back)."""

    def __init__(self, address: DtpsAddress, options: DtpsRobotOptions, frame_rate: float, *,
                 operator: Operator | None = None, python: str | None = None):
        self.address, self.options, self.frame_rate = address, options, float(frame_rate)
        self._operator = operator
        self.link = DtpsRobotLink(address, options, python=python)
        self.link.wait_for("pose", -1.0, time.monotonic() + options.start_timeout, "its first pose")

    @property
    def operator(self) -> Operator:
        if self._operator is None:
            self._operator = TerminalOperator(self.options.reset_input)
        return self._operator

    def plant(self, map_: Map | str) -> DtpsPlant:
        return DtpsPlant(self, map_)

    def close(self) -> bool | None:
        """End the bridge; whether its final (0, 0) was delivered (None: it could not say)."""
        if self._operator is not None:
            self._operator.close()
        return self.link.close()

    def __enter__(self) -> DtpsRobot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------------------------ resets
    def start_at(self, requested: tuple[float, float, float] | None, seed: int, m: Map) -> tuple[float, float, float]:
        """Put the robot at the episode's start by the reset mode; where it then stands."""
        link, o = self.link, self.options
        link.stop()
        deadline = time.monotonic() + o.reset_timeout
        if o.reset == "teleport":
            asked = time.monotonic()
            link.reset(deadline)
            time.sleep(_SETTLE_S)
            link.wait_for("pose", asked + _SETTLE_S, deadline, "after state/reset")
            return link.pose  # type: ignore[return-value]
        if requested is None:
            if o.reset == "pose-file":
                raise ValueError("reset pose-file: the episode has no start pose (give the job the file's pose)")
            requested = start_pose(m, seed)
        note = ""
        while True:
            if o.reset == "prompt":
                tile = (math.floor(requested[0] / m.tile_size), math.floor(requested[1] / m.tile_size))
                self.operator.place(PlaceRequest(str(self.address), requested, link.pose, seed, tile, note), deadline)
            asked = time.monotonic()
            link.wait_for("pose", asked, deadline, "its pose at the start")
            off = _distance(link.pose, requested)
            if off[0] <= o.pose_tolerance[0] and off[1] <= o.pose_tolerance[1]:
                return link.pose  # type: ignore[return-value]
            note = f"It stands {off[0]:.3f} m and {math.degrees(off[1]):.1f}° from the start."
            if time.monotonic() > deadline:
                raise RobotFailure("aborted", f"the DTPS robot {self.address} did not reach its start pose within "
                                              f"{o.reset_timeout:g} s ({note})")
            if o.reset == "pose-file":
                link.pump(time.monotonic() + 0.1)


def _distance(a: Sequence[float] | None, b: Sequence[float]) -> tuple[float, float]:
    if a is None:
        return math.inf, math.inf
    return math.hypot(a[0] - b[0], a[1] - b[1]), abs(math.remainder(a[2] - b[2], 2 * math.pi))


class DtpsPlant:
    """One DTPS robot as a plant of one robot on ``map_`` (see the module docstring)."""

    n = 1

    def __init__(self, robot: DtpsRobot, map_: Map | str):
        self.robot = robot
        self.map = load_map(map_) if isinstance(map_, str) else map_
        self._arrays = a = LaneNetwork(self.map).arrays
        point_on_road(0.0, 0.0, a.tile_kind, a.curve_corner, a.tile_size)  # compiled now, not in the first frame
        self.k = 0
        self.rows: list[list[float]] = []
        self.info: dict[str, Any] = {}
        #: how far the episode fell behind the robot's clock (a robot cannot be stepped: no lock-step to offer)
        self.lateness = Lateness(warn=self._late, cause="the agent's commands or the robot's link come slower "
                                 "than the camera's rate", hint="a busy machine or a weak network stretches the "
                                 "episode in wall time while the robot keeps moving")

    def _late(self, message: str) -> None:
        print(f"[dtps:{self.robot.address}] warning: {message}", file=sys.stderr, flush=True)

    @property
    def frame_rate(self) -> float:
        return self.robot.frame_rate

    def begin(self, seeds: Sequence[int], poses: Sequence[Any], routes: Sequence[Any], seconds: float,
              camera: bool, privileged: Sequence[bool]) -> int:
        if privileged[0]:
            raise RobotLacksGroundTruth(f"the DTPS robot {self.robot.address} reports no true lane pose")
        link = self.robot.link
        requested = None if poses[0] is None else tuple(float(v) for v in poses[0])
        start = self.robot.start_at(requested, int(seeds[0]), self.map)  # type: ignore[arg-type]
        self.camera = camera
        if camera:
            link.wait_for("camera", -1.0, time.monotonic() + self.robot.options.stale_timeout, "a camera frame")
        self.steps = max(1, round(seconds * self.frame_rate))
        self.k = 0
        self.lateness.begin()
        self.rows = [[0.0, *start, 0.0, 0.0, 0.0, 0.0]]
        self.info = {"start_requested": None if requested is None else list(requested), "start": list(start)}
        self._watchdogs = link.watchdogs
        self.t0: float | None = None  # the clock starts with the agent's first command (it may load for a while)
        return self.steps

    def encoded_frame(self, i: int) -> bytes | None:
        return self.robot.link.camera if self.camera else None

    def frames(self, alive: np.ndarray) -> list[np.ndarray | None] | None:
        if not self.camera:
            return None
        data = self.robot.link.camera
        try:
            return [jpeg.decode_received(data)] if data else [None]
        except Exception as exc:  # a JPEG the decoder refuses
            self.robot.link.stop()
            raise RobotFailure("bad-data", f"the DTPS robot {self.robot.address} sent a camera frame that is not a "
                                           f"JPEG: {exc}") from None

    def observation(self, i: int, image: np.ndarray | None, privileged: bool) -> Observation:
        return Observation(image, self.time(0), self.robot.link.odometry, 2 * math.pi / TICKS_PER_TURN)

    def time(self, i: int) -> float:
        return self.k / self.frame_rate

    def advance(self, commands: np.ndarray, alive: np.ndarray, k: int) -> list[tuple[int, Event, bool]]:
        link = self.robot.link
        left, right = (float(v) for v in np.clip(commands[0], -1.0, 1.0))
        link.command(left, right)
        if self.t0 is None:
            self.t0 = time.monotonic() - k / self.frame_rate
        due = self.t0 + (k + 1) / self.frame_rate
        self.lateness.frame(time.monotonic() - (due - 1 / self.frame_rate), 1 / self.frame_rate)
        link.pump(due)
        link.check_fresh(self.camera)
        self.k = k + 1
        t = self.k / self.frame_rate
        x, y, th = link.pose  # type: ignore[misc]
        px, py, pth = self.rows[-1][1:4]
        dt = t - self.rows[-1][0]
        v = math.hypot(x - px, y - py) / dt * (1.0 if math.cos(math.atan2(y - py, x - px) - pth) >= 0 else -1.0)
        self.rows.append([t, x, y, th, v, math.remainder(th - pth, 2 * math.pi) / dt, left, right])
        a = self._arrays
        if not point_on_road(x, y, a.tile_kind, a.curve_corner, a.tile_size):
            link.stop()
            return [(0, Event(t, Termination.OFF_ROAD, "the robot centre left the drivable area (its reported pose)"),
                     True)]
        return []

    def samples(self, i: int, frames: int) -> np.ndarray:
        return np.asarray(self.rows[: frames + 1], dtype=np.float64)

    def route_lanes(self, i: int, frames: int) -> None:
        return None

    def meta(self, i: int) -> dict[str, Any]:
        r, o = self.robot, self.robot.options
        said = {"real": "the user says: a real robot", "simulated": "the user says: a simulated robot"}
        return {"source": "dtps-robot", "params": None,
                "robot": {"command": f"dtps:{r.address}", "address": str(r.address), "link": "dtps",
                          "kind": o.kind or "", "said": said.get(o.kind or "", "not told (proxybench cannot tell "
                                                                               "a Duckiematrix robot from a real one)"),
                          "pose_source": o.pose if not o.pose_url else f"{o.pose_url} {o.pose}", "pwm": o.pwm,
                          "reset": o.reset, **self.info, "late_frames": self.lateness.late,
                          "max_lag_s": self.lateness.worst,
                          "watchdogs": r.link.watchdogs - getattr(self, "_watchdogs", 0)}}

    def wheel_distance(self, i: int) -> float:
        return self.robot.options.wheel_distance

    def end(self) -> None:
        self.robot.link.stop()
