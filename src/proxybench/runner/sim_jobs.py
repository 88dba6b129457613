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

    fixtures = job.streams.fixtures if job.streams is not None else ()
    k = (job.map, job.domain.canonical(), n, job.npcs, fixtures)
    if k not in _SIMS:
        if len(_SIMS) > 8:
            _SIMS.clear()
        m = job.map
        if fixtures:  # a lab's calibration tags are part of its world
            from proxybench.domain.maps import load_map
            from proxybench.runner.streams import with_fixtures

            m = with_fixtures(load_map(job.map), fixtures)
        _SIMS[k] = Simulator(m, job.domain.params, n=n, npcs=job.npcs)
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
    recorders = _recorders(jobs, sim, out_dir)
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
            frame_hook=_stream_hook(recorders),
        )
    finally:
        for a in agents:
            getattr(a, "close", lambda: None)()
        for rec in recorders:
            rec.close()
    t2 = time.perf_counter()
    results = [result_of(j, tr, out_dir, (t1 - t0) / len(jobs), (t2 - t1) / len(jobs), METRICS)
               for j, tr in zip(jobs, trajs, strict=True)]
    cpu = (time.process_time() - c0) / len(jobs)
    for r in results:
        r.timings["cpu_s"] = cpu
    for r, rec in zip(results, recorders, strict=False):
        r.streams = str(rec.out)
    return results


def _recorders(jobs: list[Job], sim, out_dir: str | None) -> list:
    """One stream recorder per job of a batch that asks for streams (robot i of the batch is world i)."""
    if jobs[0].streams is None:
        return []
    if out_dir is None:
        raise ValueError("jobs with streams need an output folder (the streams are written beside the trajectory)")
    from pathlib import Path

    from proxybench.runner.streams import StreamRecorder

    return [StreamRecorder(sim, j.streams, Path(out_dir) / f"{j.key}.streams", world=i) for i, j in enumerate(jobs)]


def _stream_hook(recorders: list):
    """The engine's frame hook that feeds the stream recorders: each world's cameras while its episode runs."""
    if not recorders:
        return None

    def hook(k: int, images, alive, plant) -> None:
        for i, rec in enumerate(recorders):
            if alive[i]:
                rec.frame(plant.time(i))
    return hook
