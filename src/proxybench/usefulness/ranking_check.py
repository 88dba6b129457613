"""Is the ranking's guarantee kept? Simulated worlds where the truth is known, for tests, benchmarks and docs.

A world: K agents whose episode scores on the target are Y = μ_k + β_k·s_e + noise (s_e: how hard episode e's
start is, shared by every agent on that episode) and on the proxy Ŷ = μ'_k + β'_k·s_e + noise'. The proxy is

- ``good``: μ' = μ + a constant bias, β' = β, less noise (it orders agents like the target and tracks starts);
- ``bad``: adversarial, μ' in the reverse order and β' = −β (it inverts the order and anti-tracks starts);
- ``none``: no proxy (the target alone).

:func:`coverage` runs many worlds and counts those with *any* wrong decision: in the fixed mode after n
episodes; in the anytime mode at *any* episode count 2 … n (a person may stop whenever), which is stricter
than any stopping rule. Its share must stay at most α (its Clopper–Pearson interval is reported).

On real targets, where the truth is only more episodes: :func:`contradicted` counts the decisions that many
further episodes contradict, and :func:`inverted` turns a real proxy adversarial (it orders the agents backwards).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy import stats

from proxybench.usefulness.ranking import PairDecision, Scores, anytime_path, fixed_interval, spread_floor

__all__ = ["Coverage", "World", "contradicted", "coverage", "draw_world", "inverted"]

ProxyKind = Literal["good", "bad", "none"]


@dataclass(frozen=True)
class World:
    """One simulated experiment: target and proxy scores (agents × episodes), the true means and the tolerance."""

    target: np.ndarray  # K × n
    proxy: np.ndarray | None  # K × (n + N): the first n paired with the target's
    means: np.ndarray  # K
    tolerance: float


@dataclass(frozen=True)
class Coverage:
    """What the simulation found: the share of worlds with a wrong decision and how much was decided."""

    mode: str
    proxy: str
    runs: int
    wrong: int
    alpha: float
    decided_with: float  # mean share of pairs decided (with the proxy as predictor)
    decided_alone: float  # the same from the target alone
    episodes_with: float  # anytime mode: median episodes per agent until every pair is decided (inf: never)
    episodes_alone: float
    worth: float  # median over worlds and pairs of (width alone / width with the proxy)²: one episode's worth

    @property
    def share(self) -> float:
        return self.wrong / self.runs

    @property
    def interval(self) -> tuple[float, float]:
        """Clopper–Pearson 95 % interval of the share of worlds with any wrong decision."""
        lo = stats.beta.ppf(0.025, self.wrong, self.runs - self.wrong + 1) if self.wrong else 0.0
        hi = stats.beta.ppf(0.975, self.wrong + 1, self.runs - self.wrong) if self.wrong < self.runs else 1.0
        return float(lo), float(hi)


def draw_world(rng: np.random.Generator, k: int, n: int, big_n: int, proxy: ProxyKind, *, spread: float = 0.6,
               noise: float = 1.0, tolerance: float = 0.1) -> World:
    """A world of ``k`` agents, ``n`` target episodes and ``big_n`` proxy-only episodes each."""
    means = np.sort(rng.normal(0.0, spread, k))
    beta = rng.uniform(0.5, 1.5, k)
    s = rng.normal(0.0, 1.0, n + big_n)
    target = means[:, None] + beta[:, None] * s[None, :n] + rng.normal(0.0, noise, (k, n))
    if proxy == "none":
        return World(target, None, means, tolerance)
    if proxy == "good":
        mu_p, beta_p = means + 0.3, beta
    else:
        mu_p, beta_p = means[::-1].copy(), -beta
    px = mu_p[:, None] + beta_p[:, None] * s[None, :] + rng.normal(0.0, noise * 0.3, (k, n + big_n))
    return World(target, px, means, tolerance)


def _wrong(low: np.ndarray, high: np.ndarray, truth: np.ndarray, eps: float) -> np.ndarray:
    """Per row: does any column's decision contradict the true difference ``truth``?"""
    better, worse = low > eps, high < -eps
    tie = (low >= -eps) & (high <= eps) & (eps > 0)
    bad = (better & (truth <= eps)) | (worse & (truth >= -eps)) | (tie & (np.abs(truth) > eps))
    return bad.any(axis=-1)


def _decided(low: np.ndarray, high: np.ndarray, eps: float) -> np.ndarray:
    return (low > eps) | (high < -eps) | ((low >= -eps) & (high <= eps) & (eps > 0))


def coverage(*, k: int = 5, n: int = 30, big_n: int = 300, proxy: ProxyKind = "good",
             mode: Literal["fixed", "anytime"] = "fixed", runs: int = 200, alpha: float = 0.1,
             seed: int = 0, tolerance: float = 0.1) -> Coverage:
    """Simulate ``runs`` worlds and count those with any wrong decision (see the module docstring)."""
    rng = np.random.default_rng(seed)
    pairs = list(itertools.combinations(range(k), 2))
    level = alpha / len(pairs)
    wrong = 0
    dec_with, dec_alone, ep_with, ep_alone, worth = [], [], [], [], []
    for _ in range(runs):
        w = draw_world(rng, k, n, big_n, proxy, tolerance=tolerance)
        i, j = np.array(pairs).T
        d = (w.target[i] - w.target[j]).T  # n × P
        truth = w.means[i] - w.means[j]
        d_hat = d_unl = None
        if w.proxy is not None:
            dp = (w.proxy[i] - w.proxy[j]).T
            d_hat, d_unl = dp[:n], dp[n:]
        floor = np.full(len(pairs), spread_floor([row[:, None] for row in w.target], [tolerance])[0])  # as rank
        if mode == "fixed":
            _, lo, hi, _ = fixed_interval(d, d_hat, d_unl, level, floor=floor)
            _, lo0, hi0, _ = fixed_interval(d, None, None, level, floor=floor)
            wrong += bool(_wrong(lo, hi, truth, tolerance))
            worth.append(np.median(((hi0 - lo0) / (hi - lo)) ** 2))
            dec_with.append(_decided(lo, hi, tolerance).mean())
            dec_alone.append(_decided(lo0, hi0, tolerance).mean())
            continue
        horizon = float(n)
        _, lo, hi, _ = anytime_path(d, d_hat, d_unl, level, horizon=horizon, floor=floor)
        _, lo0, hi0, _ = anytime_path(d, None, None, level, horizon=horizon, floor=floor)
        wrong += bool(_wrong(lo, hi, truth, tolerance).any())
        worth.append(np.median(((hi0[-1] - lo0[-1]) / (hi[-1] - lo[-1])) ** 2))
        dec_with.append(_decided(lo[-1], hi[-1], tolerance).mean())
        dec_alone.append(_decided(lo0[-1], hi0[-1], tolerance).mean())
        ep_with.append(_first_all(_decided(lo, hi, tolerance)))
        ep_alone.append(_first_all(_decided(lo0, hi0, tolerance)))
    return Coverage(mode, proxy, runs, wrong, alpha, float(np.mean(dec_with)), float(np.mean(dec_alone)),
                    _median(ep_with), _median(ep_alone), _median(worth))


def _median(v: list[float]) -> float:
    return float(np.median(v)) if v else float("nan")


def _first_all(decided: np.ndarray) -> float:
    """The first episode count at which every pair is decided (inf if none)."""
    done = np.flatnonzero(decided.all(axis=1))
    return float(done[0] + 1) if len(done) else float("inf")


def contradicted(pairs: Sequence[PairDecision], truth: Scores, metrics: Sequence[str], tolerances: Sequence[float],
                 higher: Sequence[bool], level: float = 0.95) -> int:
    """How many decisions the ``truth`` episodes (many more, other ids) contradict: their own ``level`` interval
    for the mean of a − b (normal, Welch's spread) lies wholly where the decision says it is not. A lower bound on
    the wrong decisions: a truth of finitely many episodes is itself unsure."""
    z = stats.norm.ppf(0.5 + level / 2)
    out = 0
    for p in pairs:
        m = list(metrics).index(p.metric)
        a = np.asarray([v[m] for v in truth[p.a].values()], float)
        b = np.asarray([v[m] for v in truth[p.b].values()], float)
        a, b = a[np.isfinite(a)], b[np.isfinite(b)]
        if len(a) < 2 or len(b) < 2:
            continue
        diff, se = a.mean() - b.mean(), math.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
        lo, hi = diff - z * se, diff + z * se
        if not higher[m]:
            lo, hi = -hi, -lo
        eps = tolerances[m]
        out += bool({"a>b": hi <= eps, "b>a": lo >= -eps, "tie": lo > eps or hi < -eps}.get(p.decision, False))
    return out


def inverted(proxy: Scores, metric: int = 0, higher: bool = True) -> dict[str, dict[int, np.ndarray]]:
    """An adversarial proxy from a real one: each agent gets the episodes of the agent at the mirrored place of the
    proxy's own order on ``metric`` (the best gets the worst's), so the proxy orders the agents backwards."""
    means = {a: np.nanmean([v[metric] for v in eps.values()]) for a, eps in proxy.items()}
    order = sorted(proxy, key=lambda a: means[a], reverse=higher)
    mirror = dict(zip(order, reversed(order), strict=True))
    return {a: {e: np.asarray(v, float) for e, v in proxy[mirror[a]].items()} for a in proxy}
