"""Proxy usefulness for *predicting* (thesis ch. 3): how well a proxy reproduces the target's verdicts.

Inputs are per-episode results of K agents in the proxy and in the target domain: for each agent a
(n_episodes × n_metrics) array, with the metric directions. Everything else is derived here:

- PPV  = Σ_agents Σ_metrics β_m |mean_proxy − mean_target|, β_m = 1 / (scale of metric m in the target);
- PRPV = ‖α_proxy − α_target‖₁ over all ordered pairs, α the dominance matrix (1: A_i ≥ A_j on every
  metric and > on one; 0: the reverse; 0.5: incomparable or equal), also divided by K(K−1);
- SRCC = Pearson's r between proxy and target performance (Habitat's Sim2Real correlation), with
  Spearman's ρ and Kendall's τ, and SIMPLER's mean maximum rank violation (MMRV);
- every figure with a percentile-bootstrap confidence interval over episodes.

>>> import numpy as np
>>> same = {"a": np.array([[3.0]]), "b": np.array([[2.0]]), "c": np.array([[1.0]])}
>>> swapped = {"a": np.array([[2.0]]), "b": np.array([[3.0]]), "c": np.array([[1.0]])}
>>> prpv_value(dominance(same, [True]), dominance(swapped, [True]))
2.0
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "Estimate",
    "PairedResults",
    "dominance",
    "mmrv",
    "ppv_value",
    "prpv_value",
    "usefulness",
]

Results = Mapping[str, np.ndarray]  # agent → (episodes, metrics)


@dataclass(frozen=True)
class Estimate:
    """A point value with a bootstrap confidence interval."""

    value: float
    low: float
    high: float

    def __str__(self) -> str:
        return f"{self.value:.3f} [{self.low:.3f}, {self.high:.3f}]"


def _means(res: Results, agents: Sequence[str]) -> np.ndarray:
    """(K, M) per-agent means over episodes, NaN-skipping; one NumPy call when every agent has as many
    episodes (the same sums, term by term, as agent by agent)."""
    arrays = [np.asarray(res[a], dtype=float) for a in agents]
    if arrays and all(x.shape == arrays[0].shape for x in arrays):
        return np.nanmean(np.stack(arrays), axis=1)
    return np.stack([np.nanmean(x, axis=0) for x in arrays])


def _signed(values: np.ndarray, higher_is_better: Sequence[bool]) -> np.ndarray:
    """Values turned so that higher is better on every metric."""
    return values * np.where(np.asarray(higher_is_better), 1.0, -1.0)


def dominance(res: Results, higher_is_better: Sequence[bool], *, significance: float | None = None) -> np.ndarray:
    """(K, K) dominance matrix α over the agents in ``res`` (in its key order); diagonal 0.5.

    With ``significance`` (e.g. 0.05), A_i counts as better than A_j on a metric only when Welch's t-test
    says so at that level; otherwise the two are equal on it.
    """
    agents = list(res)
    k = len(agents)
    alpha = np.full((k, k), 0.5)
    signed = {a: _signed(np.asarray(res[a], dtype=float), higher_is_better) for a in agents}
    if significance is None:  # the comparison is the sign of the mean difference: all pairs at once
        means = _means(signed, agents) if k else np.zeros((0, 0))
        cmp = np.sign(means[:, None, :] - means[None, :, :])
        ge, le = np.all(cmp >= 0, axis=2), np.all(cmp <= 0, axis=2)
        alpha[ge & ~le], alpha[le & ~ge] = 1.0, 0.0
        return alpha
    for i in range(k):
        for j in range(i + 1, k):
            cmp = _compare(signed[agents[i]], signed[agents[j]], significance)
            ge, le = np.all(cmp >= 0), np.all(cmp <= 0)
            if ge and not le:
                alpha[i, j], alpha[j, i] = 1.0, 0.0
            elif le and not ge:
                alpha[i, j], alpha[j, i] = 0.0, 1.0
    return alpha


def _compare(x: np.ndarray, y: np.ndarray, significance: float | None) -> np.ndarray:
    """Per metric: +1 if x is better, −1 if worse, 0 if equal (or not significantly different)."""
    mx, my = np.nanmean(x, axis=0), np.nanmean(y, axis=0)
    sign = np.sign(mx - my)
    if significance is None:
        return sign
    from scipy.stats import ttest_ind

    with np.errstate(invalid="ignore", divide="ignore"):
        p = ttest_ind(x, y, axis=0, equal_var=False, nan_policy="omit").pvalue
    p = np.where(np.isfinite(p), p, np.where(mx == my, 1.0, 0.0))  # zero variance: exact comparison
    return np.where(np.asarray(p) < significance, sign, 0.0)


def prpv_value(alpha_proxy: np.ndarray, alpha_target: np.ndarray) -> float:
    """1-norm of the difference of two dominance matrices (0 = the proxy orders agents as the target)."""
    return float(np.abs(alpha_proxy - alpha_target).sum())


def ppv_value(proxy: Results, target: Results, scale: np.ndarray | None = None) -> float:
    """Σ over agents and metrics of β_m |mean_proxy − mean_target|, β_m = 1/scale_m."""
    agents = list(target)
    mp, mt = _means(proxy, agents), _means(target, agents)
    if scale is None:
        scale = _scale(mt)
    return float(np.nansum(np.abs(mp - mt) / scale))


def _scale(target_means: np.ndarray) -> np.ndarray:
    """Spread of each metric across agents in the target (1 where it does not vary)."""
    s = np.nanstd(target_means, axis=0)
    return np.where(s > 1e-12, s, 1.0)


def mmrv(proxy: np.ndarray, target: np.ndarray) -> float:
    """SIMPLER's mean maximum rank violation for one metric (higher = better in both arrays)."""
    k = len(target)
    if k < 2:
        return 0.0
    viol = np.abs(target[:, None] - target[None, :]) * (
        (proxy[:, None] < proxy[None, :]) != (target[:, None] < target[None, :])
    )
    return float(viol.max(axis=1).mean())


def _correlations(mp: np.ndarray, mt: np.ndarray) -> dict[str, float]:
    """Pearson (SRCC in the thesis' sense), Spearman and Kendall τ-b per metric, averaged over metrics.

    NumPy versions of ``scipy.stats.pearsonr`` / ``spearmanr`` / ``kendalltau`` (equal to them within
    1e-12, tested): this runs for every bootstrap resample, where SciPy's per-call overhead dominated.
    A metric where either side is constant (or NaN) has no correlation.
    """
    out: dict[str, list[float]] = {"srcc": [], "spearman": [], "kendall": []}
    for m in range(mt.shape[1]):
        x, y = mp[:, m], mt[:, m]
        if not (np.nanstd(x) >= 1e-12 and np.nanstd(y) >= 1e-12):
            for v in out.values():
                v.append(np.nan)
            continue
        out["srcc"].append(_pearson(x, y))
        out["spearman"].append(_pearson(_average_ranks(x), _average_ranks(y)))
        out["kendall"].append(_kendall_tau_b(x, y))
    return {k: float(np.nanmean(v)) if not np.all(np.isnan(v)) else float("nan") for k, v in out.items()}


def _pearson(x: np.ndarray, y: np.ndarray) -> float:
    if np.isnan(x).any() or np.isnan(y).any():
        return float("nan")
    xm, ym = x - x.mean(), y - y.mean()
    r = float(np.dot(xm, ym) / (np.sqrt(np.dot(xm, xm)) * np.sqrt(np.dot(ym, ym))))
    return max(-1.0, min(1.0, r))


def _average_ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 1..n, ties sharing their average rank (``scipy.stats.rankdata``'s default)."""
    order = np.argsort(x, kind="mergesort")
    xs = x[order]
    starts = np.r_[True, xs[1:] != xs[:-1]]
    group = np.cumsum(starts) - 1
    first = np.flatnonzero(starts)
    ends = np.r_[first[1:], len(x)]
    ranks = np.empty(len(x))
    ranks[order] = (first + ends + 1)[group] / 2.0
    return ranks


def _kendall_tau_b(x: np.ndarray, y: np.ndarray) -> float:
    if np.isnan(x).any() or np.isnan(y).any():
        return float("nan")
    i, j = np.triu_indices(len(x), 1)
    dx, dy = np.sign(x[i] - x[j]), np.sign(y[i] - y[j])
    pairs = len(i)
    tx, ty = int((dx == 0).sum()), int((dy == 0).sum())
    if pairs - tx == 0 or pairs - ty == 0:
        return float("nan")
    return float((dx * dy).sum() / np.sqrt(pairs - tx) / np.sqrt(pairs - ty))


@dataclass(frozen=True)
class PairedResults:
    """Per-episode results of the same agents in a proxy and in the target domain."""

    proxy: Results
    target: Results
    higher_is_better: tuple[bool, ...]

    def __post_init__(self) -> None:
        if set(self.proxy) != set(self.target):
            missing = sorted(set(self.proxy) ^ set(self.target))
            raise ValueError(f"proxy and target results must cover the same agents; differ on {missing}")
        for name, res in (("proxy", self.proxy), ("target", self.target)):
            for a, arr in res.items():
                arr = np.asarray(arr)
                if arr.ndim != 2 or arr.shape[1] != len(self.higher_is_better) or arr.shape[0] == 0:
                    raise ValueError(f"{name}[{a!r}]: expected (episodes, {len(self.higher_is_better)}) "
                                     f"results, got shape {arr.shape}")

    @property
    def agents(self) -> list[str]:
        return list(self.target)


def _point(pr: PairedResults, significance: float | None) -> dict[str, float]:
    agents = pr.agents
    proxy = {a: pr.proxy[a] for a in agents}
    target = {a: pr.target[a] for a in agents}
    k = len(agents)
    a_p = dominance(proxy, pr.higher_is_better, significance=significance)
    a_t = dominance(target, pr.higher_is_better, significance=significance)
    prpv = prpv_value(a_p, a_t)
    mp = _signed(_means(proxy, agents), pr.higher_is_better)
    mt = _signed(_means(target, agents), pr.higher_is_better)
    out = {"prpv": prpv, "prpv_norm": prpv / (k * (k - 1)) if k > 1 else 0.0, "ppv": ppv_value(proxy, target)}
    out.update(_correlations(mp, mt))
    out["mmrv"] = float(np.mean([mmrv(mp[:, m], mt[:, m]) for m in range(mt.shape[1])]))
    return out


def _resample(res: Results, rng: np.random.Generator) -> dict[str, np.ndarray]:
    out = {}
    for a, arr in res.items():
        arr = np.asarray(arr)
        out[a] = arr[rng.integers(0, arr.shape[0], arr.shape[0])]
    return out


def usefulness(
    pr: PairedResults, *, n_boot: int = 500, level: float = 0.95, seed: int = 0,
    significance: float | None = None, progress: Callable[[int], None] | None = None,
) -> dict[str, Estimate]:
    """PRPV, PRPV/K(K−1), PPV, SRCC (Pearson), Spearman, Kendall and MMRV with bootstrap intervals.

    Episodes are resampled with replacement, independently per agent and domain, ``n_boot`` times.
    """
    point = _point(pr, significance)
    rng = np.random.default_rng(seed)
    boots: dict[str, list[float]] = {k: [] for k in point}
    for b in range(n_boot):
        sample = PairedResults(_resample(pr.proxy, rng), _resample(pr.target, rng), pr.higher_is_better)
        for k, v in _point(sample, significance).items():
            boots[k].append(v)
        if progress:
            progress(b)
    lo_q, hi_q = 100 * (1 - level) / 2, 100 * (1 + level) / 2
    out = {}
    for k, v in point.items():
        arr = np.asarray(boots[k], dtype=float)
        arr = arr[np.isfinite(arr)]
        lo, hi = (np.percentile(arr, [lo_q, hi_q]) if arr.size else (np.nan, np.nan))
        out[k] = Estimate(v, float(lo), float(hi))
    return out
