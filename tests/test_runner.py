"""The runner: episodes in, trajectories and a results table out; cached, resumable, backend-agnostic."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pandas as pd
import pytest

from proxybench.agents.base import Agent
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.runner import PrivilegedAgentError, run_episode
from proxybench.runner.backends import InlineBackend, LocalBackend, RayBackend
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
from proxybench.runner.sweep import run_jobs
from proxybench.tasks.metrics import METRICS
from proxybench.tasks.trajectory import Trajectory

SMALL = {"image_width": 80, "image_height": 60}
METRIC_NAMES = ("survival_time", "driven_lanedir_consec", "deviation_center_line")


def _jobs(agents=("pid", "straight"), episodes=2, duration=4.0):
    dom = DomainSpec("small", DomainParams(**SMALL))
    return [Job(AgentSpec(a), dom, "loop_3x3", e, 10 + e, duration, metrics=METRIC_NAMES)
            for a in agents for e in range(episodes)]


def _table(res):
    return sorted((r.agent, r.episode, tuple(sorted((k, round(v, 12)) for k, v in r.scores.items())), r.termination)
                  for r in res.results)


def test_sweep_writes_trajectories_and_a_long_results_table(tmp_path):
    res = run_jobs(_jobs(), tmp_path / "run")
    assert res.ran == 4 and res.cached == 0
    df = pd.read_parquet(tmp_path / "run" / "results.parquet")
    assert set(df.columns) >= {"agent", "domain", "episode", "metric", "value", "termination"}
    assert len(df) == 4 * len(METRIC_NAMES)
    pid = df[(df.agent == "pid") & (df.metric == "survival_time")]
    assert (pid.value == 4.0).all()
    straight = df[(df.agent == "straight") & (df.metric == "survival_time")]
    assert (straight.value < 4.0).all()  # open loop leaves the loop's road
    for r in res.results:
        traj = Trajectory.load(r.trajectory)
        assert traj.meta["source"] == "simulation" and traj.meta["agent"] == r.agent


def test_second_run_is_served_from_the_cache(tmp_path):
    first = run_jobs(_jobs(), tmp_path)
    again = run_jobs(_jobs(), tmp_path)
    assert again.ran == 0 and again.cached == 4
    assert _table(first) == _table(again)


def test_a_damaged_record_is_redone(tmp_path):
    res = run_jobs(_jobs(episodes=1), tmp_path)
    (tmp_path / "episodes" / f"{res.results[0].key}.json").write_text("{not json")
    again = run_jobs(_jobs(episodes=1), tmp_path)
    assert again.ran == 1 and again.cached == 1


def test_killed_sweep_resumes_without_redoing_finished_episodes(tmp_path):
    script = tmp_path / "sweep.py"
    script.write_text(textwrap.dedent(f"""
        from proxybench.domain.params import DomainParams
        from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
        from proxybench.runner.sweep import run_jobs
        dom = DomainSpec("small", DomainParams(**{SMALL!r}))
        jobs = [Job(AgentSpec("pid"), dom, "loop_3x3", e, e, 8.0, metrics={METRIC_NAMES!r}) for e in range(40)]
        run_jobs(jobs, {str(tmp_path / "run")!r})
    """))
    proc = subprocess.Popen([sys.executable, str(script)])
    ep = tmp_path / "run" / "episodes"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and len(list(ep.glob("*.json"))) < 3:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done_before = {p.name: p.stat().st_mtime_ns for p in ep.glob("*.json")}
    assert 3 <= len(done_before) < 40, "the sweep should have been killed mid-way"
    dom = DomainSpec("small", DomainParams(**SMALL))
    jobs = [Job(AgentSpec("pid"), dom, "loop_3x3", e, e, 8.0, metrics=METRIC_NAMES) for e in range(40)]
    res = run_jobs(jobs, tmp_path / "run")
    assert res.cached >= len(done_before) and res.cached + res.ran == 40
    assert {p.name: p.stat().st_mtime_ns for p in ep.glob("*.json") if p.name in done_before} == done_before
    assert all(r.scores["survival_time"] == 8.0 for r in res.results)


@pytest.mark.slow
def test_local_pool_and_ray_give_the_same_table_as_inline(tmp_path):
    jobs = _jobs()
    inline = run_jobs(jobs, tmp_path / "inline", InlineBackend())
    pool = LocalBackend(2)
    try:
        local = run_jobs(jobs, tmp_path / "local", pool)
    finally:
        pool.close()
    assert _table(local) == _table(inline)
    pytest.importorskip("ray")
    ray_backend = RayBackend(2)
    try:
        on_ray = run_jobs(jobs, tmp_path / "ray", ray_backend)
    finally:
        ray_backend.close()
    assert _table(on_ray) == _table(inline)



def test_pool_workers_use_one_thread_each():
    """Two workers on two cores: each runs its kernels, OpenMP and BLAS on one thread (no oversubscription)."""
    import os

    from proxybench.domain.parallelism import threads_available

    pool = LocalBackend(2)
    try:
        list(pool.run([], None))  # starts the pool
        assert pool._pool.submit(threads_available).result(timeout=120) == 1
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
            assert pool._pool.submit(os.getenv, var).result(timeout=60) == os.environ.get(var, "1")
        # a kernel compiled in a worker (on a fresh install: every kernel, the first time) compiles and runs
        # (it used to fail: "Cannot set NUMBA_NUM_THREADS to a different value once the threads have been launched")
        code = "import numba\nassert numba.njit(lambda x: x + 1)(1) == 2"
        for f in [pool._pool.submit(exec, code) for _ in range(2)]:
            assert f.result(timeout=120) is None
    finally:
        pool.close()

class _Crashing(Agent):
    name = "crashing"

    def __init__(self, after: int):
        self.after, self.k = after, 0

    def reset(self, seed, episode=None):
        self.k = 0

    def act(self, obs):
        self.k += 1
        if self.k > self.after:
            raise RuntimeError("boom")
        return np.array([0.3, 0.3])


def test_agent_failure_ends_the_episode_with_its_message():
    sim = Simulator("loop_3x3", DomainParams(**SMALL))
    traj = run_episode(sim, _Crashing(5), 0, 10.0)
    assert traj.termination == "agent_failure"
    assert traj.events[-1].kind == "agent_failure" and "boom" in traj.events[-1].message
    assert traj.duration == pytest.approx(5 / 15)


def test_camera_only_runs_refuse_privileged_agents():
    from proxybench.agents import make_agent

    sim = Simulator("loop_3x3", DomainParams(**SMALL))
    with pytest.raises(PrivilegedAgentError, match="'pid' is privileged"):
        run_episode(sim, make_agent("pid"), 0, 1.0, allow_privileged=False)


def test_imported_recording_scores_like_the_simulated_run(tmp_path):
    from proxybench.agents import make_agent

    sim = Simulator("loop_3x3", DomainParams(**SMALL))
    traj = run_episode(sim, make_agent("pid"), 3, 6.0)
    csv = tmp_path / "watchtower.csv"
    pd.DataFrame({"t": traj["t"], "x": traj["x"], "y": traj["y"], "theta": traj["theta"]}).to_csv(
        csv, index=False, float_format="%.17g")
    imported = Trajectory.from_file(csv, "loop_3x3", meta={"episode_seconds": 6.0})
    for name in ("survival_time", "driven_lanedir_consec", "deviation_center_line", "deviation_heading",
                 "in_drivable_lane", "lane_score", "driven_any"):
        assert METRICS[name](imported) == pytest.approx(METRICS[name](traj), abs=1e-9), name


def test_batched_episodes_equal_single_episodes(tmp_path):
    from proxybench.runner.sweep import _batches

    jobs = _jobs(agents=("pid", "vision", "straight"), episodes=3, duration=3.0)
    assert any(len({j.agent for j in b}) > 1 for b in _batches(jobs, 4, 1))  # camera agents of both kinds share one
    single = run_jobs(jobs, tmp_path / "single", batch_size=1)
    batched = run_jobs(jobs, tmp_path / "batched", batch_size=4)
    assert _table(single) == _table(batched)
    for a, b in zip(single.results, batched.results, strict=True):
        ta, tb = Trajectory.load(a.trajectory), Trajectory.load(b.trajectory)
        for col in ("x", "y", "theta", "pwm_left", "pwm_right"):
            np.testing.assert_array_equal(ta[col], tb[col])


def test_pool_worker_setup_survives_numba_reading_its_config_again():
    """A worker imports Numba before its initializer runs; on a fresh install the first compile re-reads
    Numba's config, which used to fail ("Cannot set NUMBA_NUM_THREADS ... once the threads have been launched")."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_NUM_THREADS"}
    code = ("import numba; from proxybench.runner.backends import _init_worker; _init_worker(); "
            "numba.core.config.reload_config(); print(numba.get_num_threads())")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "1"
