"""The validation study's typed records and summary: what one target gave (:class:`TargetRecord`, a file in
``targets/`` each) and what the study concludes (:class:`ValidationSummary`, ``summary.json``): per method, the
regrets over targets paired against the nominal θ, hit rates, and the pre-registered primary test. Glue only: the
measures are :mod:`proxybench.usefulness.validation`'s; the report reads these models and nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, computed_field

from proxybench.experiments.validate.config import ValidateSettings
from proxybench.usefulness.episodes_saved import EpisodeSavings
from proxybench.usefulness.validation import Comparison, Margin

__all__ = ["QUALITIES", "AgentLevel", "ContinuousPick", "Contribution", "HitRate", "Interval", "MeasureSummary",
           "MethodSummary", "Pick", "Primary", "PrimaryTest", "Quality", "SavingsSummary", "TargetRecord",
           "ValidationSummary", "oracle_steps", "qualities", "regrets"]  # Comparison, Margin: usefulness.validation's

QUALITIES = ("prpv_norm", "kendall_gap", "top1_regret", "topk_regret")


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, use_attribute_docstrings=True)


class Quality(_Model):
    """How well one candidate θ orders the held-out agents on fresh target episodes (lower is better)."""

    prpv_norm: float
    kendall_gap: float
    top1_regret: float
    topk_regret: float


class Pick(_Model):
    """A method's pick: the candidate's index and how many candidates tied with it (broken at random)."""

    index: int
    ties: int


class ContinuousPick(_Model):
    """A continuous method's θ on one target (trajectory_fit, calibration), or why it has none."""

    theta: dict[str, float] | None
    """the picked θ over the grid's parameters (None: not applicable)"""
    score: float = float("nan")
    """the method's own objective there (trajectory_fit: the mean trajectory error [m])"""
    estimate: dict[str, float] = {}
    """what the method measured before clipping to the draw range (calibration: trim, command_delay)"""
    reason: str = ""
    """why the method is not applicable on this target"""


class TargetRecord(_Model):
    """One target of the study: the candidates (the grid, then the continuous methods' picks), each method's pick
    from the tuning agents, every candidate's quality on the held-out agents, and what ran (``targets/NNN.json``).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    candidates: list[dict[str, float]]
    nominal_index: int
    quality: list[Quality]
    picks: dict[str, Pick]
    scores: dict[str, list[float]]
    grid_size: int = 0
    """the grid's candidates come first (the oracle is the best of them); after them, the continuous picks (0: all
    are the grid's)"""
    not_applicable: dict[str, str] = {}
    """per method that could not pick on this target: why (a target without poses has no calibration)"""
    estimates: dict[str, dict[str, float]] = {}
    """per continuous method, what it measured before clipping (calibration: trim, command_delay)"""
    agent_shares: list[dict[str, float]] = []
    """per candidate, each held-out agent's share of its PRPV/K(K−1) (their mean is the candidate's quality): the
    per-agent contributions the agent-level resampling reads"""
    savings: list[EpisodeSavings] = []
    """per candidate, its worth in target episodes for deciding the held-out agents' pairs on E2
    (:func:`proxybench.usefulness.episodes_saved.episodes_saved`; NaN with fewer than 3 episodes per agent)"""
    target: str = ""
    map: str = ""
    tuning_agents: list[str] = []
    heldout_agents: list[str] = []
    seed: int = 0
    episodes_run: int = 0
    settings_key: str = ""

    def values(self, measure: str) -> np.ndarray:
        """Every candidate's quality in ``measure`` (one of :data:`QUALITIES`)."""
        return np.array([getattr(q, measure) for q in self.quality], float)

    def oracle(self, measure: str) -> float:
        """The oracle's quality: the best grid candidate's in hindsight (continuous picks are not candidates of the
        oracle, so their regret can be negative)."""
        return float(np.nanmin(self.values(measure)[: self.grid_size or None]))


def qualities(rec: TargetRecord, method: str, measure: str = "prpv_norm") -> float:
    """The quality of ``method``'s pick on one target (NaN where it did not pick)."""
    if method not in rec.picks:
        return float("nan")
    return float(rec.values(measure)[rec.picks[method].index])


def regrets(rec: TargetRecord, method: str, measure: str = "prpv_norm") -> float:
    """The regret of ``method``'s pick on one target: its quality minus the oracle's (the best grid candidate in
    hindsight; below 0 for a continuous pick better than every grid candidate)."""
    if method not in rec.picks:
        return float("nan")
    return qualities(rec, method, measure) - rec.oracle(measure)


def oracle_steps(rec: TargetRecord, index: int, grid: dict[str, tuple[float, ...]]) -> int:
    """Grid steps (the largest along any axis) from candidate ``index`` to the nearest oracle candidate."""
    values = rec.values("prpv_norm")[: rec.grid_size or None]
    oracles = np.flatnonzero(np.isclose(values, np.nanmin(values)))
    pos = {n: {round(v, 9): i for i, v in enumerate(vals)} for n, vals in grid.items()}

    def where(c: int) -> list[float]:
        theta = rec.candidates[c]
        return [pos[n].get(round(theta[n], 9), np.searchsorted(vals, theta[n]) - 0.5) for n, vals in grid.items()]

    here = np.array(where(index), float)
    return int(min(np.max(np.abs(here - np.array(where(o), float))) for o in oracles))


class MeasureSummary(_Model):
    """One quality measure of a method: its mean regret and its paired comparison with the nominal θ."""

    mean_regret: float
    vs_nominal: Comparison


class HitRate(_Model):
    """Targets where the pick lies within one grid step of an oracle θ, with a Wilson interval."""

    hits: int
    targets: int
    low: float
    high: float


class MethodSummary(_Model):
    """A method over all targets: each quality measure, its hit rate and its mean number of tied candidates."""

    prpv_norm: MeasureSummary
    kendall_gap: MeasureSummary
    top1_regret: MeasureSummary
    topk_regret: MeasureSummary
    hit_rate: HitRate
    ties: float
    not_applicable: int = 0
    """targets where the method could not pick (left out of its comparisons)"""
    reasons: list[str] = []
    """why, each reason once"""


class CriteriaCheck(_Model):
    """What criteria.json pre-registered, and what the checks of the pre-registration found."""

    written: str
    commit: str
    commit_now: str
    scoring_unchanged: bool
    minimum_detectable_effect: dict[str, Any]
    problems: list[str] = []
    """what the checks found: the look log's chain broken, a record or the criteria edited, the scoring code
    changed, the criteria newer than cached episodes (empty: the pre-registration holds)"""

    @property
    def intact(self) -> bool:
        return not self.problems


@dataclass(frozen=True)
class Primary(Comparison):
    """The pre-registered test: PRPV's regret against the nominal θ's, at ``alpha``."""

    alpha: float
    rejected: bool
    d_z: float
    minimum_detectable_difference: float


@dataclass(frozen=True)
class PrimaryTest(Margin):
    """One primary test: PRPV − a calibration in one stratum (``all``: every target, the only one an interim look
    shows), against the margin."""

    stratum: str
    not_applicable: int  # targets of the stratum where the calibration could not pick (left out)


class Interval(_Model):
    """A point estimate with its percentile bootstrap interval and what was resampled."""

    value: float
    low: float
    high: float
    resampled: str
    n_targets: int
    n_agents: int = 0


class Contribution(_Model):
    """One held-out agent's leave-one-out share of a gain (negative: it makes PRPV look better)."""

    agent: str
    family: str
    held_out: int
    loo: float
    low: float
    high: float


class AgentLevel(_Model):
    """A gain (PRPV's pick − another method's, in held-out PRPV/K(K−1)) with targets alone resampled and with
    targets *and* agent families resampled, and the agents it rests on most."""

    targets_only: Interval
    targets_and_families: Interval
    contributions: list[Contribution]
    """every held-out agent, largest |loo| first"""


class SavingsSummary(_Model):
    """A method's proxy (its pick on each target) as the predictor for deciding the held-out pairs: the median over
    targets of the share of target episodes it saves, and of the episodes per agent a decided pair needs."""

    targets: int
    saved_share: Interval
    episodes_alone: float
    episodes_with: float
    vs_nominal: Interval | None = None
    """mean paired difference in saved share, this method's pick − the nominal θ (positive: it saves more)"""


class ValidationSummary(_Model):
    """``summary.json``: the study's conclusion, per method, with the primary test (absent when PRPV picked on no
    target) and the targets' revealed θ."""

    settings: ValidateSettings
    """the study's settings, as criteria.json pre-registered them"""
    targets: int
    """targets finished (and summarised)"""
    interim: bool
    """fewer finished than planned: an interim look, no decision"""
    methods: dict[str, MethodSummary]
    """per selection method, its regrets against the nominal θ's"""
    criteria: CriteriaCheck
    """what was pre-registered, checked against the code that scored"""
    primary_tests: list[PrimaryTest] = []
    """the pre-registered primary comparison: PRPV − each calibration per stratum (near, far) in the final report;
    at an interim look over every target finished (stratum ``all``), no stratum shown"""
    primary: Primary | None = None
    """the secondary test PRPV − nominal θ, as the first study registered it (None where PRPV picked on no target)"""
    strata: list[str] = []
    """each target's stratum (near, far), from its hidden θ: in the final report only"""
    planned: dict[str, dict[str, float | None]] = {}
    """per stratum, from the criteria's plan and the targets registered: the targets expected in it and the margin
    that many can show with the declared power at the assumed SD (``mde``)"""
    truths: list[dict[str, float]] = []
    """each target's θ, revealed after scoring, in the final report only (empty at an interim look)"""
    agent_level: dict[str, AgentLevel] = {}
    """per comparison (``prpv-nominal``, ``prpv-calibration``, …): the gain resampled over targets and agent
    families, and each held-out agent's contribution"""
    savings: dict[str, SavingsSummary] = {}
    """per method: target episodes its proxy saves when deciding the held-out pairs (the secondary endpoint of
    issue 35 item 6); the nominal θ's too"""

    @computed_field  # type: ignore[prop-decorator]
    @property
    def family(self) -> str:
        """the target family"""
        return self.settings.family

    @computed_field  # type: ignore[prop-decorator]
    @property
    def targets_planned(self) -> int:
        """targets pre-registered"""
        return self.settings.targets
    wall_s: float = 0.0
