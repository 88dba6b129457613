"""Frames out, wheel commands in: a virtual DB21J as an :class:`~proxybench.agents.base.Agent` (real time or lock-step).

Per frame the runner calls ``act(obs)``; the driver publishes the frame on the virtual robot and returns the
wheel command in force, by one of two clocks:

``realtime``  what SDK agents expect of a robot: frame k is published at wall time T0 + t_k and the command
              held over frame k is the latest that arrived before T0 + t_{k+1} (T0: when the first command
              came). The agent's own latency therefore shows in the run, and runs differ from one another
              by how the machine schedules two processes: *not reproducible* sample for sample. As with the
              Duckiematrix, a blocking ``capture(); set_pwm()`` agent's command goes out with the next frame.
              When the simulation cannot keep up, frames come late (counted in ``late_frames``; ``warn``
              hears when the run falls behind: :class:`~.lateness.Lateness`).
``lockstep``  frame k+1 is published only after a command answering frame k has arrived, and that command
              is held over frame k: the same agent gives the same trajectory every run, *if* it answers every
              camera frame with exactly one command (a camera callback, or a ``capture(block=True)`` loop);
              commands beyond one per frame are counted (``extra_commands``) because they make a run depend
              on timing again. Runs as fast as the agent answers.

Failures are the node agents' taxonomy (:data:`~proxybench.protocol.failures.REASONS`): no first command in
``start_timeout`` → ``init-timeout``; none for ``step_timeout`` (real time) or no answer to a frame
(lock-step) → ``step-timeout``; a command that is not two finite numbers in [-1, 1] or not a
DifferentialPWM → ``bad-commands``; more than ``max_commands`` in one frame → ``stdout-flood``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.dtps.lateness import Lateness
from proxybench.dtps.virtual_robot import VirtualDB21J
from proxybench.protocol.failures import AgentFailure

__all__ = ["RobotDriver"]

_SLICE = 0.05  # [s] the longest wait before the driver looks at the agent's process again


class RobotDriver(Agent):
    """Drives the rollout from the commands an SDK agent sends to ``robot`` (see the module docstring)."""

    #: whether an answer to an episode's first frame counts in ``frames_answered`` (not where that frame waits
    #: for the program's start: its wait is ``start_s``)
    start_frame_counts = False

    def __init__(self, robot: VirtualDB21J | None, *, timing: str = "realtime", start_timeout: float = 60.0,
                 step_timeout: float = 5.0, max_commands: int = 30, warn: Callable[[str], None] | None = None,
                 hint: str = ""):
        if timing not in ("realtime", "lockstep"):
            raise ValueError(f"timing must be 'realtime' or 'lockstep', not {timing!r}")
        self.robot = robot
        self.timing, self.start_timeout, self.step_timeout = timing, start_timeout, step_timeout
        self.max_commands = max_commands
        self.latencies: list[float] = []
        #: real time: how far the run fell behind the wall clock; ``warn`` hears it, ending with ``hint``
        self.lateness = Lateness(warn=warn, hint=hint)
        self._begin()

    def _begin(self) -> None:
        self.command = np.zeros(2)
        self.t0: float | None = None
        self.prev_time: float | None = None
        self.first_seq: int | None = None
        self.last_command_wall = 0.0
        self.extra_commands = self.resets = self.frames = 0
        self.start_s = 0.0
        self.latencies = []
        self.answered: set[int] = set()  # the frames a command answered, whenever it came (late ones too)
        self.lateness.begin()

    @property
    def late_frames(self) -> int:
        return self.lateness.late

    @property
    def max_lag(self) -> float:
        return self.lateness.worst

    def reset(self, seed: int, episode: str | None = None) -> None:
        self._begin()

    # ---------------------------------------------------------------------------------- the frame
    def act(self, obs: Observation) -> np.ndarray:
        dt = None if self.prev_time is None else obs.time - self.prev_time
        self.prev_time = obs.time
        if self.timing == "realtime" and self.t0 is not None:  # wait for this frame's slot
            self._collect(None, self.t0 + obs.time)
        published = time.monotonic()
        # the first frame waits for the program to start and answer: nudged in either timing, else a blocking
        # agent's first command would wait for a second frame that never comes
        seq = self.robot.publish(obs, dt=dt, nudge=self.timing == "lockstep" or self.t0 is None)
        self.frames += 1
        if self.first_seq is None:
            self.first_seq = seq
        if self.t0 is None or self.timing == "lockstep":
            timeout = self.start_timeout if self.t0 is None else self.step_timeout
            answered = self._collect(seq, published + timeout)
            if answered is None:
                self._no_answer(seq, timeout)
            if self.t0 is None:  # the first answer came after the program's start: not a latency
                self.start_s = answered - published
                self.t0 = time.monotonic() - obs.time
            else:
                self.latencies.append(answered - published)
            return self.command.copy()
        self.lateness.frame(published - (self.t0 + obs.time), dt)
        answered = self._collect(seq, self.t0 + obs.time + (dt or 0.0))
        if answered is not None:
            self.latencies.append(answered - published)
        if time.monotonic() - self.last_command_wall > self.step_timeout:
            raise self._failure("step-timeout", f"the SDK agent sent no wheel command for {self.step_timeout:g} s "
                                                f"(it stopped publishing)")
        return self.command.copy()

    def _no_answer(self, seq: int, timeout: float) -> None:
        if seq == self.first_seq:
            raise self._failure("init-timeout", f"no wheel command within {timeout:g} s of the first camera frame: "
                                                f"did the agent start and reach {self.robot.url}?")
        raise self._failure("step-timeout", f"no wheel command answered camera frame {seq - self.first_seq} within "
                                            f"{timeout:g} s (lock-step)")

    def _collect(self, seq: int | None, deadline: float) -> float | None:
        """Take events until ``deadline``; with ``seq``, return as soon as a command answers that frame (the
        monotonic time it came), else None. Real time: wait out the deadline either way (after the answer)."""
        answered = None
        while True:
            now = time.monotonic()
            for ev in self.robot.events(min(deadline, now + _SLICE)):
                got = self._event(ev, seq)
                if got and answered is None:
                    answered = time.monotonic()
            self._watch()
            if answered is not None and (self.timing == "lockstep" or self.t0 is None):
                return answered
            if time.monotonic() >= deadline:
                return answered

    def _event(self, ev: dict[str, Any], seq: int | None) -> bool:
        """Handle one bridge event; True when it is a command answering frame ``seq``."""
        kind = ev.get("ev")
        if kind == "bad":
            raise self._failure("bad-commands", f"on {ev.get('topic')}: {ev.get('detail')}")
        if kind == "reset":
            self.resets += 1
            return False
        if kind != "cmd":
            return False
        left, right = ev.get("left"), ev.get("right")
        if not all(isinstance(v, float) and math.isfinite(v) and -1.0 <= v <= 1.0 for v in (left, right)):
            raise self._failure("bad-commands", f"wheel command ({left!r}, {right!r}) on {ev.get('topic')}: "
                                                f"expected two finite PWM values in [-1, 1]")
        if isinstance(ev.get("n"), int) and ev["n"] > self.max_commands:
            raise self._failure("stdout-flood", f"more than {self.max_commands} wheel commands during one camera "
                                                f"frame")
        cmd_seq = ev.get("seq") if isinstance(ev.get("seq"), int) else -1
        if self.first_seq is not None and cmd_seq < self.first_seq:
            return False  # an answer to a frame of an earlier episode
        self.command = np.array([left, right])
        self.last_command_wall = time.monotonic()
        if cmd_seq <= self.robot.seq and (cmd_seq != self.first_seq or self.start_frame_counts):
            self.answered.add(cmd_seq)
        if seq is not None and cmd_seq >= seq:
            return True
        if self.timing == "lockstep":
            self.extra_commands += 1
        return False

    # ------------------------------------------------------------------------------ hooks
    def _watch(self) -> None:
        """Called between waits: raise a failure when the agent's side is gone (an SDK agent's process)."""

    def _failure(self, reason: str, detail: str) -> AgentFailure:
        return AgentFailure(reason, detail)

    def stats(self) -> dict[str, Any]:
        """Timing of the episode so far: frames published and answered (by a command naming the frame, whenever
        it came: a late plant's answers arrive after their frame's slot), frame → command latencies [s] (of the
        answers that came within their frame), late frames, worst lag, extra commands, resets."""
        lat = np.array(self.latencies) if self.latencies else np.zeros(0)
        return {"timing": self.timing, "start_s": self.start_s, "frames": self.frames,
                "frames_answered": len(self.answered), "frames_answered_in_time": int(lat.size),
                "latency_median_ms": float(np.median(lat) * 1e3) if lat.size else None,
                "latency_p90_ms": float(np.percentile(lat, 90) * 1e3) if lat.size else None,
                "late_frames": self.late_frames, "max_lag_s": self.max_lag, "behind": self.lateness.behind(),
                "extra_commands": self.extra_commands, "resets": self.resets}
