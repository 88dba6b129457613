"""What becomes of an episode a worker ran: the agent it was played by, and the job's result (scores, file).

Shared by the simulator's and the robot's job execution (:mod:`.sim_jobs`, :mod:`.robot_jobs`), so that both
name agents, refuse privileged agents, score trajectories and write them the same way.
"""

from __future__ import annotations

import time
from pathlib import Path

from proxybench.domain.events import Termination
from proxybench.runner.jobs import AgentSpec, InProcessAgent, Job, JobResult, NodeAgent, SdkProgram

__all__ = ["all_metrics", "camera_filter", "make_agent_for", "refused", "result_of"]


def make_agent_for(spec: AgentSpec):
    """The agent a spec names: a zoo agent or checkpoint in-process, a node process behind the protocol, or an
    SDK program."""
    match spec:
        case SdkProgram():
            from proxybench.dtps.agent import SdkAgent

            return SdkAgent(spec.command, name=spec.name, options=spec.node_options())
        case NodeAgent():
            from proxybench.protocol import RemoteAgent

            agent = RemoteAgent(spec.command, **spec.node_options().process_kwargs())
            agent.name = spec.name
            return agent
        case InProcessAgent():
            from proxybench.agents import make_agent

            return make_agent(spec.name)
    raise TypeError(f"not an agent spec: {spec!r}")


def camera_filter():
    """What camera agents see: the JPEG round trip of every frame, exactly what a protocol node receives."""
    from proxybench.protocol.jpeg import roundtrip

    return roundtrip


def all_metrics() -> tuple[str, ...]:
    from proxybench.tasks.metrics import METRICS

    return tuple(METRICS)


def refused(job: Job, agent, setup_s: float, msg: str | None = None) -> JobResult:
    """A privileged agent on a camera-only job (or on a robot without ground truth): no episode, a recorded
    reason, NaN scores."""
    msg = msg or f"agent {agent.name!r} is privileged (reads the true lane pose); this benchmark is camera-only"
    return JobResult(job.key, job.agent.label, job.domain.name, job.episode, job.seed,
                     dict.fromkeys(job.metrics or all_metrics(), float("nan")), Termination.AGENT_FAILURE, None, msg,
                     {"setup_s": setup_s})


def result_of(job: Job, traj, out_dir: str | None, setup_s: float, episode_s: float, metrics) -> JobResult:
    t = time.perf_counter()
    scores = {name: metrics[name](traj) for name in (job.metrics or tuple(metrics))}
    path = None
    if out_dir is not None:
        path = str(Path(out_dir) / f"{job.key}.parquet")
        traj.save(path)
    message = traj.failure.message if traj.failure is not None else ""
    timing = traj.meta.get("timing", {})
    sim_s, agent_s = timing.get("sim_s", 0.0), timing.get("agent_s", 0.0)
    timings = {"setup_s": setup_s, "sim_s": sim_s, "agent_s": agent_s,
               "bookkeeping_s": (episode_s - sim_s - agent_s) + (time.perf_counter() - t),
               "simulated_s": traj.duration}
    return JobResult(job.key, job.agent.label, job.domain.name, job.episode, job.seed, scores, traj.termination,
                     path, message, timings)
