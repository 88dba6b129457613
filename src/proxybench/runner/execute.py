"""How a worker does jobs: a batch of one :func:`~.jobs.batch_group` goes to the simulator or to a robot node.

Every backend (inline, process pool, Ray) calls :func:`execute_batch`; it is the one entry point of episode
sets, whatever the domain.
"""

from __future__ import annotations

from proxybench.domain.kinds import DomainKind
from proxybench.runner.jobs import Job, JobResult, batch_group
from proxybench.runner.robot_jobs import execute_robot_batch
from proxybench.runner.sim_jobs import execute_sim_batch

__all__ = ["execute", "execute_batch"]


def execute(job: Job, out_dir: str | None) -> JobResult:
    """Run one job in this process; write its trajectory under ``out_dir`` (atomically) if given."""
    return execute_batch([job], out_dir)[0]


def execute_batch(jobs: list[Job], out_dir: str | None) -> list[JobResult]:
    """Run jobs of one :func:`~.jobs.batch_group` together; write their trajectories under ``out_dir`` if given."""
    if len({batch_group(j) for j in jobs}) != 1:
        raise ValueError("execute_batch: the jobs do not share one batch group")
    if jobs[0].domain.kind is DomainKind.ROBOT:
        return execute_robot_batch(jobs, out_dir)
    return execute_sim_batch(jobs, out_dir)
