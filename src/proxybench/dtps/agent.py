"""An unchanged duckietown-sdk agent program as an :class:`~proxybench.agents.base.Agent`.

Like :class:`~proxybench.protocol.RemoteAgent` for AIDO nodes, :class:`SdkAgent` runs anywhere an agent
goes. Behind it: a virtual DB21J (:class:`~.virtual_robot.VirtualDB21J`: the bridge serving
``http://127.0.0.1:7501/robot/map_0/vehicle_0/…`` and the map layer) and the user's program, started
afresh for every episode (nothing it learnt carries over, as with a restarted robot) with the SDK
environment's ``bin`` first on its ``PATH``, so ``python3 agent.py`` runs it with duckietown-sdk. The
program is unchanged: ``DB21J("map_0/vehicle_0", simulated=True)`` finds the virtual robot where the
Duckiematrix would be. Timing and failures: :mod:`.driver`. Its own process group is killed at the end of
each episode and on any failure (with its exit status and last output lines in the failure).
"""

from __future__ import annotations

import os
import shlex
import sys
from pathlib import Path

from proxybench.domain.maps import Map
from proxybench.dtps.driver import RobotDriver
from proxybench.dtps.env import env_path, sdk_python
from proxybench.dtps.link import BridgeError
from proxybench.dtps.options import SdkOptions
from proxybench.dtps.virtual_robot import VirtualDB21J
from proxybench.protocol.failures import AgentFailure, NodeFailure, RobotFailure
from proxybench.protocol.transport import Launch, node_argv

__all__ = ["NETNS_ENV", "SdkAgent"]

#: where the program (the evaluator's sandbox shim) finds the virtual robot's network namespace
NETNS_ENV = "PROXYBENCH_DTPS_NETNS"

_GRACE = {"exited": 1.0}


def _label(command: str) -> str:
    words = [w for w in shlex.split(command, posix=True) if not w.startswith("-")] if command else []
    return "sdk:" + (Path(words[-1]).stem if words else "agent")


class SdkAgent(RobotDriver):
    #: a privileged SDK agent still drives by its camera (and reads the true pose beside it)
    wants_camera = True

    """The program ``command`` (as typed in a shell) driving a virtual DB21J; ``options``: :class:`SdkOptions`.

    :class:`~proxybench.dtps.env.DtpsEnvError` at construction when the SDK environment is missing (a problem
    of this host, not of the agent). Everything the program does wrong is an
    :class:`~proxybench.protocol.AgentFailure` from ``reset`` / ``act``, which the runner records; a virtual
    robot whose bridge dies mid-episode is a :class:`~proxybench.protocol.RobotFailure` (the lab's fault, not the
    agent's), whatever the program did after it lost its robot.
    """

    #: a privileged SDK agent still drives by its camera (it reads the true pose beside it)
    wants_camera = True

    def __init__(self, command: str, *, name: str | None = None, options: SdkOptions | None = None,
                 env_dir: str | None = None, max_stderr_bytes: int = 4 << 20):
        self.options = options or SdkOptions()
        self.python = sdk_python(env_dir)  # fails early and clearly on a host without the SDK environment
        self.bin = str(env_path(env_dir) / "bin")
        super().__init__(None, timing=self.options.timing, start_timeout=self.options.start_timeout,
                         step_timeout=self.options.step_timeout)
        self.cmd = command
        self.name = name or _label(command)
        if self.options.timing == "realtime":  # say when the simulation cannot keep the camera's rate
            self.lateness.warn = self._late
            self.lateness.hint = ("for a run that does not depend on this machine's speed, step the agent in "
                                  f"lock-step: --agent \"NAME=sdk[lockstep]:{command}\" (docs/dtps.md)")
        self.privileged = self.options.privileged
        self.max_stderr_bytes = max_stderr_bytes
        self.proc: Launch | None = None
        self.failure: NodeFailure | None = None
        self._map: Map | None = None

    def _robot(self) -> VirtualDB21J:
        if self.robot is not None and not self.robot.alive:  # it died in an earlier episode: a fresh one
            self.robot.close()
            self.robot = None
        if self.robot is None:
            try:
                self.robot = VirtualDB21J(python=str(self.python), start_timeout=self.options.start_timeout,
                                          own_netns=self.options.own_netns)
            except BridgeError as exc:
                raise AgentFailure("start-failed", f"the virtual DB21J (DTPS bridge) did not start: {exc.detail}",
                                   exc.exit_code, exc.stderr_tail) from None
            if self._map is not None:
                self.robot.publish_map(self._map)
        return self.robot

    def set_map(self, map_: Map) -> None:
        self._map = map_
        if self.robot is not None:
            self.robot.publish_map(map_)

    def reset(self, seed: int, episode: str | None = None) -> None:
        self._stop_program()
        super().reset(seed, episode)
        self.failure = None
        robot = self._robot()
        robot.drain()
        env = {"PATH": self.bin + os.pathsep + os.environ.get("PATH", "/usr/bin:/bin"), "PYTHONUNBUFFERED": "1",
               "PROXYBENCH_EPISODE_SEED": str(int(seed))}
        if robot.netns is not None:  # the sandbox joins the robot's network namespace
            env[NETNS_ENV] = robot.netns
        cwd = self.options.cwd
        if cwd is not None and not os.path.isdir(cwd):
            raise AgentFailure("start-failed", f"cannot start {self.cmd!r}: working directory {cwd!r} does not exist")
        try:
            self.proc = Launch(node_argv(self.cmd), transport="none", env=env, cwd=cwd, stderr_lines=50)
        except (OSError, ValueError) as exc:
            raise AgentFailure("start-failed", f"cannot start {self.cmd!r}: {exc}") from None

    def act(self, obs):
        if self.failure is not None:
            raise self.failure
        if self.proc is None:
            raise AgentFailure("start-failed", "act() before reset(): the SDK agent program was not started")
        self._stderr_mark = self.proc.stderr.total_bytes
        try:
            return super().act(obs)
        except BridgeError as exc:
            failure = self._failure("exited", f"the virtual DB21J (DTPS bridge) failed: {exc.detail}")
            if isinstance(failure, AgentFailure):  # the bridge answered wrongly yet runs: still the robot's
                failure = self.failure = RobotFailure("exited", f"the virtual DB21J (DTPS bridge) failed: "
                                                                f"{exc.detail}", exc.exit_code, exc.stderr_tail)
            raise failure from None

    def _late(self, message: str) -> None:
        print(f"[{self.name}] warning: {message}", file=sys.stderr, flush=True)

    # ------------------------------------------------------------------------------ the program
    def _watch(self) -> None:
        proc = self.proc
        if proc is None:
            return
        if proc.exited():
            raise self._failure("exited", "the SDK agent program ended")
        if proc.stderr.total_bytes - getattr(self, "_stderr_mark", 0) > self.max_stderr_bytes:
            raise self._failure("stderr-flood", f"more than {self.max_stderr_bytes} bytes of output during one frame")

    def _failure(self, reason: str, detail: str) -> NodeFailure:
        """Kill the program's process group (letting one that is ending finish), then the failure to raise: the
        robot's (:class:`RobotFailure`) when its bridge has died, whatever the program did after (lost its robot,
        exited, stopped answering), else the agent's."""
        proc = self.proc
        dead = self._dead_robot()
        if proc is None:
            return dead or AgentFailure(reason, detail)
        code = proc.terminate(_GRACE.get(reason, 0.0))
        self.failure = dead or AgentFailure(reason, detail, code, proc.stderr.finish(), pid=proc.pid)
        if dead is not None:
            proc.stderr.finish()
        self.proc = None
        return self.failure

    def _dead_robot(self) -> RobotFailure | None:
        """The robot's failure when the virtual DB21J's bridge (its DTPS server) is no longer running."""
        robot = self.robot
        if robot is None or robot.alive:
            return None
        code = robot.exit_code
        return RobotFailure("exited", "the virtual DB21J's DTPS server (bridge) died"
                            + ("" if code is None else f" (exit code {code})"), code, robot.link.stderr_tail())

    def _stop_program(self) -> None:
        if self.proc is not None:
            self.proc.terminate(0.0, term_first=True)
            self.proc.stderr.finish()
            self.proc = None

    def close(self) -> None:
        """End the program and the virtual robot."""
        self._stop_program()
        if self.robot is not None:
            self.robot.close()
            self.robot = None

    def __enter__(self) -> SdkAgent:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
