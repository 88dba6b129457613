"""How a worker runs the jobs of a robot domain: one node process per batch, episodes one after another.

A robot domain (``DomainSpec.robot(CMD, …)``, a ``RobotDomain``) is a robot node reached through the robot
protocol (docs/robot-protocol.md): a physical robot's bridge, another simulator, ``proxybench robot serve``.
Its jobs produce the same ``JobResult`` and trajectory files as simulated ones, through the same cache.
The node is started once per batch and reused across its episodes; after a failure the next episode
starts a fresh process. At most ``ProtocolLink.nodes`` processes of one command run at once on a machine
(a lock file per slot in the user's private folder), across workers and sweeps, so that a bridge to one
physical robot is never started twice.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import time
from collections.abc import Iterator
from typing import Any

from proxybench.domain.events import Termination
from proxybench.domain.kinds import DomainKind
from proxybench.private import open_private, user_folder
from proxybench.protocol import RobotFailure
from proxybench.runner.jobs import Job, JobResult
from proxybench.runner.outcomes import all_metrics, make_agent_for, refused, result_of
from proxybench.runner.robot_episode import RobotLacksGroundTruth, run_episode_on_plant
from proxybench.runner.robots import RobotConnection, open_robot

__all__ = ["ROBOT_INIT_TIMEOUT_S", "ROBOT_STEP_TIMEOUT_S", "execute_robot_batch", "robot_slot"]

#: the default timeouts of a robot node (``RobotNodeOptions``; a domain's ``options`` may change them): it may need
#: to start a simulator (or reach hardware) before it answers its handshake
ROBOT_INIT_TIMEOUT_S = 120.0
ROBOT_STEP_TIMEOUT_S = 10.0
#: after this many robot failures in a row the rest of a batch is not tried (each may cost a timeout)
FAILURES_IN_A_ROW = 2


@contextlib.contextmanager
def robot_slot(command: str, nodes: int, poll_s: float = 0.05) -> Iterator[int]:
    """Hold one of ``nodes`` machine-wide slots for ``command`` while the block runs; yields the slot.

    The slots are ``flock``-ed files, released by the kernel when a holder dies, so a killed worker never
    leaves a robot locked; they live in the user's private folder (:mod:`proxybench.private`), so another local
    user can neither hold a slot nor plant a link there (:class:`~proxybench.private.PrivateFileError` names it).
    """
    folder = user_folder("robots")
    tag = hashlib.sha256(command.encode()).hexdigest()[:16]
    files: list[Any] = []
    try:
        for k in range(nodes):
            files.append(os.fdopen(open_private(folder / f"{tag}.{k}.lock"), "r+b"))
        while True:
            for k, f in enumerate(files):
                try:
                    fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    continue
                try:
                    yield k
                finally:
                    fcntl.flock(f, fcntl.LOCK_UN)
                return
            time.sleep(poll_s)
    finally:
        for f in files:
            f.close()


def execute_robot_batch(jobs: list[Job], out_dir: str | None) -> list[JobResult]:
    """Run jobs on one robot domain one after another on one node process, or one DTPS bridge (closed at the end).

    A :class:`~proxybench.protocol.RobotFailure` becomes that job's result (termination ``robot_failure``,
    NaN scores, the reason in ``message``) instead of ending the sweep; :func:`~.sweep.run_jobs` does not
    cache such results, so a later run retries them. A failed robot is closed and the next episode reaches
    it afresh. After two failures in a row the rest of the batch is recorded with the last failure instead
    of being tried (a node that cannot start would otherwise cost a timeout per episode). A privileged
    agent on a robot that reports no true lane pose, or on a camera-only job, is refused like on a
    simulated domain (termination ``agent_failure``, a reason, NaN scores).
    """
    from proxybench.domain.maps import load_map
    from proxybench.tasks.metrics import METRICS

    domain = jobs[0].domain
    robot: RobotConnection | None = None
    maps: dict[str, Any] = {}
    results: list[JobResult] = []
    failure: RobotFailure | None = None
    in_a_row = 0
    with robot_slot(domain.command, domain.nodes):
        try:
            for job in jobs:
                if failure is not None and in_a_row >= FAILURES_IN_A_ROW:
                    results.append(_robot_failed(job, failure, skipped=True))
                    continue
                t0 = time.perf_counter()
                agent = make_agent_for(job.agent)
                try:
                    if agent.privileged and job.camera_only:
                        results.append(refused(job, agent, time.perf_counter() - t0))
                        continue
                    if robot is None:  # a robot not saying its rate is stepped at the domain's
                        robot = open_robot(domain)
                    if job.map not in maps:
                        maps[job.map] = load_map(job.map)
                    t1 = time.perf_counter()
                    traj = run_episode_on_plant(
                        robot.plant(maps[job.map]), agent, job.seed, job.duration, pose=job.pose,
                        route=None if job.route is None else list(job.route), camera=not agent.privileged,
                        allow_privileged=not job.camera_only,
                        meta={"map": job.map, "episode": job.episode, "domain": job.domain.name,
                              "domain_kind": DomainKind.ROBOT, "job": job.key})
                except RobotFailure as exc:
                    failure, in_a_row = exc, in_a_row + 1
                    results.append(_robot_failed(job, exc))
                    robot = _closed(robot)
                    continue
                except RobotLacksGroundTruth as exc:
                    results.append(refused(job, agent, time.perf_counter() - t0, str(exc)))
                    continue
                finally:
                    getattr(agent, "close", lambda: None)()
                in_a_row = 0
                results.append(result_of(job, traj, out_dir, t1 - t0, time.perf_counter() - t1, METRICS))
        finally:
            if robot is not None:
                robot.close()
    return results


def _closed(robot: RobotConnection | None) -> None:
    """Close a robot whose episode failed (a node already reaped, a DTPS bridge still delivering its (0, 0))."""
    if robot is not None:
        with contextlib.suppress(Exception):
            robot.close()
    return None


def _robot_failed(job: Job, exc: RobotFailure, skipped: bool = False) -> JobResult:
    """The result of a job whose robot node failed: no trajectory, NaN scores, the failure in words."""
    text = f"robot failure ({exc.reason}): {exc.detail}"
    if exc.exit_code is not None:
        text += f" (exit code {exc.exit_code})"
    if exc.stderr_tail:
        text += "; last stderr lines: " + " | ".join(exc.stderr_tail[-5:])
    if skipped:
        text = f"not run: the robot failed {FAILURES_IN_A_ROW} times in a row; last: {text}"
    return JobResult(job.key, job.agent.label, job.domain.name, job.episode, job.seed,
                     dict.fromkeys(job.metrics or all_metrics(), float("nan")), Termination.ROBOT_FAILURE, None, text)
