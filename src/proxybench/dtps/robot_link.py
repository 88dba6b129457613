"""proxybench's end of a DTPS robot: the bridge in its ``client`` role, and what the robot last said.

The robot publishes on its own clock (camera, encoders, pose); :meth:`DtpsRobotLink.pump` takes what
arrived and keeps the latest of each with its arrival time, so the plant reads "the newest camera frame"
and "the newest pose" whenever it needs them. Everything that goes wrong is a
:class:`~proxybench.protocol.RobotFailure` naming the robot: the bridge cannot start or dies (``start-failed``,
``exited``), the robot sends something unreadable (``bad-data``), or its camera, pose or command link
goes silent for ``stale_timeout`` (``connection-lost``). The robot is sent (0, 0) before any of them is
raised, and the bridge keeps trying to deliver that (0, 0) when it is closed.
"""

from __future__ import annotations

import contextlib
import math
import time
from typing import Any

from proxybench.dtps.link import BridgeError, BridgeLink
from proxybench.dtps.robot_options import DtpsAddress, DtpsRobotOptions
from proxybench.protocol.failures import RobotFailure

__all__ = ["TICKS_PER_TURN", "DtpsRobotLink"]

TICKS_PER_TURN = 135  # a DB21's wheel encoders (duckietown-sdk's DTPSWheelEncoderDriver.RESOLUTION)


class DtpsRobotLink:
    """A connection to the DTPS robot at ``address`` through a bridge process (``python``: the SDK environment's
    interpreter; None: the one ``proxybench dtps setup`` made)."""

    def __init__(self, address: DtpsAddress, options: DtpsRobotOptions, *, python: str | None = None):
        self.address, self.options = address, options
        args = ["client", "--url", address.url, "--name", address.path, "--pwm", options.pwm, "--pose", options.pose,
                "--watchdog", f"{options.watchdog:g}", "--stop-grace", f"{options.stop_grace:g}"]
        if options.pose_url:
            args += ["--pose-url", options.pose_url]
        try:
            self.link = BridgeLink(args, python=python, start_timeout=options.start_timeout)
        except BridgeError as exc:
            raise RobotFailure("start-failed", f"the DTPS bridge to {address} did not start: {exc.detail}",
                               exc.exit_code, exc.stderr_tail) from None
        self.camera: bytes | None = None
        self.pose: tuple[float, float, float] | None = None
        self.ticks: list[int | None] = [None, None]
        self.seen: dict[str, float] = {}  # kind → monotonic time of its latest message
        self.link_lost_since: float | None = None
        self.watchdogs = 0
        self.link_events: list[str] = []
        self.stopped: dict[str, Any] | None = None

    # ------------------------------------------------------------------------------- receiving
    def pump(self, deadline: float) -> None:
        """Take what the robot sent until ``deadline`` (monotonic)."""
        try:
            self.link.drain(deadline, self._event)
        except BridgeError as exc:
            raise RobotFailure("exited", f"the DTPS bridge to {self.address} ended: {exc.detail}", exc.exit_code,
                               exc.stderr_tail) from None

    def _event(self, ev: dict[str, Any]) -> None:
        kind, now = ev.get("ev"), time.monotonic()
        if kind == "camera" and isinstance(ev.get("jpeg"), bytes):
            self.camera = ev["jpeg"]
        elif kind == "pose":
            self.pose = _pose(ev.get("pose"), self.address)
        elif kind == "ticks" and ev.get("side") in ("left", "right") and isinstance(ev.get("ticks"), int):
            self.ticks[0 if ev["side"] == "left" else 1] = ev["ticks"]
        elif kind == "bad":
            self.stop()
            raise RobotFailure("bad-data", f"the DTPS robot {self.address} sent an unreadable {ev.get('topic')} "
                                           f"message: {ev.get('detail')}")
        elif kind == "link":
            self.link_lost_since = None if ev.get("state") == "ok" else (self.link_lost_since or now)
            self.link_events.append(f"{ev.get('state')}: {ev.get('detail')}")
            del self.link_events[:-20]
        elif kind == "watchdog":
            self.watchdogs += 1
        elif kind == "stopped":
            self.stopped = ev
        if isinstance(kind, str):  # when the bridge heard it: a stall of ours is not the robot's silence
            wall = ev.get("wall")
            lag = time.time() - wall if isinstance(wall, float) else 0.0
            self.seen[kind] = now - min(max(lag, 0.0), 60.0)

    def wait_for(self, kind: str, after: float, deadline: float, what: str) -> None:
        """Pump until a ``kind`` message newer than ``after`` (monotonic) arrived; ``connection-lost`` at the
        deadline, saying ``what`` was awaited."""
        while self.seen.get(kind, -1.0) <= after:
            if time.monotonic() >= deadline:
                self.stop()
                raise RobotFailure("connection-lost", f"no {kind} from the DTPS robot {self.address} "
                                                      f"({what}) in {deadline - after:.1f} s")
            self.pump(min(deadline, time.monotonic() + 0.05))

    def check_fresh(self, camera: bool) -> None:
        """``connection-lost`` when the pose (and, with ``camera``, the camera) or the command link have been
        silent for longer than ``stale_timeout``."""
        now, limit = time.monotonic(), self.options.stale_timeout
        for kind in ("pose", "camera") if camera else ("pose",):
            silent = now - self.seen.get(kind, -float("inf"))
            if silent > limit:
                self.stop()
                raise RobotFailure("connection-lost", f"no {kind} from the DTPS robot {self.address} for "
                                                      f"{min(silent, 1e6):.1f} s (more than {limit:g} s): "
                                                      "connection lost?")
        if self.link_lost_since is not None and now - self.link_lost_since > limit:
            self.stop()
            raise RobotFailure("connection-lost", f"the command publisher has not reached the DTPS robot "
                                                  f"{self.address} for {now - self.link_lost_since:.1f} s ("
                                                  f"{self.link_events[-1] if self.link_events else 'no detail'})")

    @property
    def odometry(self) -> tuple[float, float] | None:
        """(left, right) wheel angles [rad] from the latest encoder ticks."""
        if None in self.ticks:
            return None
        return tuple(t * 2 * math.pi / TICKS_PER_TURN for t in self.ticks)  # type: ignore[return-value]

    # --------------------------------------------------------------------------------- sending
    def command(self, left: float, right: float) -> None:
        self._send(op="cmd", left=float(left), right=float(right))

    def stop(self) -> None:
        """(0, 0) now (no error if the bridge is gone: it sends (0, 0) on its own way out)."""
        with contextlib.suppress(RobotFailure):
            self._send(op="stop")

    def reset(self, deadline: float) -> None:
        """Publish ``state/reset``; ``connection-lost`` if it could not be delivered."""
        self._send(op="reset")
        while True:
            self.pump(min(deadline, time.monotonic() + 0.05))
            if self.seen.get("reset-sent", -1.0) > self.seen.get("reset-asked", -1.0):
                return
            if self.seen.get("reset-failed", -1.0) > self.seen.get("reset-asked", -1.0) or time.monotonic() > deadline:
                raise RobotFailure("connection-lost", f"could not publish state/reset to the DTPS robot {self.address}")

    def _send(self, **message: Any) -> None:
        if message.get("op") == "reset":
            self.seen["reset-asked"] = time.monotonic()
        try:
            self.link.send(**message)
        except BridgeError as exc:
            raise RobotFailure("exited", f"the DTPS bridge to {self.address} ended: {exc.detail}", exc.exit_code,
                               exc.stderr_tail) from None

    def close(self) -> bool | None:
        """End the bridge: it sends (0, 0) and tries for ``stop_grace`` s to deliver it. Whether it was delivered
        (None: the bridge could not say)."""
        try:
            self.link.send(op="quit")
            self.stopped = self.link.wait_for("stopped", time.monotonic() + self.options.stop_grace + 5.0)
        except BridgeError:
            pass
        self.link.close(timeout=2.0)
        return None if self.stopped is None else bool(self.stopped.get("delivered"))


def _pose(value: Any, address: DtpsAddress) -> tuple[float, float, float]:
    ok = isinstance(value, list) and len(value) == 3 and all(isinstance(v, float | int) for v in value)
    if not ok or not all(v == v and abs(v) < 1e6 for v in value):
        raise RobotFailure("bad-data", f"the DTPS robot {address} sent the pose {value!r}, not (x, y, θ)")
    return (float(value[0]), float(value[1]), float(value[2]))
