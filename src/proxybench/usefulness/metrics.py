"""Proxy usefulness for *predicting* (thesis ch. 3): the definitions, as functions of the agents' means.

Inputs are per-episode results of K agents in a proxy and in the target: for each agent an
(episodes × metrics) array, and the metrics' directions. Every figure is a function of the agents' mean
performance in each domain, vectorised over leading axes so that bootstrap replicates are computed at
once (intervals: :mod:`proxybench.usefulness.intervals`).

- **PRPV** (thesis eq. 3.4.4) = Σ_ij |α^proxy_ij − α^target_ij| over the dominance matrices (eq. 3.4.3):
  α_ij = 1 if agent i is at least as good as j on every metric and better on one, 0 the reverse, 0.5 if
  incomparable or equal. In [0, K(K−1)]; one swapped pair costs 2.
- **PPV** (eq. 3.4.1) is defined *per agent*: PPV(S_θ, A) = Σ_m β_m |M_m(proxy) − M_m(target)|, with
  β_m = 1/s_m and s_m the spread (population std) of metric m across the agents' target means. β is fixed
  from the target once (:func:`target_scale`), so every proxy and every bootstrap replicate is measured
  with the same yardstick. Summaries: ``ppv`` = the mean over agents (comparable across agent sets) and
  ``ppv_sum`` = the sum (grows with K).
- **Correlations** per metric between proxy and target means: Pearson's r (what Habitat calls SRCC, the
  sim-vs-real correlation coefficient), Spearman's ρ and Kendall's τ_b; a metric constant across agents in
  either domain has none (the notes say so) and the summaries average the metrics that have one.
- **MMRV** (SIMPLER's mean maximum rank violation) per metric, in the metric's unit; ``mmrv_scaled``
  averages MMRV_m·β_m over the metrics (dimensionless, like PPV).

**Missing values** (NaN scores: an agent refused by a domain, a robot episode that failed, a metric that
does not apply, such as ``stopped_at_line`` without a stop line): an episode without a value is left out
of that metric's mean; an agent with *no* value on a metric is **worst** on it, two such agents tie — in
PRPV's dominance matrices exactly as in the benchmark's lexicographic semiorder
(:mod:`proxybench.tasks.scoring`), so that PRPV measures how well a proxy predicts the order the target's
own leaderboard gives. Distances and correlations (PPV, r, ρ, τ, MMRV) need numbers: they leave such an
agent out and say so. (docs/usefulness.md, "Missing values", gives the reasons.)

>>> import numpy as np
>>> same = {"a": np.array([[3.0]]), "b": np.array([[2.0]]), "c": np.array([[1.0]])}
>>> swapped = {"a": np.array([[2.0]]), "b": np.array([[3.0]]), "c": np.array([[1.0]])}
>>> prpv_value(dominance(same, [True]), dominance(swapped, [True]))
2.0
>>> float(dominance({"a": np.array([[np.nan]]), "b": np.array([[0.0]])}, [True])[0, 1])   # no value: worst
0.0
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "Estimate",
    "PairedResults",
    "agent_means",
    "correlations",
    "dominance",
    "dominance_from_means",
    "mmrv",
    "mmrv_from_means",
    "pair_signs",
    "ppv_agents",
    "ppv_value",
    "prpv_from_means",
    "prpv_value",
    "resampled_means",
    "target_scale",
]

Results = Mapping[str, np.ndarray]  # agent → (episodes, metrics)


@dataclass(frozen=True)
class Estimate:
    """A point value with a confidence interval and how the interval was made (``method``)."""

    value: float
    low: float
    high: float
    method: str = ""

    def __str__(self) -> str:
        return f"{self.value:.3f} [{self.low:.3f}, {self.high:.3f}]"


def agent_means(res: Results, agents: Sequence[str]) -> np.ndarray:
    """(K, m) mean of each metric over the episodes that produced it (NaN where none did)."""
    out = []
    for a in agents:
        arr = np.asarray(res[a], dtype=float)
        with np.errstate(invalid="ignore", divide="ignore"):
            n = np.isfinite(arr).sum(0)
            out.append(np.where(n > 0, np.nansum(arr, 0) / np.maximum(n, 1), np.nan))
    return np.stack(out)


def resampled_means(arr: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(…, m) means of ``arr`` (n, m) over the rows ``idx`` (…, n'); a metric no chosen row has is NaN."""
    x = np.asarray(arr, dtype=float)[np.asarray(idx).astype(np.intp)]
    ok = np.isfinite(x)
    n = ok.sum(-2)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.where(ok, x, 0.0).sum(-2) / np.maximum(n, 1), np.nan)


def _signed(values: np.ndarray, higher_is_better: Sequence[bool]) -> np.ndarray:
    """Values turned so that higher is better on every metric."""
    return values * np.where(np.asarray(higher_is_better), 1.0, -1.0)


def pair_signs(means: np.ndarray, higher: Sequence[bool]) -> np.ndarray:
    """(…, K, K, m) of +1 / 0 / −1: agent i better / equal / worse than j on each metric, from (…, K, m) means.

    A NaN mean is worst (below every number); two NaNs are equal.
    """
    s = _signed(np.asarray(means, dtype=float), higher)
    nan = np.isnan(s)
    with np.errstate(invalid="ignore"):
        d = np.sign(s[..., :, None, :] - s[..., None, :, :])
    nan_i, nan_j = nan[..., :, None, :], nan[..., None, :, :]
    return np.where(nan_i | nan_j, nan_j.astype(float) - nan_i.astype(float), d)


def alpha_from_signs(signs: np.ndarray) -> np.ndarray:
    """Dominance matrices from :func:`pair_signs`: 1 where every sign ≥ 0 and one > 0, 0 the reverse, else 0.5."""
    ge, le = np.all(signs >= 0, axis=-1), np.all(signs <= 0, axis=-1)
    return np.where(ge & ~le, 1.0, np.where(le & ~ge, 0.0, 0.5))


def dominance_from_means(means: np.ndarray, higher: Sequence[bool]) -> np.ndarray:
    """(…, K, K) dominance matrices α from (…, K, m) agent means (NaN: worst on that metric)."""
    return alpha_from_signs(pair_signs(means, higher))


def prpv_from_means(proxy_means: np.ndarray, target_means: np.ndarray, higher: Sequence[bool]) -> np.ndarray | float:
    """PRPV from (…, K, m) agent means of proxy and target (vectorised over leading axes)."""
    out = np.abs(dominance_from_means(proxy_means, higher) - dominance_from_means(target_means, higher)).sum((-1, -2))
    return float(out) if np.ndim(out) == 0 else out


def dominance(res: Results, higher_is_better: Sequence[bool], *, significance: float | None = None) -> np.ndarray:
    """(K, K) dominance matrix α over the agents in ``res`` (in its key order); diagonal 0.5.

    With ``significance`` (e.g. 0.05), A_i counts as better than A_j on a metric only when Welch's t-test
    says so at that level; otherwise the two are equal on it. An agent without values is worst either way.
    """
    agents = list(res)
    signs = pair_signs(agent_means(res, agents), higher_is_better)
    if significance is not None:
        signs = _significant(res, agents, higher_is_better, signs, significance)
    return alpha_from_signs(signs)


def _significant(res: Results, agents: list[str], higher: Sequence[bool], signs: np.ndarray,
                 significance: float) -> np.ndarray:
    """Signs with differences that Welch's t-test does not find at ``significance`` set to 0."""
    import warnings

    from scipy.stats import ttest_ind

    out = signs.copy()
    means = agent_means(res, agents)
    for i in range(len(agents)):
        for j in range(i + 1, len(agents)):
            x, y = np.asarray(res[agents[i]], float), np.asarray(res[agents[j]], float)
            with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore")  # too few values, or none: handled below
                p = np.asarray(ttest_ind(x, y, axis=0, equal_var=False, nan_policy="omit").pvalue, float)
            exact = means[i] == means[j]
            p = np.where(np.isfinite(p), p, np.where(exact, 1.0, 0.0))  # zero variance: exact comparison
            keep = (p < significance) | np.isnan(means[i]) | np.isnan(means[j])  # missing: worst, no test
            out[i, j] = np.where(keep, signs[i, j], 0.0)
            out[j, i] = -out[i, j]
    return out


def prpv_value(alpha_proxy: np.ndarray, alpha_target: np.ndarray) -> float:
    """1-norm of the difference of two dominance matrices (0 = the proxy orders agents as the target)."""
    return float(np.abs(alpha_proxy - alpha_target).sum())


def target_scale(target_means: np.ndarray, names: Sequence[str] | None = None) -> tuple[np.ndarray, list[str]]:
    """s_m (β_m = 1/s_m) for PPV and scaled MMRV from the (K, m) target means, and notes on fallbacks.

    s_m is the spread (population std) of metric m across the agents' target means. A metric on which the
    target does not separate the agents (e.g. every agent survives the whole episode) has no spread: then
    s_m = |its mean| (a relative error), or 1 (its own unit) when the mean is 0 too.
    """
    tm = np.asarray(target_means, dtype=float)
    names = list(names or [f"metric {k}" for k in range(tm.shape[1])])
    scale, notes = np.ones(tm.shape[1]), []
    for k in range(tm.shape[1]):
        col = tm[:, k][np.isfinite(tm[:, k])]
        s = float(np.std(col)) if col.size else 0.0
        mean = float(np.mean(np.abs(col))) if col.size else 0.0
        if s > 1e-12 * max(1.0, mean):
            scale[k] = s
        elif mean > 1e-12:
            scale[k] = mean
            notes.append(f"{names[k]} does not vary across agents on the target ({col[0]:.4g} for all): PPV "
                         f"scales it by that value (a relative error)")
        else:
            notes.append(f"{names[k]} is 0 for every agent on the target: PPV takes it in its own unit")
    return scale, notes


def ppv_agents(proxy_means: np.ndarray, target_means: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(…, K) thesis PPV of each agent: Σ_m |mean_proxy − mean_target| / s_m (NaN where a mean is missing)."""
    return (np.abs(np.asarray(proxy_means) - np.asarray(target_means)) / np.asarray(scale)).sum(-1)


def ppv_value(proxy: Results, target: Results, scale: np.ndarray | None = None) -> float:
    """Mean over agents of the per-agent PPV; s_m from ``target`` unless given (:func:`target_scale`).

    Agents without a value in either domain are left out (they have no distance).
    """
    agents = list(target)
    mp, mt = agent_means(proxy, agents), agent_means(target, agents)
    if scale is None:
        scale = target_scale(mt)[0]
    per = ppv_agents(mp, mt, scale)
    return float(np.nanmean(per)) if np.isfinite(per).any() else float("nan")


def mmrv(proxy: np.ndarray, target: np.ndarray) -> float:
    """SIMPLER's mean maximum rank violation for one metric (higher = better in both arrays), its unit."""
    return float(mmrv_from_means(np.asarray(proxy, float)[:, None], np.asarray(target, float)[:, None])[0])


def mmrv_from_means(proxy: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(…, m) MMRV of each metric from (…, K, m) signed means (higher = better): for each agent, the largest
    target gap |t_i − t_j| to an agent j that the proxy orders the other way; averaged over agents."""
    p, t = np.asarray(proxy, float), np.asarray(target, float)
    if t.shape[-2] < 2:
        return np.zeros(t.shape[:-2] + t.shape[-1:])
    gap = np.abs(t[..., :, None, :] - t[..., None, :, :])
    flipped = (p[..., :, None, :] < p[..., None, :, :]) != (t[..., :, None, :] < t[..., None, :, :])
    return (gap * flipped).max(-2).mean(-2)


def _pearson(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(…, m) Pearson's r along the agent axis of (…, K, m) arrays (NaN where one side is constant)."""
    xc, yc = x - x.mean(-2, keepdims=True), y - y.mean(-2, keepdims=True)
    den = np.sqrt((xc * xc).sum(-2) * (yc * yc).sum(-2))
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (xc * yc).sum(-2) / den
    return np.where(den > 1e-300, np.clip(r, -1.0, 1.0), np.nan)


def _kendall_b(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(…, m) Kendall's τ_b along the agent axis (ties counted as SciPy's ``kendalltau`` does)."""
    sx = np.sign(x[..., :, None, :] - x[..., None, :, :])
    sy = np.sign(y[..., :, None, :] - y[..., None, :, :])
    k = x.shape[-2]
    n0 = k * (k - 1) / 2
    s = (sx * sy).sum((-2, -3)) / 2
    tx, ty = (sx == 0).sum((-2, -3)) / 2 - k / 2, (sy == 0).sum((-2, -3)) / 2 - k / 2  # tied pairs (no diagonal)
    den = np.sqrt((n0 - tx) * (n0 - ty))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, s / den, np.nan)


def correlations(proxy_means: np.ndarray, target_means: np.ndarray) -> dict[str, np.ndarray]:
    """Per metric (…, m): Pearson's r, Spearman's ρ and Kendall's τ_b between proxy and target (…, K, m) means."""
    from scipy.stats import rankdata

    x, y = np.asarray(proxy_means, float), np.asarray(target_means, float)
    return {"pearson": _pearson(x, y),
            "spearman": _pearson(rankdata(x, axis=-2), rankdata(y, axis=-2)),
            "kendall": _kendall_b(x, y)}


def constant_metrics(means: np.ndarray) -> np.ndarray:
    """(m,) True where a metric has the same value for every agent (no correlation is defined)."""
    m = np.asarray(means, float)
    return np.ptp(m, axis=0) <= 1e-12 * np.maximum(1.0, np.abs(m).max(axis=0))


@dataclass(frozen=True)
class PairedResults:
    """Per-episode results of the same agents in a proxy and in the target domain.

    ``metrics`` names the columns (for notes and per-metric figures); without it they are ``m0``, ``m1``…
    Episode i of an agent in the proxy replays episode i of the target when both have the same count
    (paired resampling in :mod:`proxybench.usefulness.intervals`).
    """

    proxy: Results
    target: Results
    higher_is_better: tuple[bool, ...]
    metrics: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if set(self.proxy) != set(self.target):
            missing = sorted(set(self.proxy) ^ set(self.target))
            raise ValueError(f"proxy and target results must cover the same agents; differ on {missing}")
        if self.metrics and len(self.metrics) != len(self.higher_is_better):
            raise ValueError(f"{len(self.metrics)} metric names for {len(self.higher_is_better)} directions")
        for name, res in (("proxy", self.proxy), ("target", self.target)):
            for a, arr in res.items():
                arr = np.asarray(arr)
                if arr.ndim != 2 or arr.shape[1] != len(self.higher_is_better) or arr.shape[0] == 0:
                    raise ValueError(f"{name}[{a!r}]: expected (episodes, {len(self.higher_is_better)}) "
                                     f"results, got shape {arr.shape}")

    @property
    def agents(self) -> list[str]:
        return list(self.target)

    @property
    def metric_names(self) -> tuple[str, ...]:
        return self.metrics or tuple(f"m{k}" for k in range(len(self.higher_is_better)))

    @property
    def paired(self) -> bool:
        """Whether every agent has as many proxy as target episodes (episode i replays episode i)."""
        return all(len(self.proxy[a]) == len(self.target[a]) for a in self.agents)
