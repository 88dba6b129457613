"""An Autolab job on a lab's **robot node** (``command:``: a real robot's bridge, another simulator behind the robot
protocol): driven by the runner, watched by the lab, measured by its watchtowers (docs/autolab.md, "A real robot").

A robot node is stepped by proxybench itself (docs/robot-protocol.md): the runner's robot-node episode engine
(:func:`~proxybench.runner.robot_episode.run_episode_on_plant` on the node's
:class:`~proxybench.runner.robot_episode.RobotPlant`, the node opened by :func:`~proxybench.runner.robots.open_robot`
and held by its machine-wide :func:`~proxybench.runner.robot_jobs.robot_slot`) relays the job's agent to it: an AIDO
node's commands, or an SDK program's, which drives the virtual DB21J the runner serves it in lock-step (the SDK
agent of simulation jobs). The node is the lab's, so it runs with the evaluator's rights; the agent is sandboxed as
for any job. Per split:

- the lab's **watchtowers** are its own DTPS camera streams (``watchtowers.streams``, read by
  :mod:`proxybench.autolab.live`), opened once the node runs (a stand-in lab's node serves them);
- per episode the **operator** places the robot (:mod:`proxybench.autolab.operator`; the node is also told the
  start pose, which a simulator takes and a real robot's bridge may ignore) and may intervene while it runs;
- the episode's clock starts at the runner's **first command** to the node (its wall time), each watchtower's
  recording re-based to it as for a DTPS robot (:func:`.autolab_real.rebase_streams`: what any non-virtual
  robot's job shares);
- the scores come from the **localised** trajectory only (:func:`~.autolab.localize_episode`); the node's own
  record (the pose it reports) is kept beside, scored as ``robot_reported_scores``, never as the result.

A robot node that fails (it exits, breaks the protocol, misses a deadline) is ``robot_failure`` (the lab's fault);
an agent that fails is the submission's.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from proxybench.autolab.lab import Lab
from proxybench.evaluator import autolab_real as real
from proxybench.evaluator.autolab_real import Scoring
from proxybench.evaluator.outcome import HostFault, SubmissionFault

__all__ = ["check_node_robot", "run_node_split"]

log = logging.getLogger("proxybench.evaluator.job")


def check_node_robot(lab: Lab) -> None:
    """What a robot node's job needs of the lab; :class:`HostFault` saying what is missing."""
    real.check_real_robot(lab, "a robot node's robot")


class _Watched:
    """The runner's plant of the node, as the lab watches it: the wall time of the first command sent, and the
    operator's desk looked at before every frame (an intervention ends the episode before the next command)."""

    def __init__(self, plant: Any, desk: Any, nonce: str, intervened: Callable[[str], Exception]):
        self._plant, self._desk, self._nonce, self._intervened = plant, desk, nonce, intervened
        self.first: float | None = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._plant, name)

    def advance(self, commands, alive, k: int):
        reason = self._desk.intervention(self._nonce)
        if reason is not None:
            raise self._intervened(reason)
        if self.first is None:
            self.first = time.time()
        return self._plant.advance(commands, alive, k)


@dataclass(frozen=True)
class _Reported:
    """An episode's scores from the node's own record (``robot_reported_scores``), as the aggregation reads them."""

    episode: int
    scores: dict[str, float]


def _agent_failed(job, traj, split: str, episode: int, hidden: bool) -> SubmissionFault:
    """The submission's fault for an episode the agent failed, with its last stderr lines (not for hidden ones)."""
    ev = traj.failure
    tail = list(ev.stderr_tail) if ev is not None else []
    job.check_sandbox([tail])
    if hidden:
        return SubmissionFault("the agent failed in a hidden test episode (details are shown to the operators only)")
    code = f" (exit code {ev.exit_code})" if ev is not None and ev.exit_code is not None else ""
    what = f"{ev.reason or 'agent_failure'}: {ev.message}" if ev is not None else "agent_failure"
    return SubmissionFault(f"the agent failed in {split} episode {episode}: {what}{code}"
                           + "".join(f"\n  {line}" for line in tail[-15:]))


def _episode(job, lab: Lab, bench, spec, conn, live, desk, ep, what: str, folder: Path, m):
    """One episode (``what``: one attempt at it) on the node (see the module): (the streams recorded, the node's
    trajectory, first command)."""
    from proxybench.protocol.failures import RobotFailure
    from proxybench.runner.robot_episode import run_episode_on_plant
    from proxybench.runner.rollout import PrivilegedAgentError

    robot = lab.robot(job.job.autolab_robot)
    pose = real.place_robot(desk, lab, robot, bench, ep, what)
    with contextlib.ExitStack() as held:  # undone in reverse: the agent ended first, then the recording, the desk
        nonce = desk.open_episode(what)
        held.callback(desk.close_episode)
        live.sink.begin(folder / "streams")
        held.callback(live.sink.end)
        agent = _start_agent(job, spec, bench)
        held.callback(getattr(agent, "close", lambda: None))
        plant = _Watched(conn.plant(m), desk, nonce, lambda reason: real.intervened(lab, robot, what, reason))
        try:
            traj = run_episode_on_plant(
                plant, agent, ep.seed, bench.duration, pose=tuple(pose),
                route=None if ep.route is None else list(ep.route),
                camera=not agent.privileged or getattr(agent, "wants_camera", False),
                allow_privileged=not bench.camera_only,
                meta={"map": bench.map, "episode": ep.index, "domain": f"lab:{lab.name}/{robot.name}",
                      "domain_kind": "robot"})
        except RobotFailure as exc:
            raise real.robot_failure(lab, robot, what, str(exc)) from None
        except PrivilegedAgentError as exc:
            raise SubmissionFault(str(exc)) from None
    if plant.first is None:  # the runner sends a command every frame: an episode without one never stepped
        raise HostFault(f"robot_failure: robot {robot.name!r} of lab {lab.name!r} ran no frame in {what}")
    return live.sink.episodes[-1], traj, plant.first


def _start_agent(job, spec, bench):
    """The job's agent started (:func:`~proxybench.runner.outcomes.make_agent_for`: sandboxed as the spec says); one
    that fails to start, or is privileged on a camera-only benchmark, is the submission's fault."""
    from proxybench.protocol.failures import AgentFailure
    from proxybench.runner.outcomes import make_agent_for

    try:
        agent = make_agent_for(spec)
    except AgentFailure as exc:
        job.check_sandbox([exc.stderr_tail])
        raise SubmissionFault(f"the agent did not start: {exc}") from None
    if agent.privileged and bench.camera_only:
        getattr(agent, "close", lambda: None)()
        raise SubmissionFault(f"agent {spec.name!r} is privileged (reads the true lane pose); benchmark "
                              f"{bench.name!r} admits camera-only agents")
    return agent


def _open(lab: Lab, robot, bench):
    """The node (through the runner's robot domain, :func:`~proxybench.runner.robots.open_robot`), then the lab's
    watchtowers (a stand-in's node serves them) and the operator's desk; closes what opened on a failure."""
    from proxybench.autolab.operator import OperatorDesk, OperatorError
    from proxybench.protocol.failures import RobotFailure
    from proxybench.runner.jobs import DomainSpec
    from proxybench.runner.robots import open_robot

    domain = DomainSpec.robot(robot.command, frame_rate=bench.frame_rate, name=f"lab:{lab.name}/{robot.name}")
    try:
        conn = open_robot(domain)
    except RobotFailure as exc:
        raise HostFault(f"robot_failure: robot {robot.name!r} of lab {lab.name!r} (`{robot.command}`) did not "
                        f"start: {exc}") from None
    try:
        live = real.open_watchtowers(lab)
    except HostFault:
        conn.close()
        raise
    try:
        desk = OperatorDesk.of(lab, robot.name)
    except OperatorError as exc:
        live.close()
        conn.close()
        raise HostFault(f"robot_failure: robot {robot.name!r} of lab {lab.name!r}: {exc}") from None
    return conn, live, desk


@dataclass
class _Split:
    """What a split on the node holds open (the node, the watchtowers, the desk) and gathers: each attempt's record
    (``robot_record``) and each episode's scores from the node's own record, its last attempt's."""

    conn: Any
    live: Any
    desk: Any
    records: list[dict[str, Any]] = field(default_factory=list)
    reported: dict[int, _Reported] = field(default_factory=dict)


def _attempt(job, lab: Lab, robot, bench, spec, held: _Split, ep, split: str, attempt: int, m, hidden: bool,
             scoring: Scoring):
    """One attempt at an episode: run (the operator places the robot), the streams re-based on the first command,
    the node's record saved and noted, localised and validated; the episode as measured."""
    from proxybench.domain.events import Termination
    from proxybench.dtps.cameras import ReaderError
    from proxybench.tasks.metrics import METRICS

    folder = real.attempt_folder(job, split, ep.index, attempt)
    what = real.episode_name(split, ep.index, attempt)
    try:
        streams, traj, first = _episode(job, lab, bench, spec, held.conn, held.live, held.desk, ep, what, folder, m)
    except ReaderError as exc:
        raise HostFault(f"watchtowers: {exc}") from None
    if traj.termination is Termination.AGENT_FAILURE:
        raise _agent_failed(job, traj, split, ep.index, hidden)
    kept = real.rebase_streams(streams.folder, first)
    record = traj.save(folder / "robot.parquet")
    held.reported[ep.index] = _Reported(ep.index, {n: float(METRICS[n](traj)) for n in bench.metrics})
    held.records.append({"episode": ep.index, "attempt": attempt, "first_command_wall": first, "frames": kept,
                         "termination": str(traj.termination), "robot": traj.meta.get("robot"),
                         "record": record.name})
    log.info("%s: first command at %.3f; %d watchtower frames from then on; the node ended it %s", what, first,
             kept, traj.termination)
    ran = real.Ran(ep.index, streams.folder, traj.termination)
    return real.localize_episode(job, scoring, ran, bench, lab, m, folder, robot, split, attempt, record)


def run_node_split(job, lab: Lab, bench, spec, split: str, hidden: bool, *,
                   scoring: Scoring) -> dict[str, float | None]:
    """A split's episodes on the lab's robot node (see the module), an invalid one run again as the benchmark says
    (:func:`.autolab_real.run_attempts`); the benchmark's scores, from the localised trajectories."""
    from proxybench.domain.maps import load_map
    from proxybench.runner.robot_jobs import robot_slot

    robot = lab.robot(job.job.autolab_robot)
    check_node_robot(lab)
    job.phase = split
    m = load_map(bench.map)
    specs = bench.episode_specs()
    episodes = []
    with robot_slot(robot.command, 1):  # one bridge to one robot, across this machine's evaluators
        held = _Split(*_open(lab, robot, bench))
        log.info("%s: %d episodes of %g s on lab %r's robot node %r (`%s`), %d watchtowers recording over DTPS",
                 split, len(specs), bench.duration, lab.name, robot.name, robot.command, len(held.live.names))
        try:
            for k, ep in enumerate(specs):
                def attempt(n: int, ep=ep):
                    return _attempt(job, lab, robot, bench, spec, held, ep, split, n, m, hidden, scoring)
                episodes.append(real.run_attempts(job, bench, split, robot, attempt))
                job.progress(k + 1, len(specs))
        finally:
            held.conn.close()
            held.live.close()
    return real.finish_split(job, lab, robot, bench, split, hidden, scoring, kind="autolab/node",
                             about={"robot_command": robot.command}, episodes=episodes, records=held.records,
                             live=held.live,
                             extra={"robot_reported_scores": scoring.scores(list(held.reported.values()), bench)})
