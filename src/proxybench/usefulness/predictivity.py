"""The thesis' predictivity experiment (figures 3.3 and 3.4), as an importable function.

K zoo agents are evaluated on the *target* (the reality model, a simulated stand-in for a real
Duckiebot) and on proxy instances θ of the simulator swept around the target's calibrated values:
trim over [-0.3, 0.3] (figure 3.3) and three values each of trim, command delay, blur time and camera
pitch (figure 3.4). For every θ: PRPV, PPV, SRCC, Spearman, Kendall, MMRV with bootstrap intervals, and
POD. The question the figures answer: is the usefulness metric smallest at the truth, and does it grow
away from it?
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.domain.params import DomainParams
from proxybench.domain.reality import TRUTH, reality_params
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job, JobResult
from proxybench.runner.sweep import run_jobs
from proxybench.tasks.metrics import METRICS
from proxybench.usefulness.metrics import PairedResults, usefulness
from proxybench.usefulness.pod import pod

__all__ = ["PredictivityConfig", "PredictivityResult", "proxy_params", "run_predictivity"]

FULL_AGENTS = ("random", "straight", "bang-bang", "pid", "pid-fast", "pid-sluggish", "pid-twitchy", "pure-pursuit",
               "pure-pursuit-fast", "vision", "vision-fast", "vision-slow", "vision-pitch15", "vision-pitch25",
               "vision-wide", "vision-twitchy")
QUICK_AGENTS = ("straight", "bang-bang", "pid", "pid-fast", "pid-twitchy", "pure-pursuit", "vision", "vision-fast",
                "vision-pitch25", "vision-twitchy", "vision-slow", "pid-sluggish")


@dataclass
class PredictivityConfig:
    """Every knob of the experiment. ``quick()`` is the small version used by tests and first tries."""

    agents: tuple[str, ...] = FULL_AGENTS
    episodes: int = 10
    seconds: float = 60.0
    map: str = "loop_3x3"
    image_size: tuple[int, int] = (160, 120)
    metrics: tuple[str, ...] = ("driven_lanedir_consec", "survival_time")  # the thesis: distance and survival
    trim_sweep: tuple[float, ...] = tuple(np.round(np.linspace(-0.3, 0.3, 7), 3))
    grid: dict[str, tuple[float, ...]] = field(default_factory=lambda: {
        "trim": (-0.1, 0.0, 0.1),
        "command_delay": (0.05, 0.10, 0.15),
        "blur_time": (0.0, 0.05, 0.10),
        "camera_pitch": (15.0, 19.15, 23.0),
    })
    n_boot: int = 300
    pod_seconds: float = 10.0
    seed: int = 0

    @classmethod
    def quick(cls) -> PredictivityConfig:
        return cls(agents=QUICK_AGENTS, episodes=3, seconds=20.0, n_boot=100, pod_seconds=4.0)


def proxy_params(cfg: PredictivityConfig, **changes: Any) -> DomainParams:
    """A proxy instance: the plain simulator at the target's calibrated values, with ``changes``."""
    w, h = cfg.image_size
    return DomainParams(image_width=w, image_height=h, **{**TRUTH, **changes})


@dataclass
class PredictivityResult:
    """One row per (swept parameter, value): the usefulness figures, and the raw results."""

    rows: list[dict[str, Any]]
    config: PredictivityConfig
    target_scores: dict[str, dict[str, float]]

    def frame(self):
        import pandas as pd

        return pd.DataFrame(self.rows)


def _domains(cfg: PredictivityConfig) -> list[tuple[str, float, DomainSpec]]:
    """(swept parameter, value, domain) for every proxy instance; each θ appears once per parameter."""
    out = []
    for v in cfg.trim_sweep:
        out.append(("trim-sweep", float(v), DomainSpec(f"trim={v:g}", proxy_params(cfg, trim=float(v)).model_dump())))
    for name, values in cfg.grid.items():
        for v in values:
            out.append((name, float(v), DomainSpec(f"{name}={v:g}", proxy_params(cfg, **{name: v}).model_dump())))
    return out


def _results_by_agent(results: list[JobResult], metrics: tuple[str, ...]) -> dict[str, np.ndarray]:
    by: dict[str, list[list[float]]] = {}
    for r in results:
        by.setdefault(r.agent, []).append([r.scores[m] for m in metrics])
    return {a: np.asarray(v) for a, v in by.items()}


def run_predictivity(
    cfg: PredictivityConfig, run_dir: str | Path, backend: Backend | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> PredictivityResult:
    """Run (or resume) the whole experiment; episodes are cached in ``run_dir``."""
    backend = backend or InlineBackend()
    w, h = cfg.image_size
    target = DomainSpec("reality", reality_params(image_width=w, image_height=h).model_dump(), kind="reality-model")
    domains = _domains(cfg)
    unique = {d.name: d for d in [target] + [d for _, _, d in domains]}  # trim=0 is in both sweeps
    jobs = [Job(AgentSpec(a), d, cfg.map, e, cfg.seed * 10_000 + e, cfg.seconds, metrics=cfg.metrics)
            for d in unique.values() for a in cfg.agents for e in range(cfg.episodes)]
    sweep = run_jobs(jobs, run_dir, backend,
                     progress=(lambda done, total, _r: progress("episodes", done, total)) if progress else None)
    # group by the job's domain, not the result's: equal θ under two names share one cached result
    by_domain: dict[str, list[JobResult]] = {}
    for job, r in zip(jobs, sweep.results, strict=True):
        by_domain.setdefault(job.domain.name, []).append(r)
    higher = tuple(METRICS[m].higher_is_better for m in cfg.metrics)
    tgt = _results_by_agent(by_domain["reality"], cfg.metrics)
    commands = _pod_commands(cfg, target)
    rows = []
    for k, (param, value, dom) in enumerate(domains):
        prx = _results_by_agent(by_domain[dom.name], cfg.metrics)
        est = usefulness(PairedResults(prx, tgt, higher), n_boot=cfg.n_boot, seed=cfg.seed)
        row: dict[str, Any] = {"parameter": param, "value": value, "domain": dom.name,
                               "truth": float(TRUTH.get("trim" if param == "trim-sweep" else param, np.nan))}
        for name, e in est.items():
            row[name], row[f"{name}_low"], row[f"{name}_high"] = e.value, e.low, e.high
        row["pod"] = pod(DomainParams.model_validate(dom.params), DomainParams.model_validate(target.params),
                         cfg.map, commands, seed=cfg.seed)
        rows.append(row)
        if progress:
            progress("usefulness", k + 1, len(domains))
    target_scores = {a: dict(zip(cfg.metrics, np.mean(v, axis=0).tolist(), strict=True)) for a, v in tgt.items()}
    return PredictivityResult(rows, cfg, target_scores)


def _pod_commands(cfg: PredictivityConfig, target: DomainSpec) -> np.ndarray:
    """The commands the privileged PID agent issues on the target: a realistic open-loop sequence for POD."""
    from proxybench.agents import make_agent
    from proxybench.domain.simulator import Simulator
    from proxybench.runner.episode import run_episode

    sim = Simulator(cfg.map, DomainParams.model_validate(target.params), render=False)
    traj = run_episode(sim, make_agent("pid"), cfg.seed, cfg.pod_seconds, camera=False)
    per_frame = sim.substeps
    return np.stack([traj["pwm_left"][1::per_frame], traj["pwm_right"][1::per_frame]], axis=1)


def config_dict(cfg: PredictivityConfig) -> dict[str, Any]:
    return asdict(cfg)
