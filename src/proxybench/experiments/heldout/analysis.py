"""From the held-out runs to verdicts: every metric's pick per case and task, the references, the hits, hit
rates with intervals, and how PRPV's pick depends on the agent set.

Scoring only reads a case's hidden truth (``Case.reveal``) after every episode of every case has run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from proxybench.experiments.heldout.config import HeldOutSettings
from proxybench.experiments.heldout.run import CaseRun, HeldOutRun
from proxybench.tasks.metrics import METRICS as TASK_METRICS
from proxybench.usefulness.agent_sets import argmin_random_ties, order_structure
from proxybench.usefulness.heldout_scoring import (
    METRICS,
    Grid,
    best_available,
    disagreement_from_means,
    mcnemar_p,
    ordered_stats,
    reference_stability,
    wilson,
)
from proxybench.usefulness.intervals import usefulness
from proxybench.usefulness.metrics import Estimate, PairedResults, prpv_from_means
from proxybench.usefulness.noise import compare_paired, noise_floor, paired_prpv_samples

__all__ = ["CaseScore", "HeldOutResult", "HitRate", "score_heldout"]

REFERENCES = ("order", "truth")


@dataclass
class CaseScore:
    """One case under one task: each metric's values over the grid and its pick, the references, the hits."""

    case: str
    kind: str
    task: str
    values: dict[str, np.ndarray]  # metric label → (P,) point values on the evaluation episodes
    prpv_interval: tuple[np.ndarray, np.ndarray]
    picks: dict[str, int]
    ties: dict[str, int]
    reference: dict[str, list[int]]  # "order" | "truth" → grid indices
    disagreement: np.ndarray
    resolved: int
    stability: float
    truth: dict[str, Any]
    hits: dict[tuple[str, str, int], bool]
    chance: dict[tuple[str, int], float]
    noise: Estimate
    prpv_neighbours: list[Any]
    structure: dict[str, float]
    loo_hits: list[bool] = field(default_factory=list)
    loo_picks: list[int] = field(default_factory=list)

    @property
    def prpv_separated(self) -> bool:
        return bool(self.prpv_neighbours) and all(c.a_lower for c in self.prpv_neighbours)


@dataclass(frozen=True)
class HitRate:
    """Hits of one metric over cases, with a Wilson interval and the rate of a random pick."""

    task: str
    metric: str
    reference: str
    tolerance: int
    hits: int
    n: int
    low: float
    high: float
    chance: float

    @property
    def rate(self) -> float:
        return self.hits / self.n if self.n else float("nan")


@dataclass(frozen=True)
class McNemar:
    """PRPV against another metric on the same held-out targets: the targets only PRPV hit, only the metric hit,
    and the exact McNemar p-value."""

    task: str
    reference: str
    tolerance: int
    metric: str
    prpv_only: int
    metric_only: int
    p: float

    def key(self) -> tuple[str, str, int, str]:
        return self.task, self.reference, self.tolerance, self.metric


@dataclass(frozen=True)
class AgentSetAnalysis:
    """PRPV's hit rate over bootstrap agent sets (the same set in every case): its draws, their interval, and how
    often the pick stays within ``tolerance`` of the full set's."""

    task: str
    tolerance: int
    n_boot: int
    rates: np.ndarray
    interval: tuple[float, float]
    pick_stays: float


@dataclass
class HeldOutResult:
    run: HeldOutRun
    scores: list[CaseScore]
    rates: list[HitRate]
    comparisons: list[McNemar]
    agent_boot: AgentSetAnalysis

    @property
    def settings(self) -> HeldOutSettings:
        return self.run.settings

    def primary(self) -> tuple[str, str, int]:
        c = self.settings.criteria
        return self.settings.primary_task, c.primary_reference, c.primary_tolerance_steps

    def rate(self, task: str, metric: str, reference: str, tolerance: int) -> HitRate:
        return next(r for r in self.rates if (r.task, r.metric, r.reference, r.tolerance)
                    == (task, metric, reference, tolerance))


def _split(res: dict[str, np.ndarray], cols: list[int], n_eval: int) -> tuple[dict, dict]:
    ev = {a: np.asarray(v)[:n_eval][:, cols] for a, v in res.items()}
    ref = {a: np.asarray(v)[n_eval:][:, cols] for a, v in res.items()}
    return ev, ref


def _metric_values(ests: list[dict[str, Estimate]]) -> dict[str, np.ndarray]:
    out = {}
    for key, alt, label, _ in METRICS:
        k = key if key in ests[0] else alt if alt in ests[0] else None
        if k is not None:
            out[label] = np.array([e[k].value for e in ests], dtype=float)
    return out


def _direction(label: str) -> int:
    return next(d for _, _, lb, d in METRICS if lb == label)


def _pick(values: np.ndarray, direction: int, rng: np.random.Generator) -> tuple[int, int]:
    return argmin_random_ties(-direction * values, rng)


def _caps(metrics: tuple[str, ...], seconds: float) -> list[float | None]:
    return [seconds if m in ("survival_time", "lane_score") else None for m in metrics]


def _score_case(cr: CaseRun, k: int, task: str, tmetrics: tuple[str, ...], grid: Grid, s: dict[str, Any],
                truth: dict[str, Any]) -> CaseScore:
    cols = [cr.metrics.index(m) for m in tmetrics]
    higher = tuple(TASK_METRICS[m].higher_is_better for m in tmetrics)
    n_eval = s.episodes
    t_ev, t_ref = _split(cr.target.results, cols, n_eval)
    p_split = [_split(p, cols, n_eval) for p in cr.proxies]
    ests = [usefulness(PairedResults(ev, t_ev, higher, tmetrics), n_boot=s.n_boot, seed=s.seed)
            for ev, _ in p_split]
    values = _metric_values(ests)
    rng = np.random.default_rng([s.seed, k, sum(map(ord, task))])
    picks, ties = {}, {}
    for label, v in values.items():
        picks[label], ties[label] = _pick(v, _direction(label), rng)
    best, d = best_available([ref for _, ref in p_split], t_ref, higher)
    tm, ts = ordered_stats(t_ref, list(t_ref), higher)
    resolved = disagreement_from_means(tm, tm, ts)[1]
    reference = {"order": best, "truth": grid.nearest(truth) if all(n in truth for n in grid.names) else []}
    hits, chance = {}, {}
    for ref_name, ref in reference.items():
        for tol in s.criteria.tolerances:
            chance[(ref_name, tol)] = grid.chance(set(ref), tol) if ref else float("nan")
            for label, pk in picks.items():
                hits[(label, ref_name, tol)] = bool(ref) and grid.within(pk, ref, tol)
    samples = paired_prpv_samples(t_ev, [ev for ev, _ in p_split], higher, n_boot=s.n_boot, seed=s.seed)
    labels = [grid.label(i) for i in range(len(grid))]
    pk = picks["PRPV"]
    neigh = [j for j in range(len(grid)) if grid.distance(pk, j) == 1]
    comps = [compare_paired(labels, values["PRPV"], samples, pk, j) for j in neigh]
    prpv_iv = (np.array([e["prpv"].low for e in ests]), np.array([e["prpv"].high for e in ests]))
    return CaseScore(
        cr.case.name, cr.case.kind, task, values, prpv_iv, picks, ties, reference, d, resolved,
        reference_stability([ref for _, ref in p_split], t_ref, higher, best, n_boot=s.reference_boot,
                            seed=s.seed + k),
        truth, hits, chance, noise_floor(t_ev, higher, n_boot=s.n_boot, seed=s.seed), comps,
        order_structure({a: np.asarray(v)[:, cols] for a, v in cr.target.results.items()}, higher,
                        _caps(tmetrics, s.seconds)))


def _means_for(cr: CaseRun, cols: list[int], higher: tuple[bool, ...], n_eval: int, agents: list[str]):
    """(proxy eval means (P, K, m), target eval means (K, m), proxy ref means (P, K, m), target ref (means, se))."""
    t_ev, t_ref = _split(cr.target.results, cols, n_eval)
    pe, pr = [], []
    for p in cr.proxies:
        ev, ref = _split(p, cols, n_eval)
        pe.append(ordered_stats(ev, agents, higher)[0])
        pr.append(ordered_stats(ref, agents, higher)[0])
    return np.stack(pe), ordered_stats(t_ev, agents, higher)[0], np.stack(pr), ordered_stats(t_ref, agents, higher)


def _subset_hit(grid: Grid, pe, te, pr, tr, idx, tol: int, rng) -> tuple[int, bool]:
    """PRPV's pick and whether it hits the order reference, both computed on the agents ``idx`` only."""
    prpv = np.asarray(prpv_from_means(pe[:, idx], te[idx][None], (True,) * te.shape[1]), dtype=float)
    pick = argmin_random_ties(prpv, rng)[0]
    d, _ = disagreement_from_means(pr[:, idx], tr[0][idx], tr[1][idx])
    best = [int(i) for i in np.flatnonzero(np.isclose(d, d.min(), rtol=0, atol=1e-9))]
    return pick, grid.within(pick, best, tol)


def _agent_analyses(run: HeldOutRun, scores: list[CaseScore]) -> AgentSetAnalysis:
    """Leave-one-agent-out and bootstrap-over-agents hit rates of PRPV (primary task and tolerance, order
    reference), with the same agent sets in every case so that a set's hit rate is one draw of the population."""
    s = run.settings
    task = s.primary_task
    tol = s.criteria.primary_tolerance_steps
    tmetrics = tuple(s.tasks[task])
    agents = [a.label for a in run.agents]
    k = len(agents)
    held = [(cr, sc) for cr, sc in zip(run.cases, [x for x in scores if x.task == task], strict=True)]
    rng = np.random.default_rng([s.seed, 0xB007])
    data = []
    for cr, _ in held:
        cols = [cr.metrics.index(m) for m in tmetrics]
        higher = tuple(TASK_METRICS[m].higher_is_better for m in tmetrics)
        data.append(_means_for(cr, cols, higher, s.episodes, agents))
    for (_, sc), dd in zip(held, data, strict=True):
        for drop in range(k):
            idx = np.array([i for i in range(k) if i != drop])
            pick, hit = _subset_hit(run.grid, *dd, idx, tol, rng)
            sc.loo_picks.append(pick)
            sc.loo_hits.append(hit)
    n_boot = s.agent_boot
    kinds = [sc.kind for _, sc in held]
    rates, stays = [], []
    for _ in range(n_boot):
        idx = rng.integers(0, k, k)
        while np.unique(idx).size < min(3, k):
            idx = rng.integers(0, k, k)
        hits = []
        for (_, sc), dd, kind in zip(held, data, kinds, strict=True):
            pick, hit = _subset_hit(run.grid, *dd, idx, tol, rng)
            if kind == "held-out":
                hits.append(hit)
                stays.append(run.grid.distance(pick, sc.picks["PRPV"]) <= tol)
        if hits:
            rates.append(float(np.mean(hits)))
    q = 100 * (1 - s.criteria.level) / 2
    rates_a = np.asarray(rates)
    interval = (float(np.percentile(rates_a, q)), float(np.percentile(rates_a, 100 - q))) if rates else \
        (float("nan"), float("nan"))
    return AgentSetAnalysis(task, tol, n_boot, rates_a, interval, float(np.mean(stays)) if stays else float("nan"))


def score_heldout(run: HeldOutRun) -> HeldOutResult:
    """Score every case under every task, then the hit rates (Wilson intervals over the held-out cases)."""
    s = run.settings
    truths = [cr.case.reveal() for cr in run.cases]  # only now, after every episode ran
    scores = [_score_case(cr, k, task, tuple(ms), run.grid, s, truths[k])
              for task, ms in s.tasks.items() for k, cr in enumerate(run.cases)]
    rates, comparisons = [], []
    level = s.criteria.level
    for task in s.tasks:
        held = [sc for sc in scores if sc.task == task and sc.kind == "held-out"]
        for ref in REFERENCES:
            for tol in s.criteria.tolerances:
                for label in held[0].picks if held else []:
                    hs = [sc.hits[(label, ref, tol)] for sc in held if sc.reference[ref]]
                    lo, hi = wilson(sum(hs), len(hs), level)
                    ch = [sc.chance[(ref, tol)] for sc in held if sc.reference[ref]]
                    rates.append(HitRate(task, label, ref, tol, sum(hs), len(hs), lo, hi,
                                         float(np.mean(ch)) if ch else float("nan")))
                if held:
                    base = [sc.hits[("PRPV", ref, tol)] for sc in held]
                    for label in held[0].picks:
                        if label != "PRPV":
                            b, c, p = mcnemar_p(base, [sc.hits[(label, ref, tol)] for sc in held])
                            comparisons.append(McNemar(task, ref, tol, label, b, c, p))
    return HeldOutResult(run, scores, rates, comparisons, _agent_analyses(run, scores))
