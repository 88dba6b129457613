"""The held-out experiment: how often does each metric pick the best available proxy θ on targets it was not
tuned on?

Every *case* is a target the experiment sees as a black box — a held-out target of
:mod:`proxybench.targets.heldout` (structural differences, θ drawn off-grid from a hidden seed), and the
standing negative case (the shipped reality model against proxies without its fisheye lens, the stronger
lens error that moved the PRPV optimum) — with a grid of proxy θ. For each case:

1. the target runs every agent for ``episodes`` *evaluation* and ``reference_episodes`` *reference*
   episodes (disjoint seeds), and every grid proxy replays all of them (same starts and seeds; a proxy's
   episodes are shared by every case with the same θ and starts, through the runner's cache);
2. on the evaluation episodes, ``usefulness()`` gives PRPV, PPV, SRCC (Pearson), Spearman, Kendall and
   MMRV of every θ; each metric *picks* its best θ (ties broken at random, seeded, and counted);
3. the reference episodes give the *best available θ* (:mod:`proxybench.usefulness.heldout_scoring`),
   and only now is the hidden truth revealed, for the second reference (the grid θ nearest it);
4. a pick is a *hit* under the criteria fixed in the config — and written to ``criteria.json`` before
   anything runs — e.g. "within one grid step of a best available θ".

Hit rates come with Wilson intervals over cases and the rate a random pick would reach; PRPV's pick also
with the target's noise floor, paired comparisons with its grid neighbours, and its sensitivity to the
agent set (:mod:`proxybench.usefulness.agent_sets`).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.experiments.config import ConfigError
from proxybench.experiments.heldout.config import (
    DEFAULTS,
    Criteria,
    HeldOutConfig,
    HeldOutSettings,
    load_heldout_config,
)
from proxybench.experiments.proxies import proxy_params
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
from proxybench.runner.sweep import run_jobs
from proxybench.targets.spec import Target, TargetRun
from proxybench.usefulness.heldout_scoring import Grid

__all__ = ["Case", "CaseRun", "Criteria", "HeldOutConfig", "HeldOutRun", "cases_for", "load_heldout_config",
           "run_heldout", "write_criteria"]

Progress = Callable[[str, int, int], None]

@dataclass
class Case:
    """A target as the experiment sees it (a black box), the θ every proxy of this case has on top of the
    nominal calibration, and how to reveal its truth once every episode ran."""

    name: str
    kind: str  # "held-out" | "negative"
    target: Target
    proxy: dict[str, Any] = field(default_factory=dict)
    description: str = ""
    truth: dict[str, Any] | None = None  # known θ of a target that cannot reveal one (scored only)

    def reveal(self) -> dict[str, Any]:
        """The target's θ, for scoring after every episode ran: a held-out target's hidden draw, the given
        ``truth``, or the reality model's calibrated values; {} when unknown (then only ``order`` is scored)."""
        if self.truth is not None:
            return dict(self.truth)
        reveal = getattr(self.target, "reveal", None)
        if reveal is not None:
            return dict(reveal())
        truth = getattr(self.target, "truth", None)
        return dict(truth()) if truth is not None else {}


def cases_for(cfg: HeldOutConfig, quick: bool = False) -> list[Case]:
    """The held-out targets of the family (black boxes) and, if asked, the standing negative case."""
    from proxybench.targets.heldout import heldout_targets
    from proxybench.targets.spec import RealityTarget

    n = cfg.targets or DEFAULTS[quick].targets
    out = [Case(t.name, "held-out", t, {}, "held-out target (structural differences, θ hidden)")
           for t in heldout_targets(n, cfg.family_seed)]
    if cfg.negative_case:
        out.append(Case("lens-negative", "negative", RealityTarget(), {"fisheye": False},
                        "the shipped reality model (fisheye lens) against proxies with a pinhole camera: the "
                        "stronger lens error that moved the PRPV optimum (README)"))
    return out


@dataclass
class CaseRun:
    """The episodes of one case: the target's and every grid proxy's, per agent (episodes × metrics), with
    the episode order of the target (evaluation episodes first, then reference episodes)."""

    case: Case
    target: TargetRun
    proxies: list[dict[str, np.ndarray]]
    metrics: tuple[str, ...]


@dataclass
class HeldOutRun:
    """Everything the scoring needs: the resolved settings and the runs of every case."""

    settings: HeldOutSettings
    grid: Grid
    agents: list[AgentSpec]
    cases: list[CaseRun]
    criteria_file: Path | None
    simulated_episodes: int = 0
    wall_s: float = 0.0


def resolve_settings(cfg: HeldOutConfig, quick: bool) -> HeldOutSettings:
    """Every choice made: the config, then the mode's defaults."""
    d = DEFAULTS[quick]
    return HeldOutSettings(
        quick=quick, targets=cfg.targets or d.targets,
        family_seed_sha256=hashlib.sha256(str(cfg.family_seed).encode()).hexdigest()[:12],
        negative_case=cfg.negative_case, agents=tuple(cfg.agents or d.agents), map=cfg.map,
        episodes=cfg.episodes or d.episodes, reference_episodes=cfg.reference_episodes or d.reference_episodes,
        seconds=cfg.seconds or d.seconds, tasks=cfg.tasks, primary_task=cfg.primary_task, grid=cfg.grid or d.grid,
        image_size=cfg.image_size, criteria=cfg.criteria, n_boot=cfg.n_boot or d.n_boot, agent_boot=cfg.agent_boot,
        reference_boot=cfg.reference_boot, seed=cfg.seed)


def write_criteria(settings: HeldOutSettings, out: Path) -> Path:
    """``criteria.json``: the pass criteria and settings, written before any episode runs (the report quotes
    it with its time and hash, so the criteria cannot have been chosen after seeing the results). A resumed
    run with the same settings keeps the file, and so the time it was first written."""
    from proxybench.usefulness.heldout_scoring import __doc__ as definition

    out.mkdir(parents=True, exist_ok=True)
    path = out / "criteria.json"
    try:
        if json.loads(path.read_text()).get("settings") == settings.model_dump(mode="json"):
            return path  # the same experiment resumed: the criteria keep the time they were first written
    except (OSError, ValueError):
        pass
    doc = {"written": time.strftime("%Y-%m-%d %H:%M:%S %z"), "settings": settings.model_dump(mode="json"),
           "best_available_definition": (definition or "").split("**Best available θ**", 1)[-1].split(">>>")[0].strip(),
           "hit": "a metric's pick (its best θ on the evaluation episodes, ties broken at random) is a hit when it "
                  "lies within tolerance_steps grid steps (along every axis) of a θ in the reference set"}
    path.write_text(json.dumps(doc, indent=1))
    return path


def _proxy_jobs(agents: dict[str, AgentSpec], tgt: TargetRun, dom: DomainSpec, metrics: tuple[str, ...]) -> list[Job]:
    """The target's episodes replayed in one proxy (as ``predictivity.proxy_jobs``)."""
    return [Job(agents[e.agent], dom, tgt.map, e.episode, e.seed, tgt.seconds, pose=e.pose, metrics=metrics)
            for e in tgt.episodes]


def run_heldout(cfg: HeldOutConfig, out: str | Path, backend: Backend | None = None, progress: Progress | None = None,
                *, quick: bool = False, cases: list[Case] | None = None) -> HeldOutRun:
    """Write the criteria, then run every case's target and proxies (cached in ``out/runs``; resumable)."""
    from proxybench.experiments.agent_args import AgentArgError, parse_agents

    t0 = time.perf_counter()
    out = Path(out)
    backend = backend or InlineBackend()
    s = resolve_settings(cfg, quick)
    try:
        agents = parse_agents(s.agents, out / "agents")
    except AgentArgError as exc:
        raise ConfigError(f"agents: {exc}") from None
    criteria_file = write_criteria(s, out)
    cases = cases if cases is not None else cases_for(cfg, quick)
    grid = Grid.from_dict(s.grid)
    metrics = tuple(dict.fromkeys(m for ms in s.tasks.values() for m in ms))
    n_eps = s.episodes + s.reference_episodes
    run_dir = out / "runs"
    specs = {a.label: a for a in agents}
    targets, jobs, ran = [], [], 0
    for k, case in enumerate(cases):
        tgt = case.target.run(agents, map_name=s.map, seconds=s.seconds, episodes=n_eps, seed=s.seed,
                              metrics=metrics, image_size=tuple(s.image_size), run_dir=run_dir, backend=backend,
                              progress=(lambda _st, d, t, c=case: progress(f"target {c.name}", d, t)) if progress
                              else None)
        ran += tgt.ran
        targets.append(tgt)
        if progress:
            progress("target episodes (cases)", k + 1, len(cases))
        for g, p in enumerate(grid.points):
            params = proxy_params(tuple(s.image_size), case.proxy, **p)
            jobs.extend(_proxy_jobs(specs, tgt, DomainSpec(grid.label(g), params), metrics))
    keys = [j.key for j in jobs]
    unique = list({k: j for k, j in zip(keys, jobs, strict=True)}.values())  # cases with equal θ share episodes
    sweep = run_jobs(unique, run_dir, backend,
                     progress=(lambda d, t, _r: progress("proxy episodes", d, t)) if progress else None)
    ran += sweep.ran
    result = {r.key: r for r in sweep.results}
    runs, i = [], 0
    for case, tgt in zip(cases, targets, strict=True):
        proxies = []
        for _ in grid.points:
            by: dict[str, list[list[float]]] = {}
            for _e in tgt.episodes:
                r = result[keys[i]]
                by.setdefault(jobs[i].agent.label, []).append([r.scores[m] for m in metrics])
                i += 1
            proxies.append({a: np.asarray(v, dtype=float) for a, v in by.items()})
        runs.append(CaseRun(case, tgt, proxies, metrics))
    return HeldOutRun(s, grid, agents, runs, criteria_file, ran, time.perf_counter() - t0)
