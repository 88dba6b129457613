"""A DTPS robot watched while someone else drives it: the record an Autolab keeps of a real robot's episode.

In an Autolab the agent (an SDK program in the sandbox) speaks to the lab's DTPS robot itself; the evaluator only
listens. :class:`RobotObserver` runs the bridge in its ``client`` role with ``--observe``: it forwards every wheel
command published on the robot's command topics (``actuator/wheels/base/pwm`` and ``pwm_filtered``: the agent's)
and the pose the robot reports (``state/pose``, if it has one), each with the wall-clock time the bridge heard it,
and publishes nothing until told to :meth:`stop` the robot ((0, 0), after an episode; and again when closed).

What the robot sends is a stranger's input: a command or pose that is not numbers is counted, never recorded.
A bridge that ends is a :class:`~proxybench.protocol.RobotFailure` naming the robot.
"""

from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass, field
from typing import Any

from proxybench.dtps.link import BridgeError, BridgeLink
from proxybench.dtps.robot_options import DtpsAddress
from proxybench.protocol.failures import RobotFailure

__all__ = ["Observed", "RobotObserver"]

#: at most this many commands and poses are kept per episode (a robot at 100 Hz for 1 h)
MAX_RECORDS = 360_000


@dataclass
class Observed:
    """What the observer heard: commands ``(wall, left, right)`` and poses ``(wall, x, y, θ)``, bad messages."""

    commands: list[tuple[float, float, float]] = field(default_factory=list)
    poses: list[tuple[float, float, float, float]] = field(default_factory=list)
    bad: int = 0
    first_problem: str | None = None

    def since(self, wall: float) -> Observed:
        """The part heard at or after ``wall``."""
        return Observed([c for c in self.commands if c[0] >= wall], [p for p in self.poses if p[0] >= wall],
                        self.bad, self.first_problem)


class RobotObserver:
    """Listens to the DTPS robot at ``address`` (see the module); ``python``: the SDK environment's interpreter."""

    def __init__(self, address: DtpsAddress, *, pose: str = "state/pose", python: str | None = None,
                 start_timeout: float = 60.0, stop_grace: float = 3.0):
        self.address = address
        args = ["client", "--url", address.url, "--name", address.path, "--observe", "--pose", pose,
                "--watchdog", "1e9", "--stop-grace", f"{stop_grace:g}"]
        try:
            self.link = BridgeLink(args, python=python, start_timeout=start_timeout)
        except BridgeError as exc:
            raise RobotFailure("start-failed", f"cannot listen to the DTPS robot {address}: {exc.detail}",
                               exc.exit_code, exc.stderr_tail) from None
        self.heard = Observed()
        self.stop_grace = stop_grace

    def pump(self, deadline: float) -> None:
        """Take what the bridge heard until ``deadline`` (monotonic)."""
        try:
            self.link.drain(deadline, self._event)
        except BridgeError as exc:
            raise RobotFailure("exited", f"the DTPS link to the robot {self.address} ended: {exc.detail}",
                               exc.exit_code, exc.stderr_tail) from None

    def _event(self, ev: dict[str, Any]) -> None:
        kind, wall = ev.get("ev"), ev.get("wall")
        if kind not in ("command", "pose", "bad") or not isinstance(wall, float):
            return
        h = self.heard
        try:
            if kind == "bad":
                raise ValueError(f"an unreadable {ev.get('topic')} message: {ev.get('detail')}")
            if kind == "command":
                values = (float(ev["left"]), float(ev["right"]))
            else:
                pose = ev.get("pose")
                if not (isinstance(pose, list) and len(pose) == 3):
                    raise ValueError(f"a pose {str(pose)[:80]!r}, not (x, y, θ)")
                values = tuple(float(v) for v in pose)
            if not all(math.isfinite(v) and abs(v) < 1e6 for v in values):
                raise ValueError(f"a {kind} of values out of range {values!r}")
        except (KeyError, TypeError, ValueError) as exc:
            h.bad += 1
            h.first_problem = h.first_problem or " ".join(str(exc).split())[:300]
            return
        if len(h.commands) + len(h.poses) >= MAX_RECORDS:
            return
        if kind == "command":
            h.commands.append((wall, *values))
        else:
            h.poses.append((wall, *values))

    def take(self) -> Observed:
        """What was heard since the last :meth:`take` (pumped first)."""
        self.pump(time.monotonic())
        heard, self.heard = self.heard, Observed()
        return heard

    @property
    def alive(self) -> bool:
        return self.link.alive

    def stop(self) -> None:
        """Publish (0, 0) on the robot's command topic (the agent is gone; the robot must not drive on)."""
        with contextlib.suppress(BridgeError):
            self.link.send(op="stop")

    def close(self) -> None:
        """End the bridge: it publishes (0, 0) and tries for ``stop_grace`` s to deliver it."""
        try:
            self.link.send(op="quit")
            self.link.wait_for("stopped", time.monotonic() + self.stop_grace + 5.0)
        except BridgeError:
            pass
        self.link.close(timeout=2.0)
