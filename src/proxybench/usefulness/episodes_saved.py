"""What a proxy is worth in target episodes: how many fewer target episodes decide the same pairs of agents when
the proxy's paired episodes serve as the predictor (``proxybench rank``'s PPI++ estimator, :mod:`.ranking`).

For one pair (a, b) and metric, d = score(a) − score(b) on each target episode and d̂ the proxy's on the same
start and seed. With plenty of proxy-only episodes (they are cheap; the lab runs N ≫ n of them), PPI++'s
estimator has per-episode variance Var(d − λd̂) instead of Var(d), at the variance-minimising λ clipped to
[0, 1]. The **worth** of a target episode is the ratio of the two: the factor by which the proxy multiplies the
target's episodes, and 1 − 1/worth the share of target episodes it saves for the same interval width.

λ is one per metric, pooled over the pairs, and the variance it leaves is measured out of sample: each episode's d
is predicted from the other episodes (their mean, plus λ fitted on them times the proxy's deviation), so a λ fitted
to the noise of a few episodes does not flatter a proxy that predicts nothing (in sample, 3 episodes per agent made a
useless proxy look worth ~40 %). Metrics are scaled by their pooled spread so they weigh alike. The episodes *needed*
are a plug-in planning figure: per pair whose estimated gap clears its tolerance ε, the n at which a two-sided
normal interval at the Bonferroni level (α over every pair and metric) excludes ±ε, i.e.
n = (z·σ / (|Δ̂| − ε))²; pairs within ε need a tie's interval and are left out. Reported as the median over those
pairs: near-ties make the maximum unbounded and the mean meaningless.

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> noise = rng.normal(size=(40, 3))
>>> target = {a: (i + noise[:, i:i + 1]) for i, a in enumerate("xyz")}
>>> saved = episodes_saved(target, target, (0.0,))  # a proxy that predicts every episode exactly
>>> round(saved.saved_share, 2)
1.0
>>> episodes_saved(target, {a: -v for a, v in target.items()}, (0.0,)).worth  # an inverted one: λ = 0
1.0
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

__all__ = ["EpisodeSavings", "episodes_saved"]

#: agent → (episodes × metrics) scores, rows paired across target and proxy (same starts and seeds)
Results = Mapping[str, np.ndarray]


@dataclass(frozen=True)
class EpisodeSavings:
    """A proxy's worth on one target's pairs (see the module docstring); NaN where nothing could be computed."""

    worth: float
    """target-alone episodes one target episode with the proxy is worth (1: the proxy adds nothing)"""
    saved_share: float
    """1 − 1/worth: the share of target episodes the proxy saves for the same interval width"""
    episodes_alone: float
    """median over decidable pairs of the target episodes per agent that decide the pair without the proxy"""
    episodes_with: float
    """the same with the proxy as the predictor"""
    pairs: int
    """pairs × metrics whose gap cleared ε (the episodes' median is over these)"""
    weights: tuple[float, ...]
    """λ per metric"""

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


def _columns(res: Results, agents: list[str]) -> np.ndarray:
    """(episodes × pairs × metrics) differences a − b for every pair of ``agents``, rows cut to the shortest."""
    n = min(len(res[a]) for a in agents)
    tables = [np.asarray(res[a], float)[:n] for a in agents]
    return np.stack([tables[i] - tables[j] for i in range(len(agents)) for j in range(i + 1, len(agents))], 1)


def _weight(d: np.ndarray, d_hat: np.ndarray) -> float:
    """PPI++'s λ (N ≫ n) pooled over the columns (pairs) of ``d`` and ``d_hat`` (episodes × pairs), in [0, 1]."""
    dc, hc = d - d.mean(0), d_hat - d_hat.mean(0)
    var_h = float((hc * hc).sum())
    return float(np.clip((dc * hc).sum() / var_h, 0.0, 1.0)) if var_h > 0 else 0.0


def _held_out_spreads(d: np.ndarray, d_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per column, the mean squared error of predicting each episode's d from the other episodes: by their mean
    (the target alone), and by their mean plus λ·(d̂ − the others' d̂ mean) with λ fitted on the others (the proxy).
    Leave-one-episode-out, so a λ fitted to a few episodes' noise does not flatter the proxy."""
    n = len(d)
    sd, sh = d.sum(0), d_hat.sum(0)  # per column; the others' sums are these minus row i
    md, mh = (sd - d) / (n - 1), (sh - d_hat) / (n - 1)
    cov = ((d * d_hat).sum(0) - d * d_hat - (sd - d) * (sh - d_hat) / (n - 1)).sum(1)  # per row i, over columns
    var = ((d_hat * d_hat).sum(0) - d_hat * d_hat - (sh - d_hat) ** 2 / (n - 1)).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.clip(np.where(var > 0, cov / var, 0.0), 0.0, 1.0)[:, None]
    return ((d - md) ** 2).mean(0), ((d - md - lam * (d_hat - mh)) ** 2).mean(0)


def episodes_saved(target: Results, proxy: Results, tolerances: Sequence[float], alpha: float = 0.05) -> EpisodeSavings:
    """The proxy's worth for deciding ``target``'s pairs of agents (every agent of ``target``; ``proxy`` holds the
    same agents on the same episodes, row for row; the direction of a metric does not matter: a gap is a gap)."""
    agents = list(target)
    missing = [a for a in agents if a not in proxy]
    if missing:
        raise ValueError(f"proxy: no episodes of {', '.join(missing)}")
    nan = float("nan")
    if len(agents) < 2 or min(len(target[a]) for a in agents) < 3:
        return EpisodeSavings(nan, nan, nan, nan, 0, ())
    n = min(min(len(target[a]), len(proxy[a])) for a in agents)
    d = _columns({a: target[a][:n] for a in agents}, agents)
    d_hat = _columns({a: proxy[a][:n] for a in agents}, agents)
    ok = np.isfinite(d).all(0) & np.isfinite(d_hat).all(0)  # pairs × metrics usable
    var_d = d.var(0, ddof=1)
    loo_alone, loo_with = np.full(var_d.shape, np.nan), np.full(var_d.shape, np.nan)
    lams = []
    for m in range(d.shape[2]):
        use = ok[:, m]
        if not use.any():
            lams.append(nan)
            continue
        lams.append(_weight(d[:, use, m], d_hat[:, use, m]))
        loo_alone[use, m], loo_with[use, m] = _held_out_spreads(d[:, use, m], d_hat[:, use, m])
    # what the proxy leaves of the target's spread, out of sample (cross-fitted λ), on the in-sample scale
    with np.errstate(divide="ignore", invalid="ignore"):
        resid_var = var_d * np.where(loo_alone > 0, loo_with / loo_alone, 1.0)
    scale = np.sqrt(np.nanmean(np.where(ok, var_d, np.nan), 0))  # per metric, so metrics weigh alike
    with np.errstate(divide="ignore", invalid="ignore"):
        num = np.nansum(np.where(ok, var_d / scale**2, np.nan))
        den = np.nansum(np.where(ok, resid_var / scale**2, np.nan))
        worth = float(num / den) if den > 0 else (math.inf if num > 0 else nan)
    gaps = np.abs(d.mean(0))
    eps = np.broadcast_to(np.asarray(tolerances, float), gaps.shape)
    z = stats.norm.ppf(1 - alpha / (2 * max(int(ok.sum()), 1)))
    clear = ok & (gaps > eps)
    with np.errstate(divide="ignore", invalid="ignore"):
        alone = (z * np.sqrt(var_d[clear]) / (gaps[clear] - eps[clear])) ** 2
        with_p = (z * np.sqrt(resid_var[clear]) / (gaps[clear] - eps[clear])) ** 2
    share = 1.0 - 1.0 / worth if math.isfinite(worth) and worth > 0 else (1.0 if worth == math.inf else nan)
    return EpisodeSavings(worth, share, _median_at_least_2(alone), _median_at_least_2(with_p), int(clear.sum()),
                          tuple(float(v) for v in lams))


def _median_at_least_2(episodes: np.ndarray) -> float:
    """The median of per-pair episode counts, each at least 2 (an interval needs two episodes' spread)."""
    return float(np.median(np.maximum(episodes, 2.0))) if len(episodes) else float("nan")
