"""An Autolab job on a lab's **DTPS robot** (a real DB21J, a Duckiematrix robot): driven by the agent, watched by
the lab, measured by its watchtowers (docs/autolab.md, "A real robot").

Here proxybench simulates nothing: the robot is foreign. Per split:

- the lab's **watchtowers** are its own DTPS camera streams (``watchtowers.streams``), read by
  :mod:`proxybench.autolab.live` (a simulated layout cannot see a robot it does not simulate: refused);
- a **relay** (:mod:`proxybench.dtps.relay`) gives the sandboxed SDK agent the robot at ``127.0.0.1:7501`` in a
  network namespace that holds nothing else (safe sandbox), so the agent speaks DTPS to *that* robot, with no other
  network; the robot's path is the agent's to name (the Duckiematrix's ``robot/map_0/vehicle_0`` is what
  ``DB21J("map_0/vehicle_0", simulated=True)`` asks for);
- an **observer** (:mod:`proxybench.dtps.observer`) records the episode from the robot's own topics: every wheel
  command and the pose the robot reports, if any (kept beside the result, never scored).

Per episode: the operator places the robot (``reset: operator``, or ``pose_file`` for its poses: a real robot is
placed by a person either way) and confirms (:mod:`proxybench.autolab.operator`); the watchtowers record; the
agent's program starts; the episode's clock starts at the robot's **first command** and runs the benchmark's
duration; then the program is ended and the robot sent (0, 0). The recording is re-based on that clock (a frame
before it is dropped: the robot stood still) and localised, validated and scored as a virtual robot's
(:func:`~.autolab.localize_episode`), from the localised trajectory only. An operator's intervention ends the
episode and the job: ``manual_intervention``; no confirmation in time: ``robot_failure: operator-timeout``; a
program that ends early or never commands the robot is the agent's failure. A robot that **drops off** DTPS (its
server no longer accepts a connection, :class:`Heartbeat`, or the relay or observer ends) ends the episode and the
job as ``robot_failure``, whatever the program did after it lost its robot. What this shares with a robot node's
job (:mod:`.autolab_node`) is in :mod:`.autolab_real`.
"""

from __future__ import annotations

import csv
import logging
import os
import socket
import threading
import time
from pathlib import Path

from proxybench.autolab.lab import Lab
from proxybench.evaluator import autolab_real as real
from proxybench.evaluator.autolab_real import Scoring
from proxybench.evaluator.outcome import HostFault, SubmissionFault

__all__ = ["Heartbeat", "Scoring", "check_dtps_robot", "run_dtps_split"]

log = logging.getLogger("proxybench.evaluator.job")
#: how often the episode loop looks at the robot, the program and the operator's desk [s]
_TICK = 0.05


def check_dtps_robot(lab: Lab, spec) -> None:
    """What a DTPS robot's job needs; :class:`HostFault` saying what is missing."""
    from proxybench.runner.jobs import SdkProgram

    real.check_real_robot(lab, "a DTPS robot")
    if not isinstance(spec, SdkProgram):
        raise HostFault(f"lab {lab.name!r}: on a DTPS robot this evaluator runs duckietown-sdk agents only; agent "
                        f"{spec.name!r} is an AIDO node (docs/autolab.md, 'A real robot')")


class Heartbeat:
    """Whether a DTPS robot is still there: a thread opens a TCP connection to its server every ``period`` [s]
    (``timeout`` each); ``misses`` failures in a row and :attr:`lost` says why. Nothing else tells: the observer
    only listens (a subscription to a server that went away reports nothing) and the relay copies bytes for the
    agent, whose connections may close for any reason; a real robot's Wi-Fi may drop a probe, hence the misses."""

    def __init__(self, host: str, port: int, *, period: float = 1.0, timeout: float = 2.0, misses: int = 2):
        self.host, self.port, self.period, self.timeout, self.misses = host, port, period, timeout, misses
        self.lost: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="dtps-robot-heartbeat", daemon=True)
        self._thread.start()

    def probe(self) -> str | None:
        """One connection to the robot's server now: None when it accepted, else why not."""
        try:
            socket.create_connection((self.host, self.port), timeout=self.timeout).close()
        except OSError as exc:
            return exc.strerror or type(exc).__name__
        return None

    def _run(self) -> None:
        missed = 0
        while not self._stop.wait(self.period):
            why = self.probe()
            missed = 0 if why is None else missed + 1
            if missed >= self.misses:
                self.lost = f"its DTPS server {self.host}:{self.port} answered none of {missed} connections in a row " \
                            f"({why})"
                return

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=self.timeout + 1.0)


def _write_record(path: Path, heard, origin: float) -> Path:
    """The robot's own record of the episode (commands, reported poses) on the episode's clock, as CSV."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["kind", "t", "left", "right", "x", "y", "theta"])
        w.writerows(("command", f"{c[0] - origin:.4f}", c[1], c[2], "", "", "") for c in heard.commands)
        w.writerows(("pose", f"{p[0] - origin:.4f}", "", "", p[1], p[2], p[3]) for p in heard.poses)
    return path


class _Lab:
    """What a split holds open on the lab: the relay, the observer, the watchtower reader, the desk."""

    def __init__(self, lab: Lab, robot, spec, layout_none_streams):
        from proxybench.autolab.operator import OperatorDesk, OperatorError
        from proxybench.dtps.link import PortLock
        from proxybench.dtps.observer import RobotObserver
        from proxybench.dtps.relay import RelayError, RobotRelay
        from proxybench.dtps.robot_options import parse_address
        from proxybench.protocol.failures import RobotFailure

        self.address = parse_address(robot.dtps)
        self.live = layout_none_streams
        self.lock = None
        self.relay = self.observer = self.heartbeat = None
        own = bool(spec.node_options().own_netns)
        try:
            self.desk = OperatorDesk.of(lab, robot.name)
            if not own:  # the developer's unsafe modes: the relay on the host's 7501, one at a time
                self.lock = PortLock(7501)
                self.lock.acquire(60.0)
            self.relay = RobotRelay(self.address.host, self.address.port, own_netns=own)
            self.observer = RobotObserver(self.address)
            self.heartbeat = Heartbeat(self.address.host, self.address.port)
        except (RelayError, RobotFailure, OperatorError, OSError) as exc:
            self.close()
            raise HostFault(f"robot_failure: robot {robot.name!r} of lab {lab.name!r} ({self.address}): {exc}") \
                from None

    def close(self) -> None:
        for part in (self.heartbeat, self.observer, self.relay):
            if part is not None:
                try:
                    part.close()
                except Exception as exc:  # closing must go on for the rest
                    log.warning("closing the lab's link to its robot: %s", exc)
        if self.lock is not None:
            self.lock.release()


def _episode(job, lab: Lab, robot, bench, spec, held: _Lab, ep, what: str, folder: Path):
    """One episode (``what``: one attempt at it) on the DTPS robot (see the module): (the streams folder, what the
    robot heard, clock origin)."""
    from proxybench.dtps.agent import NETNS_ENV
    from proxybench.dtps.env import env_path
    from proxybench.protocol.failures import RobotFailure
    from proxybench.protocol.transport import Launch, node_argv

    real.place_robot(held.desk, lab, robot, bench, ep, what)
    held.observer.take()  # what came before this episode is not its record
    options = spec.node_options()
    nonce = held.desk.open_episode(what)
    sink = held.live.sink
    sink.begin(folder / "streams")
    env = {"PATH": f"{env_path() / 'bin'}{os.pathsep}{os.environ.get('PATH', '/usr/bin:/bin')}",
           "PYTHONUNBUFFERED": "1", "PROXYBENCH_EPISODE_SEED": str(int(ep.seed))}
    if held.relay.netns is not None:
        env[NETNS_ENV] = held.relay.netns
    began, first, proc = time.time(), None, None
    heard = None
    try:
        proc = Launch(node_argv(spec.command), transport="none", env=env, stderr_lines=50)
        while True:
            time.sleep(_TICK)
            try:
                held.observer.pump(time.monotonic())
            except RobotFailure as exc:
                raise real.robot_failure(lab, robot, what, exc.detail) from None
            if first is None and held.observer.heard.commands:
                first = held.observer.heard.commands[0][0]
            reason = held.desk.intervention(nonce)
            if reason is not None:
                raise real.intervened(lab, robot, what, reason)
            if held.heartbeat.lost is not None:
                raise real.robot_failure(lab, robot, what, held.heartbeat.lost)
            if not held.relay.alive or not held.observer.alive:
                raise real.robot_failure(lab, robot, what, f"its DTPS link ({held.address}) ended")
            now = time.time()
            if first is not None and now - first >= bench.duration:
                break
            if proc.exited():
                gone = held.heartbeat.probe()  # a program that lost its robot is not at fault
                if gone is not None:
                    raise real.robot_failure(lab, robot, what, f"its DTPS server {held.address.host}:"
                                                               f"{held.address.port} went away ({gone})")
                tail = proc.stderr.finish()
                job.check_sandbox([tail])
                ran = "before its first command" if first is None else f"{now - first:.1f} s into the episode"
                raise SubmissionFault(f"the SDK agent program ended {ran} ({what}), exit code {proc.terminate()}"
                                      + "".join(f"\n  {line}" for line in tail[-15:]))
            if first is None and now - began > options.start_timeout:
                raise SubmissionFault(f"the SDK agent program sent the robot no wheel command within its "
                                      f"start_timeout ({options.start_timeout:g} s) in {what}")
    finally:
        if proc is not None:
            proc.terminate(0.0, term_first=True)
            proc.stderr.finish()
        held.observer.stop()
        heard = held.observer.take()
        held.desk.close_episode()
        sink.end()
    return sink.episodes[-1], heard, first


def _attempt(job, lab: Lab, robot, bench, spec, held: _Lab, ep, split: str, attempt: int, m, scoring: Scoring,
             origins: list[dict]):
    """One attempt at an episode: run (the operator places the robot), the streams re-based on the first command,
    the robot's record written and noted in ``origins``, localised and validated; the episode as measured."""
    from proxybench.domain.events import Termination
    from proxybench.dtps.cameras import ReaderError

    folder = real.attempt_folder(job, split, ep.index, attempt)
    what = real.episode_name(split, ep.index, attempt)
    try:
        streams, heard, first = _episode(job, lab, robot, bench, spec, held, ep, what, folder)
    except ReaderError as exc:
        raise HostFault(f"watchtowers: {exc}") from None
    kept = real.rebase_streams(streams.folder, first)
    log.info("%s: first command at %.3f; %d watchtower frames from then on, %d commands and %d poses heard", what,
             first, kept, len(heard.commands), len(heard.poses))
    record = _write_record(folder / "robot.csv", heard.since(first), first)
    origins.append({"episode": ep.index, "attempt": attempt, "first_command_wall": first,
                    "commands": len(heard.commands), "poses": len(heard.poses), "bad": heard.bad, "frames": kept})
    ran = real.Ran(ep.index, streams.folder, Termination.TIMEOUT)
    return real.localize_episode(job, scoring, ran, bench, lab, m, folder, robot, split, attempt, record)


def run_dtps_split(job, lab: Lab, bench, spec, split: str, hidden: bool, *,
                   scoring: Scoring) -> dict[str, float | None]:
    """A split's episodes on the lab's DTPS robot (see the module), an invalid one run again as the benchmark says
    (:func:`.autolab_real.run_attempts`); the benchmark's scores, from the localised trajectories."""
    from proxybench.domain.maps import load_map

    robot = lab.robot(job.job.autolab_robot)
    check_dtps_robot(lab, spec)
    job.phase = split
    m = load_map(bench.map)
    live = real.open_watchtowers(lab)
    specs = bench.episode_specs()
    log.info("%s: %d episodes of %g s on lab %r's DTPS robot %r (%s), %d watchtowers recording over DTPS", split,
             len(specs), bench.duration, lab.name, robot.name, robot.dtps, len(live.names))
    episodes, origins = [], []
    held = None
    try:
        held = _Lab(lab, robot, spec, live)
        for k, ep in enumerate(specs):
            def attempt(n: int, ep=ep):
                return _attempt(job, lab, robot, bench, spec, held, ep, split, n, m, scoring, origins)
            episodes.append(real.run_attempts(job, bench, split, robot, attempt))
            job.progress(k + 1, len(specs))
    finally:
        if held is not None:
            held.close()
        live.close()
    return real.finish_split(job, lab, robot, bench, split, hidden, scoring, kind="autolab/dtps",
                             about={"robot_address": robot.dtps}, episodes=episodes, records=origins, live=live)
