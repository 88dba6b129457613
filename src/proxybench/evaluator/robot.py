"""Target jobs on a robot node: the compliance check and the episodes, through the robot protocol.

An evaluator started with ``--robot-cmd CMD`` runs its target jobs on the robot node that ``CMD`` starts
(AIDO's simulator protocol for one robot, docs/robot-protocol.md) instead of the reality model. What
that node is, it says itself (``robot_interface_description``): ``robot`` for a physical robot's bridge,
``simulation`` for a simulator served as a robot (``proxybench robot serve``). Reports carry it as
``domain_kind`` = ``robot-node/<kind>``, so a simulator behind the protocol is never called a robot.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from proxybench.evaluator.compliance import (
    MAX_STRAIGHT_DRIFT_RAD,
    MIN_RESPONSE_M,
    RESPONSE_TIMEOUT_S,
    Check,
    ComplianceReport,
    check_calibration,
    check_frame,
)
from proxybench.protocol.options import RobotNodeOptions
from proxybench.runner.evaluate import Evaluation
from proxybench.runner.jobs import AgentSpec
from proxybench.tasks.benchmark import Benchmark

__all__ = ["check_robot", "evaluate_on_robot", "robot_domain_kind"]

_PWM = 0.5
#: a robot node may compile its kernels or home its hardware at start: more time than an agent gets (the default
#: of ``RobotNodeOptions``, which the evaluator's --robot-* options change)
ROBOT_INIT_TIMEOUT_S = RobotNodeOptions().start_timeout


def _process_kwargs(options: RobotNodeOptions | None) -> dict:
    return (options or RobotNodeOptions()).process_kwargs()  # defaults: 120 s to start, 10 s per step


def robot_domain_kind(kind: str) -> str:
    return f"robot-node/{kind}"


def check_robot(bench: Benchmark, cmd: str, *, seed: int = 0, options: RobotNodeOptions | None = None,
                ) -> ComplianceReport:
    """Start the robot node (with ``options``), then check that it responds, sends valid frames and is
    calibrated to spec."""
    from proxybench.domain.maps import load_map
    from proxybench.protocol import RemoteRobot, RobotFailure

    spec = bench.domain_params()
    report = ComplianceReport(f"robot node {cmd!r}", robot_domain_kind("unknown"))
    try:
        with RemoteRobot(cmd, frame_rate=bench.frame_rate, **_process_kwargs(options)) as robot:
            t0 = time.monotonic()
            info = robot.start_episode(load_map(bench.map), seed, seconds=2.0)
            report.domain_kind = robot_domain_kind(info.kind)
            report.target = f"robot node {cmd!r} (says it is: {info.kind})"
            camera = check_frame(robot.observations(0.0).observations.jpg, spec.image_width, spec.image_height)
            if camera.ok and not math.isclose(info.frame_rate, bench.frame_rate, rel_tol=1e-6):
                camera = Check("camera", False, f"the robot sends {info.frame_rate:g} frames/s; the benchmark "
                                                f"runs at {bench.frame_rate:g} Hz")
            start = robot.state(0.0).pose
            frames = max(1, round(info.frame_rate))
            state = None
            for k in range(frames):
                _, state, _ = robot.frame(k / info.frame_rate, np.array([_PWM, _PWM]), (k + 1) / info.frame_rate,
                                          observe=False)
            wall = time.monotonic() - t0
    except RobotFailure as exc:
        report.checks.append(Check("responds", False, f"the robot node failed: {exc}"))
        return report
    end = state.pose if state is not None else start
    moved = float(math.hypot(end[0] - start[0], end[1] - start[1]))
    ok = moved >= MIN_RESPONSE_M and wall <= RESPONSE_TIMEOUT_S
    report.checks.append(Check("responds", ok, f"moved {moved:.3f} m in one second at PWM {_PWM} (need ≥ "
                                               f"{MIN_RESPONSE_M} m); setup and that second took {wall:.2f} s "
                                               f"(limit {RESPONSE_TIMEOUT_S:g} s)"))
    report.checks.append(camera)
    calib = check_calibration(info.params or {}, spec) if info.params else \
        Check("calibration", True, "the robot declares no calibration values; only its driving is checked")
    drift = abs((end[2] - start[2] + math.pi) % (2 * math.pi) - math.pi)
    if drift > MAX_STRAIGHT_DRIFT_RAD:
        calib = Check("calibration", False, f"heading drifted {drift:.3f} rad in one second of equal wheel "
                                            f"commands (limit {MAX_STRAIGHT_DRIFT_RAD}); {calib.detail}")
    else:
        calib.detail += f"; straight-line drift {drift:.3f} rad (limit {MAX_STRAIGHT_DRIFT_RAD})"
    report.checks.append(calib)
    return report


def evaluate_on_robot(bench: Benchmark, spec: AgentSpec, cmd: str, run_dir: Path,
                      progress: Callable[[int, int], None] | None = None, *,
                      options: RobotNodeOptions | None = None) -> Evaluation:
    """Every episode of ``bench`` with the agent ``spec`` on the robot node ``cmd`` (started with ``options``),
    as an :class:`Evaluation`.

    Raises :class:`~proxybench.protocol.AgentFailure` when the agent node cannot start, ``RobotFailure``
    when the robot fails, ``PrivilegedAgentError`` for a privileged agent on a camera-only benchmark.
    """
    from proxybench.domain.maps import load_map
    from proxybench.protocol import RemoteRobot
    from proxybench.runner.jobs import JobResult
    from proxybench.runner.outcomes import make_agent_for
    from proxybench.runner.robot_episode import run_episode_on_robot
    from proxybench.runner.sweep import SweepResult, results_frame
    from proxybench.tasks.aggregate import aggregate, scores_by_agent
    from proxybench.tasks.metrics import METRICS
    from proxybench.tasks.scoring import leaderboard

    ep_dir = run_dir / "episodes"
    ep_dir.mkdir(parents=True, exist_ok=True)
    m = load_map(bench.map)
    specs = bench.episode_specs()
    results: list[JobResult] = []
    t0 = time.perf_counter()
    if progress:
        progress(0, len(specs))
    with RemoteRobot(cmd, frame_rate=bench.frame_rate, **_process_kwargs(options)) as robot:
        for ep in specs:
            agent = make_agent_for(spec)
            try:
                traj = run_episode_on_robot(robot, agent, ep.seed, bench.duration, map_=m, pose=ep.pose,
                                            camera=not agent.privileged, allow_privileged=not bench.camera_only,
                                            meta={"map": bench.map, "episode": ep.index, "domain": "robot"})
            finally:
                getattr(agent, "close", lambda: None)()
            path = traj.save(ep_dir / f"episode-{ep.index}.parquet")
            message = next((e["message"] for e in traj.events if e["kind"] == "agent_failure"), "")
            results.append(JobResult(f"robot-{ep.index}", spec.label, "robot", ep.index, ep.seed,
                                     {name: METRICS[name](traj) for name in bench.metrics}, traj.termination,
                                     str(path), message))
            if progress:
                progress(len(results), len(specs))
    frame = results_frame(results)
    frame.to_parquet(run_dir / "results.parquet", index=False)
    agg = aggregate(frame[["agent", "domain", "episode", "metric", "value"]], n_resamples=1000)
    ranks = leaderboard(scores_by_agent(agg), bench.criteria())
    return Evaluation(bench, ranks, agg, SweepResult(results, run_dir, 0, len(results), time.perf_counter() - t0), {})
