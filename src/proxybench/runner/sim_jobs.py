"""How a worker runs the jobs of a simulated domain: one batched simulator per batch, cached per worker."""

from __future__ import annotations

import time
from typing import Any

from proxybench.runner.episode import run_episodes
from proxybench.runner.jobs import Job, JobResult
from proxybench.runner.outcomes import camera_filter, make_agent_for, refused, result_of
from proxybench.tasks.metrics import METRICS

__all__ = ["execute_sim_batch"]

_SIMS: dict[tuple[Any, ...], Any] = {}


def _simulator(job: Job, n: int = 1):
    """One cached simulator per (map, θ, batch size) per worker: building one costs more than an episode."""
    from proxybench.domain.simulator import Simulator

    k = (job.map, job.domain.canonical(), n, job.npcs)
    if k not in _SIMS:
        if len(_SIMS) > 8:
            _SIMS.clear()
        _SIMS[k] = Simulator(job.map, job.domain.params, n=n, npcs=job.npcs)
    return _SIMS[k]


def execute_sim_batch(jobs: list[Job], out_dir: str | None) -> list[JobResult]:
    """Run jobs of one :func:`~.jobs.batch_group` on a simulated domain together: one simulator of N robots,
    one agent per robot (agents may differ from robot to robot; a batch gives the same trajectories as N
    single runs). In-process agents are batched; node agents (one process each) run one by one.
    """
    if len(jobs) > 1 and jobs[0].agent.command:
        return [r for j in jobs for r in execute_sim_batch([j], out_dir)]
    job0 = jobs[0]
    t0, c0 = time.perf_counter(), time.process_time()
    agents = [make_agent_for(j.agent) for j in jobs]
    if len({a.privileged for a in agents}) > 1:  # an agent that is not what its name said: see alike, run alike
        for a in agents:
            getattr(a, "close", lambda: None)()
        return [r for flag in (False, True)
                for r in execute_sim_batch([j for j, a in zip(jobs, agents, strict=True) if a.privileged == flag],
                                       out_dir)]
    sim = _simulator(job0, len(jobs))
    t1 = time.perf_counter()
    try:
        if agents[0].privileged and job0.camera_only:
            return [refused(j, a, (t1 - t0) / len(jobs)) for j, a in zip(jobs, agents, strict=True)]
        trajs = run_episodes(
            sim, agents, [j.seed for j in jobs], job0.duration, poses=[j.pose for j in jobs],
            routes=[j.route for j in jobs], allow_privileged=not job0.camera_only,
            camera=not agents[0].privileged or getattr(agents[0], "wants_camera", False),
            image_filter=camera_filter(),
            metas=[{"map": j.map, "episode": j.episode, "domain": j.domain.name, "domain_kind": j.domain.kind,
                    "source": j.domain.kind, "job": j.key} for j in jobs],
        )
    finally:
        for a in agents:
            getattr(a, "close", lambda: None)()
    t2 = time.perf_counter()
    results = [result_of(j, tr, out_dir, (t1 - t0) / len(jobs), (t2 - t1) / len(jobs), METRICS)
               for j, tr in zip(jobs, trajs, strict=True)]
    cpu = (time.process_time() - c0) / len(jobs)
    for r in results:
        r.timings["cpu_s"] = cpu
    return results
