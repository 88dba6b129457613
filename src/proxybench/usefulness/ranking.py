"""Ranking K agents on the target with a guarantee, the proxy's paired episodes as the predictor.

Every pair of agents (a, b) and metric gets a decision: ``a>b`` (a better by more than the task's tolerance ε),
``b>a``, ``tie`` (the difference within ±ε: the indifference module's semiorder) or ``undecided``. The
decisions rest on simultaneous intervals for the mean paired difference d = score(a) − score(b) over the
target's episodes (the same episode ids: same starts and seeds for both agents), so the chance that *any*
decision is wrong is at most α (family-wise: Bonferroni over every pair and metric, α/(P·M) per interval).

The proxy enters as a predictor (prediction-powered inference, PPI++: Angelopoulos, Duchi & Zrnic 2023). With
n target episodes of d, the proxy's d̂ on the same episodes, and N proxy-only episodes d̂ᵘ drawn the same way,

    θ̂(λ) = λ·mean(d̂ᵘ) + mean(d − λ·d̂)

is unbiased for every λ; the tuned λ (per pair and metric, clipped to [0, 1]) minimises its variance, so a proxy
that predicts nothing (or the opposite) gets λ ≈ 0 and costs, asymptotically, nothing against the target alone.
The fixed-sample intervals are ``ppi_py.ppi_mean_ci``'s, widened from the normal to Student's t quantile on
the n − 1 target degrees of freedom (labs run few episodes).

Anytime-valid (``sequential``): intervals that hold at every number of episodes at once, so a person may stop
whenever every pair looks settled. The boundary is the Gaussian-mixture asymptotic confidence sequence of
Waudby-Smith, Arbour, Sinha, Kennedy & Ramdas (2024), applied to x_i = d_i − λ_i·(d̂_i − m̂) with λ_i chosen from the
episodes before i only (predictable) and m̂ the proxy-only mean, plus λ̄·(m̂'s own fixed interval h_m, at a twentieth
of the level):

    x_i = d_i − λ_i·(d̂_i − m̂),   mean(x)  ±  σ̂·√(2(tρ² + 1)/(t²ρ²) · log(√(tρ² + 1)/α′))  ±  λ̄·h_m,

the boundary widened at few episodes by Student's quantile over the normal one (σ̂ is itself unsure there).

Written here because no maintained package provides it for Python 3.11 (``expectation`` needs 3.12; ``confseq``
builds its boundaries from C++ and did not build here); its error rate is measured by simulation
(tests/test_ranking.py, ``benchmarks/bench_rank.py``).

Rank-sets (Chatzi et al. 2024's construction from simultaneous pairwise decisions): agent a may hold any rank
from 1 + #{agents decided better than a} to K − #{agents decided worse than a}.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy import stats

__all__ = ["ERROR_CONTROL", "PairDecision", "Ranking", "RankingError", "Scores", "anytime_interval",
           "decide", "fixed_interval", "rank", "rank_sets", "spread_floor"]

Decision = Literal["a>b", "b>a", "tie", "undecided"]
#: agent → episode id → scores (one value per metric)
Scores = Mapping[str, Mapping[int, Sequence[float] | np.ndarray]]
ERROR_CONTROL = ("family-wise error rate over every pair and metric (Bonferroni): the chance that any decision "
                 "is wrong is at most α")
#: the share of α spent on the proxy mean's interval in the anytime mode
PROXY_SHARE = 0.05


class RankingError(ValueError):
    """Input the ranking cannot use; the message names the value at fault."""


@dataclass(frozen=True)
class PairDecision:
    """One pair on one metric: the difference a − b (in the metric's units), its interval, and what it decides."""

    a: str
    b: str
    metric: str
    decision: Decision
    estimate: float
    interval: tuple[float, float]
    n: int  # target episodes both agents ran
    weight: float  # λ given to the proxy (0: the target alone)

    def to_dict(self) -> dict[str, object]:
        return {"a": self.a, "b": self.b, "metric": self.metric, "decision": self.decision,
                "estimate": self.estimate, "interval": list(self.interval), "n": self.n, "weight": self.weight}


@dataclass(frozen=True)
class Ranking:
    """Every pair's decision with the proxy (``pairs``) and without it (``target_only``), rank-sets per metric."""

    agents: tuple[str, ...]
    metrics: tuple[str, ...]
    alpha: float
    sequential: bool
    pairs: tuple[PairDecision, ...]
    target_only: tuple[PairDecision, ...]
    rank_sets: dict[str, dict[str, tuple[int, int]]] = field(default_factory=dict)  # metric → agent → (best, worst)
    target_episodes: int = 0
    proxy_episodes: int = 0  # paired (on the target's episodes) plus proxy-only
    error_control: str = ERROR_CONTROL

    def decided(self, with_proxy: bool = True) -> int:
        """Pairs (× metrics) that are not ``undecided``."""
        return sum(p.decision != "undecided" for p in (self.pairs if with_proxy else self.target_only))

    def episode_worth(self) -> float:
        """What one target episode is worth with the proxy, in target-alone episodes: the median over pairs of
        (interval width alone / width with the proxy)², widths shrinking as 1/√n (1: the proxy adds nothing;
        2: it halves the target episodes needed). NaN where no interval is finite."""
        ratios = [((b.interval[1] - b.interval[0]) / (p.interval[1] - p.interval[0])) ** 2
                  for p, b in zip(self.pairs, self.target_only, strict=True)
                  if math.isfinite(p.interval[1] - p.interval[0]) and math.isfinite(b.interval[1] - b.interval[0])
                  and p.interval[1] > p.interval[0]]
        return float(np.median(ratios)) if ratios else float("nan")


def decide(low: float, high: float, tolerance: float, higher_is_better: bool) -> Decision:
    """What an interval [low, high] for the mean of a − b decides, ε = ``tolerance`` (a tie is |d| ≤ ε)."""
    if not higher_is_better:
        low, high = -high, -low
    if low > tolerance:
        return "a>b"
    if high < -tolerance:
        return "b>a"
    if -tolerance <= low and high <= tolerance and tolerance > 0:
        return "tie"
    return "undecided"


def fixed_interval(d: np.ndarray, d_hat: np.ndarray | None, d_unl: np.ndarray | None, alpha: float, *,
                   floor: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(estimate, low, high, λ) per column of ``d`` (n × P target differences) at level 1 − ``alpha`` each,
    with the proxy's differences on the same episodes (``d_hat``, n × P) and on its own (``d_unl``, N × P)
    as PPI++'s predictor, or the target alone where they are None. ``floor``: a spread counted as one more
    episode's (see :func:`rank`), so a few identical episodes never make a zero-width interval."""
    n, p = d.shape
    pad = np.broadcast_to(np.asarray(floor, float), (p,)) ** 2 / n**2  # added to the squared standard error
    if n < 2:
        nan = np.full(p, np.nan)
        return d.mean(0) if n else nan, np.full(p, -np.inf), np.full(p, np.inf), np.zeros(p)
    tq, zq = stats.t.ppf(1 - alpha / 2, n - 1), stats.norm.ppf(1 - alpha / 2)
    if d_hat is None or d_unl is None or len(d_unl) < 2:
        est, se = d.mean(0), np.sqrt(d.var(0, ddof=1) / n + pad)
        half = tq * se
        return est, est - half, est + half, np.zeros(p)
    from ppi_py import ppi_mean_ci, ppi_mean_pointestimate

    lam = _ppi_weight(d, d_hat, d_unl)
    est = np.atleast_1d(ppi_mean_pointestimate(d, d_hat, d_unl, lam=lam))
    lo, hi = (np.atleast_1d(v) for v in ppi_mean_ci(d, d_hat, d_unl, alpha=alpha, lam=lam))
    # ppi_py's standard error (its spreads with 1/n, here 1/(n − 1) as the target alone's), Student's quantile
    half = tq * np.sqrt(((hi - lo) / 2 / zq) ** 2 * n / (n - 1) + pad)
    return est, est - half, est + half, lam


def _ppi_weight(d: np.ndarray, d_hat: np.ndarray, d_unl: np.ndarray) -> np.ndarray:
    """PPI++'s variance-minimising λ per column, Cov(d, d̂) / ((1 + n/N)·Var(d̂)), clipped to [0, 1] (ppi_py's
    ``lam_optim_mode="element"`` rule, computed once for every column)."""
    n, big_n = len(d), len(d_unl)
    cov = ((d - d.mean(0)) * (d_hat - d_hat.mean(0))).sum(0) / n  # ppi_py's 1/n
    var = (np.concatenate([d_hat, d_unl]).var(0, ddof=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(var > 0, cov / ((1 + n / big_n) * var), 0.0)
    return np.clip(np.nan_to_num(lam), 0.0, 1.0)


def anytime_interval(d: np.ndarray, d_hat: np.ndarray | None, d_unl: np.ndarray | None, alpha: float, *,
                     horizon: float = 100.0,
                     floor: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(estimate, low, high, λ̄) for the columns of ``d`` after all its rows, from intervals that hold at every
    row count at once (the module docstring's confidence sequence; ``horizon``: the episode count the
    boundary is tightest at; ``floor`` as in :func:`fixed_interval`)."""
    est, low, high, lam = anytime_path(d, d_hat, d_unl, alpha, horizon=horizon, floor=floor)
    if len(d) == 0:
        p = d.shape[1]
        return np.full(p, np.nan), np.full(p, -np.inf), np.full(p, np.inf), np.zeros(p)
    return est[-1], low[-1], high[-1], lam[-1]


def anytime_path(d: np.ndarray, d_hat: np.ndarray | None, d_unl: np.ndarray | None, alpha: float, *,
                 horizon: float = 100.0,
                 floor: np.ndarray | float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The anytime interval after each row t = 1 … n (arrays n × P): what a person watching would see."""
    n, p = d.shape
    use_proxy = d_hat is not None and d_unl is not None and len(d_unl) >= 2
    a_cs = alpha * (1 - PROXY_SHARE) if use_proxy else alpha
    if use_proxy:
        lam = _predictable_weights(d, d_hat, len(d_unl))  # type: ignore[arg-type]
        m_hat = d_unl.mean(0)  # type: ignore[union-attr]
        x = d - lam * (d_hat - m_hat)  # centred: a changing λ_i does not move x's mean, only its spread
        h_m = stats.norm.ppf(1 - alpha * PROXY_SHARE / 2) * d_unl.std(0, ddof=1) / math.sqrt(len(d_unl))  # type: ignore[union-attr]
    else:
        lam, x, h_m = np.zeros((n, p)), d, np.zeros(p)
    t = np.arange(1, n + 1, dtype=float)[:, None]
    s1, s2 = np.cumsum(x, 0), np.cumsum(x * x, 0)
    mean = s1 / t
    var = np.maximum(s2 / t - mean**2, 0.0) * t / np.maximum(t - 1, 1) + np.asarray(floor, float) ** 2 / t
    rho2 = (-2 * math.log(a_cs) + math.log(-2 * math.log(a_cs) + 1)) / horizon
    half = np.sqrt(var) * np.sqrt(2 * (t * rho2 + 1) / (t * t * rho2) * np.log(np.sqrt(t * rho2 + 1) / a_cs))
    # the boundary is asymptotic: with few episodes σ̂ is itself unsure, so it is widened by Student's quantile
    # over the normal one at the same level (→ 1 as episodes grow; without it ~10 % of worlds erred at α = 10 %,
    # nearly all at 3–5 episodes: usefulness.ranking_check)
    half *= stats.t.ppf(1 - a_cs / 2, np.maximum(t - 1, 1)) / stats.norm.ppf(1 - a_cs / 2)
    half[: 2] = np.inf  # one episode has no spread; two are not enough for an asymptotic sequence
    lam_bar = np.cumsum(lam, 0) / t
    est = mean
    return est, est - half - lam_bar * h_m, est + half + lam_bar * h_m, lam_bar


def _predictable_weights(d: np.ndarray, d_hat: np.ndarray, big_n: int) -> np.ndarray:
    """λ_i from rows before i only (0 for the first three), the PPI++ rule on what was seen so far."""
    n = len(d)
    t = np.arange(n, dtype=float)[:, None]  # rows seen before row i
    sd, sh = np.cumsum(d, 0) - d, np.cumsum(d_hat, 0) - d_hat
    sdh, shh = np.cumsum(d * d_hat, 0) - d * d_hat, np.cumsum(d_hat * d_hat, 0) - d_hat * d_hat
    with np.errstate(divide="ignore", invalid="ignore"):
        cov = (sdh - sd * sh / t) / (t - 1)
        var = (shh - sh * sh / t) / (t - 1)
        lam = cov / ((1 + t / big_n) * var)
    lam = np.clip(np.nan_to_num(lam, nan=0.0, posinf=0.0, neginf=0.0), 0.0, 1.0)
    lam[:3] = 0.0
    return lam


def rank_sets(decisions: Sequence[PairDecision], agents: Sequence[str], metric: str) -> dict[str, tuple[int, int]]:
    """Per agent, the best and worst rank it may hold on ``metric`` given the decisions (ties and undecided pairs
    leave both places open)."""
    better = dict.fromkeys(agents, 0)  # agents decided better than it
    worse = dict.fromkeys(agents, 0)  # agents decided worse than it
    for p in decisions:
        if p.metric != metric or p.decision not in ("a>b", "b>a"):
            continue
        win, lose = (p.a, p.b) if p.decision == "a>b" else (p.b, p.a)
        worse[win] += 1
        better[lose] += 1
    k = len(agents)
    return {a: (1 + better[a], k - worse[a]) for a in agents}


def rank(target: Scores, proxy: Scores | None, metrics: Sequence[str], higher: Sequence[bool],
         tolerances: Sequence[float], alpha: float = 0.05, *, sequential: bool = False,
         horizon: float = 100.0) -> Ranking:
    """Decide every pair of ``target``'s agents on every metric (see the module docstring).

    ``target``/``proxy``: agent → episode id → scores per metric. The proxy's episodes with the target's ids are
    its paired predictions; its other ids are proxy-only episodes. Pairs use the ids both agents ran on the
    target (and, for the predictor, on the proxy).

    Every interval counts one more episode of spread σ₀ (the larger of the metric's ε and the target's pooled
    spread of that metric across agents): a pair seen equal in a few episodes of a metric with point masses
    (survival time at the episode's end) is not decided on zero width.
    """
    agents = _check(target, proxy, metrics, higher, tolerances, alpha)
    sigma0 = spread_floor([np.asarray(list(target[a].values()), float).reshape(-1, len(metrics)) for a in agents],
                          tolerances)
    pairs = [(a, b) for i, a in enumerate(agents) for b in agents[i + 1:]]
    level = alpha / (len(pairs) * len(metrics))
    interval = anytime_interval if sequential else fixed_interval
    with_proxy, alone = [], []
    for group, members in _groups(target, proxy, pairs).items():
        ids, unl = group
        d, d_hat, d_unl = _differences(target, proxy, members, ids, unl, len(metrics))
        kw: dict[str, object] = {"floor": np.tile(sigma0, len(members))}
        if sequential:
            kw["horizon"] = horizon
        for out, args in ((with_proxy, (d_hat, d_unl)), (alone, (None, None))):
            est, lo, hi, lam = interval(d, *args, level, **kw)  # type: ignore[operator]
            for j, (a, b) in enumerate(members):
                for m, name in enumerate(metrics):
                    c = j * len(metrics) + m
                    out.append(PairDecision(a, b, name, decide(lo[c], hi[c], tolerances[m], higher[m]),
                                            float(est[c]), (float(lo[c]), float(hi[c])), len(ids), float(lam[c])))
    order = {(a, b): i for i, (a, b) in enumerate(pairs)}
    with_proxy.sort(key=lambda p: (order[(p.a, p.b)], metrics.index(p.metric)))
    alone.sort(key=lambda p: (order[(p.a, p.b)], metrics.index(p.metric)))
    sets = {m: rank_sets(with_proxy, agents, m) for m in metrics}
    return Ranking(tuple(agents), tuple(metrics), alpha, sequential, tuple(with_proxy), tuple(alone), sets,
                   sum(len(v) for v in target.values()), sum(len(v) for v in (proxy or {}).values()))


def spread_floor(episodes: Sequence[np.ndarray], tolerances: Sequence[float]) -> np.ndarray:
    """σ₀ per metric: the larger of its ε and the within-agent spread of the target's episodes (one array,
    episodes × metrics, per agent) pooled over agents (a pair that never differed in ten episodes of survival
    time, while other agents' episodes vary by seconds, must not be a tie: a held-out target's pure-pursuit
    survived all 10, then failed in 1 of 6 more)."""
    out = np.asarray(tolerances, float).copy()
    rows = [np.asarray(r, float) for r in episodes if len(r) >= 2]
    if rows:
        pooled = np.sqrt(np.nanmean([r.var(0, ddof=1) for r in rows], axis=0))
        out = np.maximum(out, np.nan_to_num(pooled))
    return out


def _check(target: Scores, proxy: Scores | None, metrics: Sequence[str], higher: Sequence[bool],
           tolerances: Sequence[float], alpha: float) -> list[str]:
    if not 0.0 < alpha < 1.0:
        raise RankingError(f"alpha: {alpha:g} is not within (0, 1)")
    agents = list(target)
    if len(agents) < 2:
        raise RankingError(f"agents: ranking needs at least 2, got {len(agents)} ({', '.join(agents) or 'none'})")
    if not (len(metrics) == len(higher) == len(tolerances)) or not metrics:
        raise RankingError("metrics: one direction and one tolerance per metric, and at least one metric")
    for a, eps in target.items():
        for e, v in eps.items():
            if len(v) != len(metrics):
                raise RankingError(f"target: {a} episode {e} has {len(v)} scores for {len(metrics)} metrics")
    missing = [a for a in agents if proxy is not None and a not in proxy]
    if missing:
        raise RankingError(f"proxy: no episodes of {', '.join(missing)}")
    return agents


def _groups(target: Scores, proxy: Scores | None,
            pairs: list[tuple[str, str]]) -> dict[tuple[tuple[int, ...], tuple[int, ...]], list[tuple[str, str]]]:
    """Pairs sharing the same target ids and proxy-only ids, computed together."""
    all_target = set().union(*(set(v) for v in target.values()))
    out: dict[tuple[tuple[int, ...], tuple[int, ...]], list[tuple[str, str]]] = {}
    for a, b in pairs:
        ids = set(target[a]) & set(target[b])
        unl: set[int] = set()
        if proxy is not None:
            both = set(proxy[a]) & set(proxy[b])
            ids_p = ids & both
            ids = ids_p if len(ids_p) == len(ids) else ids  # the predictor only where it covers every episode
            unl = both - all_target if len(ids_p) == len(ids) else set()
        out.setdefault((tuple(sorted(ids)), tuple(sorted(unl))), []).append((a, b))
    return out


def _differences(target: Scores, proxy: Scores | None, members: list[tuple[str, str]], ids: tuple[int, ...],
                 unl: tuple[int, ...], m: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(d, d̂, d̂ᵘ): a − b per episode, columns pair-major then metric; each agent's table is built once."""
    def tables(src: Scores, keys: tuple[int, ...]) -> dict[str, np.ndarray]:
        agents = {x for pair in members for x in pair}
        return {a: np.asarray([src[a][e] for e in keys], dtype=float).reshape(len(keys), m) for a in agents}

    def diff(t: dict[str, np.ndarray]) -> np.ndarray:
        return np.hstack([t[a] - t[b] for a, b in members])

    d = diff(tables(target, ids))
    if proxy is None or not unl:
        return d, None, None
    return d, diff(tables(proxy, ids)), diff(tables(proxy, unl))
