"""Ranking agents: a lexicographic semiorder (AIDO's scoring rule) and Pareto dominance matrices.

AIDO ranks submissions by an ordered list of criteria, each with a tolerance: agent x beats y on the
first criterion where they differ by *more* than its tolerance; differences within the tolerance are
treated as noise and the next criterion decides. Such a relation is a *semiorder*: it is antisymmetric,
but "tied within tolerance" is not transitive (a ~ b and b ~ c while a beats c), and with several
criteria even "beats" can form cycles. :func:`leaderboard` therefore ranks by Copeland score.

:func:`dominance_matrix` is the Pareto relation over several metrics that the usefulness measure PRPV
compares between two domains (1 / 0 / 0.5 for dominates / dominated / incomparable or equal).

NaN values (a metric that could not be computed) count as the *worst* possible value in every
comparison, whatever the direction and tolerance: a NaN never beats a number, two NaNs tie. This is the
project's one rule for missing values: an *episode* without a value is left out of its agent's statistics
(:mod:`proxybench.tasks.aggregate`), an *agent* without any value is worst on that metric — here and in
PRPV's dominance matrices (:mod:`proxybench.usefulness.metrics`); docs/usefulness.md gives the reasons.

>>> crit = [Criterion("distance_mean", True, 0.5), Criterion("survival_time_mean", True, 1.0)]
>>> scores = {"a": {"distance_mean": 10.0, "survival_time_mean": 50.0},
...           "b": {"distance_mean": 10.3, "survival_time_mean": 60.0},
...           "c": {"distance_mean": 2.0, "survival_time_mean": 60.0}}
>>> compare(scores["a"], scores["b"], crit)   # distance within 0.5 m: survival decides
-1
>>> [(r.rank, r.agent) for r in leaderboard(scores, crit)]
[(1, 'b'), (2, 'a'), (3, 'c')]
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Criterion", "Rank", "better", "compare", "copeland_counts", "dominance_matrix", "leaderboard",
           "semiorder_matrix"]

Scores = Mapping[str, float]


@dataclass(frozen=True)
class Criterion:
    """One scoring criterion: a (usually aggregated) metric name, its direction and its tolerance.

    ``tolerance`` is in the metric's unit: differences up to it count as a tie on this criterion.
    """

    metric: str
    higher_is_better: bool = True
    tolerance: float = 0.0

    def __post_init__(self) -> None:
        if not self.metric:
            raise ValueError("a criterion needs a metric name")
        if not (isinstance(self.tolerance, (int, float)) and self.tolerance >= 0):  # also rejects NaN
            raise ValueError(f"criterion {self.metric!r}: tolerance must be a number >= 0, got {self.tolerance!r}")

    @property
    def direction(self) -> str:
        return "↑" if self.higher_is_better else "↓"


@dataclass(frozen=True)
class Rank:
    """One leaderboard row. ``rank`` is shared by agents with equal ``copeland`` score ("1, 1, 3").

    ``copeland`` = ``wins`` − ``losses`` over all pairwise :func:`compare` results.
    """

    rank: int
    agent: Hashable
    copeland: int
    wins: int
    losses: int
    ties: int


def better(a: float, b: float, higher_is_better: bool, tolerance: float = 0.0) -> int:
    """+1 if value ``a`` beats ``b`` by more than ``tolerance``, −1 if ``b`` beats ``a``, else 0; NaN is worst."""
    a_nan, b_nan = math.isnan(a), math.isnan(b)
    if a_nan or b_nan:
        return int(b_nan) - int(a_nan)
    gain = (a - b) if higher_is_better else (b - a)
    if gain > tolerance:  # inf - inf is NaN: equal infinities compare as a tie
        return 1
    if gain < -tolerance:
        return -1
    return 0


def _value(scores: Scores, metric: str) -> float:
    try:
        return float(scores[metric])
    except KeyError:
        raise KeyError(f"no score for {metric!r}; have {', '.join(map(str, scores)) or 'none'}") from None


def compare(x: Scores, y: Scores, criteria: Sequence[Criterion]) -> int:
    """+1 if ``x`` beats ``y``, −1 if ``y`` beats ``x``, 0 if they tie within tolerance on every criterion.

    The first criterion on which one is better by more than the tolerance decides (lexicographic
    semiorder); with all tolerances 0 this is plain lexicographic order with the directions applied.
    """
    for c in criteria:
        verdict = better(_value(x, c.metric), _value(y, c.metric), c.higher_is_better, c.tolerance)
        if verdict:
            return verdict
    return 0


def _matrix(agents: list, pair: Callable[[int, int], int]) -> np.ndarray:
    """(K, K) matrix of 1 / 0 / 0.5 from ``pair(i, j)`` ∈ {+1, −1, 0}; diagonal 0.5."""
    k = len(agents)
    d = np.full((k, k), 0.5)
    for i in range(k):
        for j in range(i + 1, k):
            v = pair(i, j)
            if v:
                d[i, j], d[j, i] = (1.0, 0.0) if v > 0 else (0.0, 1.0)
    return d


def _check_complete(scores: Mapping[Hashable, Scores], metrics: Sequence[str]) -> None:
    """Fail before comparing anything when an agent lacks a metric, naming the agent."""
    for agent, s in scores.items():
        missing = [m for m in metrics if m not in s]
        if missing:
            raise KeyError(f"agent {agent!r} has no score for {', '.join(missing)}")


def semiorder_matrix(scores: Mapping[Hashable, Scores], criteria: Sequence[Criterion]) -> tuple[list, np.ndarray]:
    """Agents (input order) and D with D[i, j] = 1 if i beats j under :func:`compare`, 0 if j beats i, else 0.5.

    Computed for all pairs at once (array operations, one pass per criterion): a leaderboard of
    hundreds of submissions is re-ranked in milliseconds. Same verdicts as :func:`compare` (tested).
    """
    _check_complete(scores, [c.metric for c in criteria])
    agents = list(scores)
    values = np.array([[_value(scores[a], c.metric) for c in criteria] for a in agents], dtype=float)
    verdict = _semiorder_verdicts(values.reshape(len(agents), len(criteria)), criteria)
    d = np.full(verdict.shape, 0.5)
    d[verdict > 0] = 1.0
    d[verdict < 0] = 0.0
    return agents, d


def _semiorder_verdicts(values: np.ndarray, criteria: Sequence[Criterion]) -> np.ndarray:
    """(K, K) of +1 / −1 / 0: :func:`compare` of every pair of rows of ``values`` (K agents × criteria)."""
    k = values.shape[0]
    out = np.zeros((k, k), dtype=np.int8)
    undecided = np.ones((k, k), dtype=bool)
    for col, c in enumerate(criteria):
        v = values[:, col]
        nan = np.isnan(v)
        with np.errstate(invalid="ignore"):  # inf − inf is NaN: equal infinities tie, as in better()
            gain = v[:, None] - v[None, :]
            if not c.higher_is_better:
                gain = -gain  # exact: fl(b − a) = −fl(a − b)
            verdict = np.where(gain > c.tolerance, 1, np.where(gain < -c.tolerance, -1, 0))
        either_nan = nan[:, None] | nan[None, :]
        verdict = np.where(either_nan, nan[None, :].astype(int) - nan[:, None].astype(int), verdict)
        decides = undecided & (verdict != 0)
        out[decides] = verdict[decides]
        undecided &= ~decides
    return out


def copeland_counts(values: np.ndarray, criteria: Sequence[Criterion]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(wins, losses, ties) of each row of ``values`` (K agents × criteria) against all others under
    :func:`compare`: the counts :func:`semiorder_matrix` gives, in O(K) memory. A compiled pair loop that
    stops at the first deciding criterion: a 3,000-entry server leaderboard in tens of milliseconds (the
    K × K matrices took seconds and hundreds of MiB).
    """
    from proxybench.tasks._copeland import copeland_kernel

    higher = np.array([c.higher_is_better for c in criteria], dtype=np.bool_)
    tol = np.array([c.tolerance for c in criteria], dtype=np.float64)
    return copeland_kernel(np.ascontiguousarray(values, dtype=np.float64), higher, tol)


def _pareto(x: Scores, y: Scores, metrics: Sequence[tuple[str, bool]]) -> int:
    """+1 if x is at least as good on every metric and better on one, −1 for the reverse, else 0."""
    verdicts = [better(_value(x, m), _value(y, m), hib) for m, hib in metrics]
    if any(v > 0 for v in verdicts) and not any(v < 0 for v in verdicts):
        return 1
    if any(v < 0 for v in verdicts) and not any(v > 0 for v in verdicts):
        return -1
    return 0


def dominance_matrix(scores: Mapping[Hashable, Scores], metrics: Sequence[tuple[str, bool]]) -> tuple[list, np.ndarray]:
    """Agents (input order) and the Pareto dominance matrix over ``metrics`` = [(name, higher_is_better)].

    D[i, j] = 1 if agent i dominates j (at least as good on all metrics, strictly better on one), 0 if j
    dominates i, 0.5 if they are incomparable or equal (and on the diagonal), so D + Dᵀ = 1. PRPV is the
    1-norm of the difference of two such matrices, so give both domains' agents in the same order.
    """
    _check_complete(scores, [m for m, _ in metrics])
    agents = list(scores)
    return agents, _matrix(agents, lambda i, j: _pareto(scores[agents[i]], scores[agents[j]], metrics))


def leaderboard(scores: Mapping[Hashable, Scores], criteria: Sequence[Criterion]) -> list[Rank]:
    """Agents ranked by Copeland score (pairwise wins − losses under :func:`compare`), best first.

    Why Copeland: the semiorder need not be transitive, so there may be no order consistent with every
    pairwise verdict; counting pairwise wins is deterministic, agrees with the order whenever it is
    transitive, and never separates agents that compare equally against everyone. Agents with equal
    scores share a rank and are listed by name (``str(agent)``), then input order — so the result does
    not depend on the mapping's order. Note an agent may beat a higher-ranked one when the relation
    has cycles.
    """
    _check_complete(scores, [c.metric for c in criteria])
    agents = list(scores)
    values = np.array([[_value(scores[a], c.metric) for c in criteria] for a in agents], dtype=float)
    wins, losses, ties = copeland_counts(values.reshape(len(agents), len(criteria)), criteria)
    order = sorted(range(len(agents)), key=lambda i: (-(wins[i] - losses[i]), str(agents[i]), i))
    rows: list[Rank] = []
    for pos, i in enumerate(order):
        cope = int(wins[i] - losses[i])
        rank = rows[-1].rank if rows and rows[-1].copeland == cope else pos + 1
        rows.append(Rank(rank, agents[i], cope, int(wins[i]), int(losses[i]), int(ties[i])))
    return rows
