"""The validation study's scoring: each method's pick on one target (:func:`score_target`) and the study's
conclusion over its targets (:func:`summarize`). With :mod:`~proxybench.experiments.validate.measures` and the
measures they call (:mod:`proxybench.usefulness`, :mod:`proxybench.tasks`), this is the code ``criteria.json``
hashes (:func:`~proxybench.experiments.validate.registration.scoring_hash`): keep the running, the registration
and the report out of it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.experiments.proxies import proxy_params
from proxybench.experiments.validate.config import ValidateSettings
from proxybench.experiments.validate.measures import (
    QUALITIES,
    CriteriaCheck,
    HitRate,
    MeasureSummary,
    MethodSummary,
    Pick,
    Primary,
    Quality,
    TargetRecord,
    ValidationSummary,
    oracle_steps,
    regrets,
)
from proxybench.tasks.metrics import METRICS as TASK_METRICS
from proxybench.usefulness.validation import METHODS, minimum_detectable_effect, pick, quality, selection_scores

__all__ = ["ValidationRun", "score_target", "summarize"]


@dataclass
class ValidationRun:
    """The settings, the criteria file and one record per target (picks, qualities of every candidate)."""

    settings: ValidateSettings
    criteria_file: Path
    records: list[TargetRecord]
    targets: list[Any]
    episodes_run: int = 0
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    indices: list[int] = field(default_factory=list)  # the target index of each record (an interim look skips some)
    #: what the pre-registration's checks found (empty: it holds; registration.check_registration)
    problems: list[str] = field(default_factory=list)
    scoring_unchanged: bool = True


def score_target(s: ValidateSettings, k: int, cands: list[dict[str, float]], target_a, target_b, prox_a: list,
                 prox_b: list, traj_err: list[float] | None) -> TargetRecord:
    """Each method's pick from the tuning agents, and the quality of every candidate on the held-out agents."""
    higher = tuple(TASK_METRICS[m].higher_is_better for m in s.metrics)
    qualities = [Quality(**quality(p, target_b, higher, k=s.top_k).as_dict()) for p in prox_b]
    nominal = proxy_params(tuple(s.image_size))
    nominal_index = next(c for c, theta in enumerate(cands)
                         if all(abs(theta[n] - float(getattr(nominal, n))) < 1e-9 for n in theta))
    tol = [s.tolerances[m] for m in s.metrics]
    picks, scores = {}, {}
    for method in s.methods:
        if method == "nominal":
            values = np.array([0.0 if c == nominal_index else 1.0 for c in range(len(cands))])
        elif method == "trajectory":
            values = np.asarray(traj_err if traj_err is not None else [np.nan] * len(cands), float)
        else:
            values = selection_scores(method, prox_a, target_a, higher, tolerances=tol, n_boot=s.n_boot,
                                      seed=s.seed + k)
        if not np.isfinite(values).any():
            continue
        index, ties = pick(np.where(np.isfinite(values), values, np.inf),
                           np.random.default_rng([s.seed, k, METHODS.index(method)]))
        picks[method] = Pick(index=index, ties=ties)
        scores[method] = [float(v) for v in values]
    return TargetRecord(candidates=cands, nominal_index=nominal_index, quality=qualities, picks=picks, scores=scores)


def summarize(run: ValidationRun, criteria: dict[str, Any] | None = None) -> ValidationSummary:
    """summary.json: per method, the regrets over targets (primary and secondary), each paired against the nominal
    θ, hit rates beside the nominal pick's; the criteria (``run.criteria_file``'s unless given) with what the
    pre-registration's checks found (``run.problems``). The targets' θ are revealed only when every target is
    finished: an interim look shows none."""
    from proxybench.experiments.reporting import source_commit
    from proxybench.usefulness.heldout_scoring import wilson
    from proxybench.usefulness.validation import compare

    s, recs = run.settings, run.records
    criteria = criteria if criteria is not None else json.loads(run.criteria_file.read_text())
    check = CriteriaCheck(written=criteria["written"], commit=criteria["commit"], commit_now=source_commit(),
                          scoring_unchanged=run.scoring_unchanged,
                          minimum_detectable_effect=criteria["minimum_detectable_effect"], problems=run.problems)
    methods = [m for m in s.methods if any(m in r.picks for r in recs)]
    nominal = {m: [regrets(r, "nominal", m) for r in recs] for m in QUALITIES}
    out: dict[str, MethodSummary] = {}
    for method in methods:
        measures = {}
        for measure in QUALITIES:
            rg = [regrets(r, method, measure) for r in recs]
            finite = np.asarray(rg, float)[np.isfinite(rg)]
            measures[measure] = MeasureSummary(
                mean_regret=float(finite.mean()) if finite.size else float("nan"),
                vs_nominal=compare(method, "nominal", rg, nominal[measure], seed=s.seed))
        hits = [oracle_steps(r, r.picks[method].index, s.grid) <= 1 for r in recs if method in r.picks]
        lo, hi = wilson(sum(hits), len(hits)) if hits else (float("nan"), float("nan"))
        out[method] = MethodSummary(**measures, hit_rate=HitRate(hits=int(sum(hits)), targets=len(hits), low=lo,
                                                                 high=hi),
                                    ties=float(np.mean([r.picks[method].ties for r in recs if method in r.picks])))
    interim = len(recs) < s.targets
    primary = None
    if "prpv" in out:
        first = out["prpv"].prpv_norm.vs_nominal
        # the registered settings' (criteria.json's, checked against them), or, at an interim look, what the
        # targets finished so far can detect, not what the full study will
        mde = minimum_detectable_effect(len(recs) if interim else s.targets, s.alpha, s.power)
        primary = Primary(**first.as_dict(), alpha=s.alpha, rejected=bool(first.p_wilcoxon < s.alpha), d_z=mde,
                          minimum_detectable_difference=float(mde * first.sd) if np.isfinite(first.sd)
                          else float("nan"))
    truths = []
    if not interim:  # the reveal waits for the final report
        indices = run.indices or list(range(len(recs)))
        reveal = [getattr(run.targets[i], "reveal", dict)() for i in indices]
        truths = [{k: v for k, v in tr.items() if k in s.grid or k in s.draw} for tr in reveal]
    return ValidationSummary(settings=s, targets=len(recs), interim=interim, methods=out, criteria=check,
                             primary=primary, truths=truths, wall_s=run.wall_s)
