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
  recording re-based to it as for a DTPS robot (:func:`.autolab_dtps.rebase_streams`);
- the scores come from the **localised** trajectory only (:func:`~.autolab.localize_episode`); the node's own
  record (the pose it reports) is kept beside, scored as ``robot_reported_scores``, never as the result.

A robot node that fails (it exits, breaks the protocol, misses a deadline) is ``robot_failure`` (the lab's fault);
an agent that fails is the submission's.
"""

from __future__ import annotations

import contextlib
import json
import logging
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from proxybench.autolab.lab import Lab
from proxybench.evaluator.autolab_dtps import Scoring, rebase_streams, tell_operator
from proxybench.evaluator.outcome import Artifact, HostFault, SubmissionFault

__all__ = ["check_node_robot", "run_node_split"]

log = logging.getLogger("proxybench.evaluator.job")


def check_node_robot(lab: Lab) -> None:
    """What a robot node's job needs of the lab; :class:`HostFault` saying what is missing."""
    if lab.watchtowers.layout is not None:
        raise HostFault(f"lab {lab.name!r}: simulated watchtowers (layout) cannot see a robot node's robot; give the "
                        "lab's own cameras as watchtowers.streams")
    if lab.reset.mode == "teleport":  # lab.yaml refuses it already; a lab made in code might not
        raise HostFault(f"lab {lab.name!r}: a robot node's robot is placed by its operator (reset.mode operator or "
                        "pose_file)")


class _Watched:
    """The runner's plant of the node, as the lab watches it: the wall time of the first command sent, and the
    operator's desk looked at before every frame (an intervention ends the episode before the next command)."""

    def __init__(self, plant: Any, desk: Any, nonce: str, what: str):
        self._plant, self._desk, self._nonce, self._what = plant, desk, nonce, what
        self.first: float | None = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._plant, name)

    def advance(self, commands, alive, k: int):
        reason = self._desk.intervention(self._nonce)
        if reason is not None:
            raise HostFault(f"manual_intervention: the operator intervened on {self._what}: {reason}")
        if self.first is None:
            self.first = time.time()
        return self._plant.advance(commands, alive, k)


@dataclass
class _Ran:
    """One episode as :func:`~.autolab.localize_episode` reads it: its streams, no truth, the node's ending."""

    episode: int
    streams: Path
    termination: object
    trajectory: Path | None = None


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


def _episode(job, lab: Lab, bench, spec, conn, live, desk, ep, split: str, folder: Path, m):
    """One episode on the node (see the module): (the streams recorded, the node's trajectory, first command)."""
    from proxybench.protocol.failures import RobotFailure
    from proxybench.runner.robot_episode import run_episode_on_plant
    from proxybench.runner.rollout import PrivilegedAgentError
    from proxybench.runner.starts import start_pose

    robot = lab.robot(job.job.autolab_robot)
    pose = ep.pose if ep.pose is not None else start_pose(bench.map, ep.seed, bench.domain_params())
    what = f"{split} episode {ep.index}"
    x, y, th = pose
    waited = _place(desk, f"place robot {robot.name} at x={x:.3f} m, y={y:.3f} m, θ={th * 57.29578:.1f}° for "
                          f"{what}", lab.operator.timeout_s)
    log.info("%s: the operator placed %s after %.1f s", what, robot.name, waited)
    with contextlib.ExitStack() as held:  # undone in reverse: the agent ended first, then the recording, the desk
        nonce = desk.open_episode(what)
        held.callback(desk.close_episode)
        live.sink.begin(folder / "streams")
        held.callback(live.sink.end)
        agent = _start_agent(job, spec, bench)
        held.callback(getattr(agent, "close", lambda: None))
        plant = _Watched(conn.plant(m), desk, nonce, f"robot {robot.name!r} of lab {lab.name!r} in {what}")
        try:
            traj = run_episode_on_plant(
                plant, agent, ep.seed, bench.duration, pose=tuple(pose),
                route=None if ep.route is None else list(ep.route),
                camera=not agent.privileged or getattr(agent, "wants_camera", False),
                allow_privileged=not bench.camera_only,
                meta={"map": bench.map, "episode": ep.index, "domain": f"lab:{lab.name}/{robot.name}",
                      "domain_kind": "robot"})
        except RobotFailure as exc:
            raise HostFault(f"robot_failure: robot {robot.name!r} of lab {lab.name!r} failed in {what}: {exc}") \
                from None
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


def _place(desk, request: str, timeout_s: float) -> float:
    """The operator's placement (:meth:`OperatorDesk.place`); no answer in time is the lab's fault."""
    from proxybench.autolab.operator import OperatorTimeout

    try:
        return desk.place(request, timeout_s, tell=tell_operator)
    except OperatorTimeout as exc:
        raise HostFault(f"robot_failure: {exc}") from None


def _open(lab: Lab, robot, bench):
    """The node (through the runner's robot domain, :func:`~proxybench.runner.robots.open_robot`), then the lab's
    watchtowers (a stand-in's node serves them) and the operator's desk; closes what opened on a failure."""
    from proxybench.autolab.live import live_streams
    from proxybench.autolab.operator import OperatorDesk, OperatorError
    from proxybench.dtps.cameras import ReaderError
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
        live = live_streams(lab, None)
    except ReaderError as exc:
        conn.close()
        raise HostFault(f"watchtowers: {exc}") from None
    try:
        desk = OperatorDesk.of(lab, robot.name)
    except OperatorError as exc:
        live.close()
        conn.close()
        raise HostFault(f"robot_failure: robot {robot.name!r} of lab {lab.name!r}: {exc}") from None
    return conn, live, desk


def run_node_split(job, lab: Lab, bench, spec, split: str, hidden: bool, *,
                   scoring: Scoring) -> dict[str, float | None]:
    """A split's episodes on the lab's robot node (see the module); the benchmark's scores, from the localised
    trajectories."""
    from proxybench.domain.events import Termination
    from proxybench.domain.maps import load_map
    from proxybench.dtps.cameras import ReaderError
    from proxybench.runner.robot_jobs import robot_slot
    from proxybench.tasks.metrics import METRICS

    robot = lab.robot(job.job.autolab_robot)
    check_node_robot(lab)
    job.phase = split
    m = load_map(bench.map)
    specs = bench.episode_specs()
    episodes, reported, records = [], [], []
    with robot_slot(robot.command, 1):  # one bridge to one robot, across this machine's evaluators
        conn, live, desk = _open(lab, robot, bench)
        log.info("%s: %d episodes of %g s on lab %r's robot node %r (`%s`), %d watchtowers recording over DTPS",
                 split, len(specs), bench.duration, lab.name, robot.name, robot.command, len(live.names))
        try:
            for k, ep in enumerate(specs):
                folder = job.dir / "autolab" / split / str(ep.index)
                try:
                    streams, traj, first = _episode(job, lab, bench, spec, conn, live, desk, ep, split, folder, m)
                except ReaderError as exc:
                    raise HostFault(f"watchtowers: {exc}") from None
                if traj.termination is Termination.AGENT_FAILURE:
                    raise _agent_failed(job, traj, split, ep.index, hidden)
                kept = rebase_streams(streams.folder, first)
                record = traj.save(folder / "robot.parquet")
                reported.append(_Reported(ep.index, {n: float(METRICS[n](traj)) for n in bench.metrics}))
                records.append({"episode": ep.index, "first_command_wall": first, "frames": kept,
                                "termination": str(traj.termination), "robot": traj.meta.get("robot"),
                                "record": Path(record).name})
                log.info("%s episode %d: first command at %.3f; %d watchtower frames from then on; the node ended "
                         "it %s", split, ep.index, first, kept, traj.termination)
                ran = _Ran(ep.index, streams.folder, traj.termination)
                job.phase = f"{split} localisation"
                episodes.append(scoring.localize(ran, bench, lab, None, m, folder / "localized", METRICS,
                                                 robot.name))
                job.phase = split
                job.progress(k + 1, len(specs))
        finally:
            conn.close()
            live.close()
    return _finish(job, lab, robot, bench, split, hidden, scoring, episodes, reported, records, live)


def _finish(job, lab: Lab, robot, bench, split: str, hidden: bool, scoring: Scoring, episodes, reported, records,
            live) -> dict[str, float | None]:
    """The split's report, its trajectories' zip, the DTA's verdict and the scores (from the localisation only)."""
    report = {"domain_kind": "autolab/node", "measured_by": "watchtowers", "lab": lab.name, "robot": robot.name,
              "robot_command": robot.command, "watchtowers": len(live.names),
              "localization": [e.report() for e in episodes], "localization_median_error_m": None,
              "robot_record": records, "robot_reported_scores": scoring.scores(reported, bench),
              "watchtower_streams": [e.report() for e in live.sink.episodes],
              "episodes": [{"episode": e.episode, "scores": e.report()["scores"], "valid": e.valid}
                           for e in episodes]}
    if hidden:
        job.outcome.hidden_report = report
    else:
        job.outcome.public_report.update(report)
    zip_path = job.dir / f"trajectories-{split}.zip"
    with zipfile.ZipFile(zip_path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for e in episodes:
            for f in e.files:
                zf.write(f, f"episode-{e.episode}{'' if f.suffix == '.parquet' else '-' + f.stem}{f.suffix}")
            zf.write(job.dir / "autolab" / split / str(e.episode) / "robot.parquet",
                     f"robot-episode-{e.episode}.parquet")
        zf.writestr("robot-record.json", json.dumps(records, indent=1))
    job.outcome.artifacts.append(Artifact(zip_path.name, str(zip_path), hidden, "application/zip"))
    bad = [e for e in episodes if not e.valid or e.trajectory is None]
    if bad:
        e = bad[0]
        word = "tracking_lost" if e.lost or e.trajectory is None else "invalid"
        raise HostFault(f"{word}: {split} episode {e.episode} is not fit to be scored (the DTA's validation): "
                        + ("; ".join(e.reasons) or "the watchtowers localised the robot fewer than twice"))
    if not hidden and job.job.video and episodes and episodes[0].trajectory is not None:
        scoring.video(job, episodes[0].trajectory, bench)
    return scoring.scores(episodes, bench)
