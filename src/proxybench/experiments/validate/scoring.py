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

from proxybench.experiments.validate.config import ValidateSettings, nominal_theta, stratum_of
from proxybench.experiments.validate.measures import (
    QUALITIES,
    AgentLevel,
    ContinuousPick,
    Contribution,
    CriteriaCheck,
    HitRate,
    Interval,
    MeasureSummary,
    MethodSummary,
    Pick,
    Primary,
    PrimaryTest,
    Quality,
    SavingsSummary,
    TargetRecord,
    ValidationSummary,
    oracle_steps,
    qualities,
    regrets,
)
from proxybench.tasks.metrics import METRICS as TASK_METRICS
from proxybench.usefulness import calibration
from proxybench.usefulness.agent_resampling import prpv_agent_shares
from proxybench.usefulness.episodes_saved import episodes_saved
from proxybench.usefulness.metrics import agent_means, dominance_from_means
from proxybench.usefulness.validation import (
    CONTINUOUS,
    METHODS,
    holm,
    margin_test,
    minimum_detectable_effect,
    pick,
    quality,
    selection_scores,
)

__all__ = ["ValidationRun", "calibrated_theta", "score_target", "summarize"]


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


def calibrated_theta(s: ValidateSettings, straight: list[tuple[np.ndarray, ...]], step: list[tuple[np.ndarray, ...]],
                     *, per_trim: float, step_time: float, reason: str = "") -> ContinuousPick:
    """The ``calibration`` method's θ: trim from the straight drives ((t, x, y, θ) each), the command delay from the
    step drives ((t, x, y) each, the command stepped at ``step_time``), each the median over the drives, clipped
    to its draw range (the grid's range when it is not drawn); the grid's other parameters stay nominal (a drive
    cannot see a camera). Not applicable (``theta`` None, with the reason) when there is nothing to read."""
    if reason:
        return ContinuousPick(theta=None, reason=reason)
    if not straight and not step:
        return ContinuousPick(theta=None, reason="the target's drives carry no pose (a recording of scores only): "
                                                 "nothing to calibrate from")
    draw = s.proxy_draw()
    estimate = {"trim": float(np.nanmedian([calibration.trim_from_drive(*r, per_trim) for r in straight]))
                if straight else float("nan"),
                "command_delay": float(np.nanmedian([calibration.delay_from_step(*r, step_time) for r in step]))
                if step else float("nan")}
    theta = nominal_theta(s.grid)
    for name in theta:
        if name in estimate:
            if not np.isfinite(estimate[name]):
                return ContinuousPick(theta=None, estimate=estimate,
                                      reason=f"the drives did not move the robot enough to read its {name}")
            lo, hi = min(draw.get(name, s.grid[name])), max(draw.get(name, s.grid[name]))
            theta[name] = float(np.clip(estimate[name], lo, hi))
    return ContinuousPick(theta=theta, estimate=estimate)


def score_target(s: ValidateSettings, k: int, cands: list[dict[str, float]], target_a, target_b, prox_a: list,
                 prox_b: list, traj_err: list[float] | None,
                 continuous: dict[str, ContinuousPick] | None = None) -> TargetRecord:
    """Each method's pick from the tuning agents, and the quality of every candidate on the held-out agents.

    ``cands``: the grid (``prox_a``: the tuning agents in each), then the continuous picks' θ; ``prox_b``: the
    held-out agents in every candidate; ``traj_err``: the grid's trajectory errors; ``continuous``: per continuous
    method, its θ (one of ``cands``) or why it has none."""
    higher = tuple(TASK_METRICS[m].higher_is_better for m in s.metrics)
    qualities_b = [Quality(**quality(p, target_b, higher, k=s.top_k).as_dict()) for p in prox_b]
    grid_size = len(prox_a)
    nominal = nominal_theta(s.grid)
    nominal_index = next(c for c, theta in enumerate(cands[:grid_size])
                         if all(abs(theta[n] - nominal[n]) < 1e-9 for n in theta))
    tol = [s.tolerances[m] for m in s.metrics]
    picks, scores, not_applicable, estimates = {}, {}, {}, {}
    for method in s.methods:
        if method in CONTINUOUS:  # a θ of its own, judged like a candidate
            c = (continuous or {}).get(method) or ContinuousPick(theta=None, reason="not run")
            if c.estimate:
                estimates[method] = c.estimate
            if c.theta is None:
                not_applicable[method] = c.reason
                continue
            picks[method] = Pick(index=cands.index(c.theta), ties=1)
            scores[method] = [c.score]
            continue
        if method == "nominal":
            values = np.array([0.0 if c == nominal_index else 1.0 for c in range(grid_size)])
        elif method == "trajectory":
            values = np.asarray(traj_err if traj_err is not None else [np.nan] * grid_size, float)
        else:
            values = selection_scores(method, prox_a, target_a, higher, tolerances=tol, n_boot=s.n_boot,
                                      seed=s.seed + k)
        if not np.isfinite(values).any():
            not_applicable[method] = "no finite score on any candidate (for trajectory: no recorded poses)"
            continue
        index, ties = pick(np.where(np.isfinite(values), values, np.inf),
                           np.random.default_rng([s.seed, k, METHODS.index(method)]))
        picks[method] = Pick(index=index, ties=ties)
        scores[method] = [float(v) for v in values]
    agents = list(target_b)
    dom_t = dominance_from_means(agent_means(target_b, agents), higher)
    shares = [dict(zip(agents, map(float, prpv_agent_shares(dominance_from_means(agent_means(p, agents), higher),
                                                             dom_t)), strict=True)) for p in prox_b]
    savings = [episodes_saved({a: target_b[a] for a in agents}, p, tol, s.alpha) for p in prox_b]
    return TargetRecord(candidates=cands, nominal_index=nominal_index, quality=qualities_b, picks=picks,
                        scores=scores, grid_size=grid_size, not_applicable=not_applicable, estimates=estimates,
                        agent_shares=shares, savings=savings)


def primary_tests(s: ValidateSettings, recs: list[TargetRecord], strata: list[str] | None) -> list[PrimaryTest]:
    """The pre-registered primary comparison: per stratum (``strata``: each record's, from the hidden θ; None at
    an interim look: every record together, stratum ``all``) and calibration, PRPV − calibration in the quality of
    the pick on the held-out agents, against the margin."""
    if "prpv" not in s.methods:
        return []
    groups = ({"all": recs} if strata is None else
              {name: [r for r, st in zip(recs, strata, strict=True) if st == name] for name in s.primary.strata})
    cells, values, tests = [], [], []
    for other in (m for m in s.primary.comparisons if m in s.methods):
        for stratum, group in groups.items():
            pair = ([qualities(r, "prpv") for r in group], [qualities(r, other) for r in group])
            tests.append(margin_test("prpv", other, *pair, s.margin, alpha=s.alpha, power=s.power,
                                     fallback_sd=s.assumed_sd))
            values.append(pair)
            cells.append((stratum, sum(other in r.not_applicable for r in group)))
    if s.primary.multiplicity == "holm":
        tests = holm(tests, values, s.alpha, fallback_sd=s.assumed_sd)
    return [PrimaryTest(**test.as_dict(), stratum=stratum, not_applicable=skipped)
            for test, (stratum, skipped) in zip(tests, cells, strict=True)]


def _comparisons(s: ValidateSettings) -> list[tuple[str, str]]:
    """PRPV against the nominal θ and against each calibration of the primary comparison that the study ran."""
    return [("prpv", "nominal"), *(("prpv", m) for m in s.primary.comparisons if m in s.methods)]


def _interval(r: Any) -> Interval:
    return Interval(value=r.mean, low=r.low, high=r.high, resampled=r.resample + (" (families)" if r.by_family else ""),
                    n_targets=r.n_targets, n_agents=r.n_agents)


def agent_level(s: ValidateSettings, recs: list[TargetRecord]) -> dict[str, AgentLevel]:
    """Per comparison a − b: the gain in held-out PRPV/K(K−1) built from each held-out agent's share (so that the
    pool, not only the targets, is a sample), resampled over targets alone and over targets and agent families
    (:mod:`proxybench.usefulness.agent_resampling`), and each agent's leave-one-out contribution."""
    from proxybench.agents.families import family_map
    from proxybench.usefulness.agent_resampling import ContributionTable, agent_contributions, two_way_bootstrap

    out = {}
    for a, b in _comparisons(s):
        rows = [(str(k), agent, share - r.agent_shares[r.picks[b].index][agent])
                for k, r in enumerate(recs) if a in r.picks and b in r.picks and r.agent_shares
                for agent, share in r.agent_shares[r.picks[a].index].items()
                if np.isfinite(share - r.agent_shares[r.picks[b].index][agent])]
        if len({t for t, _, _ in rows}) < 2:
            continue
        table = ContributionTable.from_records(rows)
        families = family_map(table.agents)
        contributions = sorted(agent_contributions(table, groups=families, seed=s.seed), key=lambda c: -abs(c.loo))
        out[f"{a}-{b}"] = AgentLevel(
            targets_only=_interval(two_way_bootstrap(table, resample="targets", seed=s.seed)),
            targets_and_families=_interval(two_way_bootstrap(table, groups=families, seed=s.seed)),
            contributions=[Contribution(agent=c.agent, family=c.family or "", held_out=c.n_targets, loo=c.loo,
                                        low=c.low, high=c.high) for c in contributions])
    return out


def _median_interval(values: np.ndarray, seed: int) -> tuple[float, float, float]:
    """The median and its 95 % percentile bootstrap interval over targets."""
    rng = np.random.default_rng([seed, 0x5A7E])
    boots = np.median(values[rng.integers(0, len(values), (2000, len(values)))], axis=1)
    med = float(np.median(values))
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return med, min(float(lo), med), max(float(hi), med)


def savings_summary(s: ValidateSettings, recs: list[TargetRecord]) -> dict[str, SavingsSummary]:
    """Per method: the share of target episodes its pick saves as PPI++'s predictor for deciding the held-out pairs
    (median over targets, bootstrap interval), the episodes per agent a decided pair needs with and without it, and
    the paired difference in saved share against the nominal θ's proxy."""
    from proxybench.usefulness.validation import compare

    def saved(r: TargetRecord, m: str) -> float:
        return r.savings[r.picks[m].index].saved_share if m in r.picks and r.savings else float("nan")

    out = {}
    for m in (x for x in s.methods if any(x in r.picks for r in recs)):
        mine = np.array([saved(r, m) for r in recs])
        ok = np.isfinite(mine)
        if ok.sum() < 2:
            continue
        med, lo, hi = _median_interval(mine[ok], s.seed)
        used = [r for r, good in zip(recs, ok, strict=True) if good]
        alone = np.nanmedian([r.savings[r.picks[m].index].episodes_alone for r in used])
        with_p = np.nanmedian([r.savings[r.picks[m].index].episodes_with for r in used])
        vs = None
        if m != "nominal":
            c = compare(m, "nominal", mine, [saved(r, "nominal") for r in recs], seed=s.seed)
            vs = Interval(value=c.mean, low=c.low, high=c.high, resampled="targets", n_targets=c.n)
        out[m] = SavingsSummary(targets=int(ok.sum()),
                                saved_share=Interval(value=med, low=lo, high=hi, resampled="targets (median)",
                                                     n_targets=int(ok.sum())),
                                episodes_alone=float(alone), episodes_with=float(with_p), vs_nominal=vs)
    return out


def _planned(s: ValidateSettings) -> dict[str, dict[str, float | None]]:
    """Per stratum: the targets the plan expects in it and the margin they can show (:meth:`StratumPlan.planned`)."""
    out = {}
    for name, st in s.primary.strata.items():
        n, mde = st.planned(s.targets, s.primary.level(s.alpha), s.power, s.assumed_sd)
        out[name] = {"targets": n, "mde": mde}
    return out


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
    methods = [m for m in s.methods if any(m in r.picks or m in r.not_applicable for r in recs)]
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
        ties = [r.picks[method].ties for r in recs if method in r.picks]
        reasons = [r.not_applicable[method] for r in recs if method in r.not_applicable]
        out[method] = MethodSummary(**measures, hit_rate=HitRate(hits=int(sum(hits)), targets=len(hits), low=lo,
                                                                 high=hi),
                                    ties=float(np.mean(ties)) if ties else float("nan"),
                                    not_applicable=len(reasons), reasons=sorted(set(reasons)))
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
    truths, strata = [], []
    if not interim:  # the reveal (θ and with it each target's stratum) waits for the final report
        indices = run.indices or list(range(len(recs)))
        reveal = [getattr(run.targets[i], "reveal", dict)() for i in indices]
        truths = [{k: v for k, v in tr.items() if k in s.grid or k in s.draw} for tr in reveal]
        strata = [stratum_of(s.to_proxy(tr), s.near) for tr in reveal]
    return ValidationSummary(settings=s, targets=len(recs), interim=interim, methods=out, criteria=check,
                             primary_tests=primary_tests(s, recs, None if interim else strata), primary=primary,
                             planned=_planned(s),
                             truths=truths, strata=strata, agent_level=agent_level(s, recs),
                             savings=savings_summary(s, recs), wall_s=run.wall_s)
