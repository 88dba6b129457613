"""Scoring the validation study: which θ each method picks from the tuning agents, and how well that proxy then
orders agents it never saw, on target episodes it never saw (``proxybench validate``, docs/validate.md).

Per target, candidates θ_c (a grid and the nominal calibration) are scored with the *tuning* agents A on
target episodes E1; each method picks the candidate it likes best. The picked proxy is then judged on the
*held-out* agents B on fresh target episodes E2 by a quality Q (lower is better):

- **primary**: PRPV/K(K−1) of the proxy's order of B against the target's (all task metrics, dominance);
- secondary: 1 − Kendall τ_b of the B agents' means on the first task metric, and the regret of picking the
  top agent (and the top k) of B with the proxy, in that metric's unit.

The **regret** of a pick is Q(pick) − Q(oracle), the oracle being the candidate with the lowest Q in
hindsight. The target is the unit of analysis: :func:`compare` gives the paired differences of two methods'
regrets over targets with a bootstrap interval and one-sided tests (Wilcoxon signed-rank and paired t), and
:func:`minimum_detectable_effect` the effect a study of n targets can see, declared before it runs.

>>> import numpy as np
>>> target = {"a": np.array([[3.0], [3.1]]), "b": np.array([[2.0], [2.1]]), "c": np.array([[1.0], [1.2]])}
>>> good = target
>>> bad = {"a": np.array([[1.0], [1.0]]), "b": np.array([[2.0], [2.0]]), "c": np.array([[3.0], [3.0]])}
>>> scores = selection_scores("prpv", [good, bad], target, (True,))
>>> scores.tolist()
[0.0, 6.0]
>>> quality(bad, target, (True,)).prpv_norm
1.0
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, replace

import numpy as np

from proxybench.usefulness.intervals import usefulness
from proxybench.usefulness.metrics import (
    PairedResults,
    agent_means,
    alpha_from_signs,
    dominance_from_means,
    pair_signs,
    resampled_means,
)

__all__ = ["CONTINUOUS", "METHODS", "Comparison", "Margin", "Quality", "compare", "holm", "margin_test",
           "minimum_detectable_effect", "pick", "quality", "selection_scores", "targets_needed", "trajectory_error"]

Results = Mapping[str, np.ndarray]

#: the ways of choosing θ from the tuning agents; "trajectory" (trajectory matching on the grid), "trajectory_fit"
#: (trajectory matching over continuous θ), "calibration" (scripted drives on the target, no simulator) and
#: "nominal" are scored by the study itself (replays of the target's commands; drives; no target data)
METHODS = ("prpv", "eps_prpv", "prob_prpv", "ppv", "pearson", "spearman", "kendall", "mmrv", "trajectory",
           "trajectory_fit", "calibration", "nominal")
#: the methods whose pick is a continuous θ, not a grid candidate (judged like one: replayed on the held-out agents)
CONTINUOUS = ("trajectory_fit", "calibration")


@dataclass(frozen=True)
class Quality:
    """How well a proxy orders agents against the target (every field: lower is better)."""

    prpv_norm: float  # PRPV / K(K−1) over the task metrics
    kendall_gap: float  # 1 − Kendall τ_b of the agents' means on the first metric
    top1_regret: float  # target score of the true best agent − of the proxy's best (first metric, its unit)
    topk_regret: float  # the same for the mean of the top k

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def _signed(means: np.ndarray, higher: Sequence[bool]) -> np.ndarray:
    return means * np.where(np.asarray(higher, bool), 1.0, -1.0)


def _kendall_b(x: np.ndarray, y: np.ndarray) -> float:
    from scipy.stats import kendalltau

    if np.ptp(x) == 0 or np.ptp(y) == 0:
        return 0.0
    return float(kendalltau(x, y).statistic)


def _top_mean(order_by: np.ndarray, values: np.ndarray, k: int) -> float:
    """Mean of ``values`` over the k entries ``order_by`` ranks highest (ties at the cut share the places)."""
    k = min(k, len(values))
    cut = np.sort(order_by)[::-1][k - 1]
    above = order_by > cut
    tied = order_by == cut
    return float((values[above].sum() + values[tied].mean() * (k - above.sum())) / k)


def quality(proxy: Results, target: Results, higher: Sequence[bool], *, k: int = 3) -> Quality:
    """:class:`Quality` of ``proxy`` against ``target`` over the agents of ``target``."""
    agents = list(target)
    pm, tm = agent_means(proxy, agents), agent_means(target, agents)
    n = len(agents)
    prpv = float(np.abs(dominance_from_means(pm, higher) - dominance_from_means(tm, higher)).sum())
    ps, ts = _signed(pm, higher)[:, 0], _signed(tm, higher)[:, 0]
    ps, ts = np.nan_to_num(ps, nan=-np.inf), np.nan_to_num(ts, nan=-np.inf)
    finite_t = np.where(np.isfinite(ts), ts, np.nanmin(np.where(np.isfinite(ts), ts, np.nan)) - 1.0)
    top1 = float(finite_t.max() - _top_mean(ps, finite_t, 1))
    topk = float(_top_mean(finite_t, finite_t, k) - _top_mean(ps, finite_t, k))
    return Quality(prpv / max(n * (n - 1), 1), 1.0 - _kendall_b(np.where(np.isfinite(ps), ps, -1e9), finite_t),
                   top1, topk)


def _eps_signs(means: np.ndarray, higher: Sequence[bool], tolerances: np.ndarray) -> np.ndarray:
    """:func:`pair_signs` with differences within each metric's tolerance counted as ties (a semiorder)."""
    s = pair_signs(means, higher)
    signed = _signed(means, higher)
    with np.errstate(invalid="ignore"):
        close = np.abs(signed[..., :, None, :] - signed[..., None, :, :]) <= tolerances
    return np.where(close & np.isfinite(signed[..., :, None, :]) & np.isfinite(signed[..., None, :, :]), 0.0, s)


def _prob_alpha(res: Results, agents: list[str], higher: Sequence[bool], n_boot: int, seed: int) -> np.ndarray:
    """α_ij = P(agent i dominates j) under a bootstrap of each agent's episodes (0.5 weight for ties)."""
    rng = np.random.default_rng(seed)
    means = np.stack([resampled_means(np.asarray(res[a], float), rng.integers(0, len(res[a]), (n_boot, len(res[a]))))
                      for a in agents], 1)
    return dominance_from_means(means, higher).mean(0)


def selection_scores(method: str, proxies: Sequence[Results], target: Results, higher: Sequence[bool], *,
                     tolerances: Sequence[float] | None = None, n_boot: int = 100, seed: int = 0) -> np.ndarray:
    """One score per candidate proxy (lower: the method likes it better) from the tuning agents' results.

    ``prpv``: PRPV; ``eps_prpv``: PRPV with pairs within ``tolerances`` (per metric) counted as ties in both
    domains; ``prob_prpv``: Σ|P^proxy(i ≻ j) − P^target(i ≻ j)| with the probabilities from a bootstrap of the
    episodes; ``ppv``: mean per-agent PPV; ``pearson`` / ``spearman`` / ``kendall``: minus the mean correlation;
    ``mmrv``: scaled MMRV.
    """
    agents = list(target)
    tm = agent_means(target, agents)
    if method == "prpv":
        return np.array([float(np.abs(dominance_from_means(agent_means(p, agents), higher)
                                      - dominance_from_means(tm, higher)).sum()) for p in proxies])
    if method == "eps_prpv":
        tol = np.asarray(tolerances if tolerances is not None else np.zeros(len(higher)), float)
        at = alpha_from_signs(_eps_signs(tm, higher, tol))
        return np.array([float(np.abs(alpha_from_signs(_eps_signs(agent_means(p, agents), higher, tol)) - at).sum())
                         for p in proxies])
    if method == "prob_prpv":
        at = _prob_alpha(target, agents, higher, n_boot, seed)
        return np.array([float(np.abs(_prob_alpha(p, agents, higher, n_boot, seed + 1) - at).sum()) for p in proxies])
    if method in ("ppv", "pearson", "spearman", "kendall", "mmrv"):
        key = {"mmrv": "mmrv_scaled"}.get(method, method)
        sign = -1.0 if method in ("pearson", "spearman", "kendall") else 1.0
        out = []
        for p in proxies:
            v = usefulness(PairedResults(dict(p), dict(target), tuple(higher)), n_boot=10, seed=seed)[key].value
            out.append(sign * v if np.isfinite(v) else np.inf)
        return np.asarray(out, float)
    raise ValueError(f"unknown selection method {method!r}; known: {', '.join(METHODS)}")


def pick(scores: np.ndarray, rng: np.random.Generator) -> tuple[int, int]:
    """(index of the lowest score, how many candidates tie there); ties broken at random (seeded)."""
    scores = np.asarray(scores, float)
    best = np.flatnonzero(np.isclose(scores, np.nanmin(scores), rtol=1e-12, atol=1e-12))
    return int(rng.choice(best)), len(best)


@dataclass(frozen=True)
class Comparison:
    """Paired differences of a regret over targets: method a − method b (negative: a is better)."""

    a: str
    b: str
    n: int
    mean: float
    low: float  # 95 % percentile bootstrap over targets
    high: float
    wins: int  # targets where a's regret is lower
    losses: int
    ties: int
    p_wilcoxon: float  # one-sided: a's regret lower than b's
    p_t: float  # one-sided paired t-test
    sd: float  # standard deviation of the paired differences

    def as_dict(self) -> dict[str, float | int | str]:
        return asdict(self)


def compare(a: str, b: str, regret_a: Sequence[float], regret_b: Sequence[float], *, n_boot: int = 2000,
            seed: int = 0, level: float = 0.95) -> Comparison:
    """The paired comparison of two methods' regrets over the same targets."""
    from scipy.stats import ttest_1samp, wilcoxon

    d = np.asarray(regret_a, float) - np.asarray(regret_b, float)
    d = d[np.isfinite(d)]
    n = len(d)
    if n == 0:
        nan = float("nan")
        return Comparison(a, b, 0, nan, nan, nan, 0, 0, 0, nan, nan, nan)
    rng = np.random.default_rng([seed, 0x5A11])
    boots = d[rng.integers(0, n, (n_boot, n))].mean(1)
    lo, hi = np.percentile(boots, [100 * (1 - level) / 2, 100 * (1 + level) / 2])
    lo, hi = min(lo, d.mean()), max(hi, d.mean())
    nonzero = d[d != 0]
    p_w = float(wilcoxon(nonzero, alternative="less").pvalue) if len(nonzero) >= 1 else 1.0
    spread = np.ptp(d) > 1e-9 * max(1.0, float(np.abs(d).max()))  # equal differences: no t-test to do
    p_t = float(ttest_1samp(d, 0.0, alternative="less").pvalue) if n >= 2 and spread else float("nan")
    return Comparison(a, b, n, float(d.mean()), float(lo), float(hi), int((d < 0).sum()), int((d > 0).sum()),
                      int((d == 0).sum()), p_w, p_t, float(d.std(ddof=1)) if n > 1 else float("nan"))


def minimum_detectable_effect(n: int, alpha: float = 0.05, power: float = 0.8) -> float:
    """The smallest mean paired difference, in standard deviations of the differences (Cohen's d_z), that a
    one-sided paired t-test at ``alpha`` detects with probability ``power`` over n targets (noncentral t)."""
    from scipy.optimize import brentq
    from scipy.stats import nct, t

    if n < 2:
        return math.inf
    crit = t.ppf(1 - alpha, n - 1)
    return float(brentq(lambda dz: nct.sf(crit, n - 1, dz * math.sqrt(n)) - power, 1e-6, 50.0))


def targets_needed(margin: float, sd: float, alpha: float = 0.05, power: float = 0.8, *, most: int = 100_000
                   ) -> int:
    """The fewest targets for which a one-sided paired t-test at ``alpha`` shows a difference of ``margin`` with
    probability ``power``, at a standard deviation ``sd`` of the paired differences (noncentral t): the size a
    non-inferiority test needs when the true difference is 0."""
    if margin <= 0 or sd <= 0:
        raise ValueError(f"margin and sd must be > 0, got margin={margin}, sd={sd}")
    dz = margin / sd
    lo, hi = 2, 2
    while minimum_detectable_effect(hi, alpha, power) > dz:
        if hi >= most:
            return most
        lo, hi = hi, min(most, hi * 2)
    while lo < hi:  # the MDE falls with n: the first n whose MDE is within dz
        mid = (lo + hi) // 2
        lo, hi = (mid + 1, hi) if minimum_detectable_effect(mid, alpha, power) > dz else (lo, mid)
    return lo


@dataclass(frozen=True)
class Margin:
    """A non-inferiority and superiority test of a − b (lower is better) over targets, against ``margin``: the
    upper bound of the one-sided (1 − α) t interval of the mean difference."""

    a: str
    b: str
    n: int
    mean: float
    sd: float
    upper: float  # one-sided (1 − α) upper bound of the mean difference
    margin: float
    alpha: float
    noninferior: bool  # upper < margin: a is no worse than b by the margin
    superior: bool  # upper < 0: a is better than b
    mde: float  # the difference (in the measure's unit, at the observed SD) n targets detect with ``power``
    power: float

    def as_dict(self) -> dict[str, float | int | str | bool]:
        return asdict(self)


def margin_test(a: str, b: str, values_a: Sequence[float], values_b: Sequence[float], margin: float, *,
                alpha: float = 0.05, power: float = 0.8, fallback_sd: float | None = None) -> Margin:
    """Non-inferiority (upper bound < ``margin``) and superiority (upper bound < 0) of a − b, paired over targets;
    targets where either is missing (not applicable) are left out. Fewer than two targets: no test (NaN). Where
    every difference is the same (no spread: two methods that picked alike on a few targets) the bound uses
    ``fallback_sd`` (the SD the power computation assumed), never a zero-width interval."""
    from scipy.stats import t

    d = np.asarray(values_a, float) - np.asarray(values_b, float)
    d = d[np.isfinite(d)]
    n = len(d)
    if n < 2:
        nan = float("nan")
        return Margin(a, b, n, float(d.mean()) if n else nan, nan, nan, margin, alpha, False, False, nan, power)
    sd = float(d.std(ddof=1))
    if sd <= 1e-12 and fallback_sd is not None:
        sd = float(fallback_sd)
    upper = float(d.mean() + t.ppf(1 - alpha, n - 1) * sd / math.sqrt(n))
    return Margin(a, b, n, float(d.mean()), sd, upper, margin, alpha, bool(upper < margin), bool(upper < 0),
                  float(minimum_detectable_effect(n, alpha, power) * sd), power)


def holm(tests: Sequence[Margin], values: Sequence[tuple[Sequence[float], Sequence[float]]], alpha: float, *,
         fallback_sd: float | None = None) -> list[Margin]:
    """The non-inferiority tests ``tests`` (each of a − b over its ``values``: (a's, b's)) again under Holm's
    step-down, so that the family's chance of any false "non-inferior" is at most ``alpha``: ordered by their
    one-sided p-value against the margin, the j-th (from 0) of m is tested at alpha/(m − j) and only while every
    earlier one was shown. Each comes back with its level as ``alpha``, its bound and MDE at that level, and
    ``superior`` only where non-inferiority was shown and the bound at the same level is below 0 (the usual switch
    from non-inferiority to superiority). Why: several strata × competitors each at ``alpha`` would let one pass
    in four by chance alone. Tests without a p-value (under two targets) stay untested and are ordered last."""
    from scipy.stats import t as student

    def p_value(m: Margin) -> float:
        if m.n < 2 or not math.isfinite(m.sd) or m.sd <= 0:
            return math.inf
        return float(student.cdf((m.mean - m.margin) / (m.sd / math.sqrt(m.n)), m.n - 1))

    order = sorted(range(len(tests)), key=lambda i: p_value(tests[i]))
    out: list[Margin | None] = [None] * len(tests)
    shown_so_far = True
    for j, i in enumerate(order):
        level = alpha / (len(tests) - j)
        m = tests[i]
        again = margin_test(m.a, m.b, *values[i], m.margin, alpha=level, power=m.power, fallback_sd=fallback_sd)
        shown_so_far = shown_so_far and again.noninferior
        out[i] = replace(again, noninferior=shown_so_far, superior=shown_so_far and again.superior)
    return [m for m in out if m is not None]


def trajectory_error(replay: np.ndarray, recorded: np.ndarray) -> float:
    """Mean distance [m] between a replayed and a recorded run ((n, 3) rows t, x, y each) over the recorded run's
    time span, the replay held at its last pose once it ended (a replay that left the road early is far off)."""
    t = recorded[:, 0]
    if replay.shape[0] == 0 or t.size == 0:
        return float("nan")
    x = np.interp(t, replay[:, 0], replay[:, 1])
    y = np.interp(t, replay[:, 0], replay[:, 2])
    return float(np.mean(np.hypot(x - recorded[:, 1], y - recorded[:, 2])))
