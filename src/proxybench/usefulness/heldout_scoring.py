"""Scoring the held-out experiment: the θ grid, the "best available θ", the criteria, hit rates.

**Best available θ** (the reference a metric's pick is scored against) is defined from the *ordering* of
the agents, measured on a separate, larger set of *reference episodes* that the metrics never see:

    D(θ) = Σ over agent pairs (i, j) and task metrics m that the target's reference episodes resolve
           (|mean_i − mean_j| > 1.96 × its standard error) of [the proxy's reference means order
           i and j the other way on m] (a proxy tie counts ½);
    best available = every grid θ with the smallest D.

Why this and not the hidden truth: a proxy is useful for *predicting* when it orders the agents as the
target does, and with structural differences the θ that does so need not be the one nearest the truth
(the negative case: a lens the proxies do not model moves it). Why not PRPV on more episodes: that would
make PRPV's own argmin the answer key. D counts per metric and per pair, which is what every metric under
test (PRPV, PPV, SRCC, Spearman, Kendall, MMRV) tries to capture in its own way, and only pairs the target
itself separates, so noise ties are not scored. The reference episodes are disjoint from the evaluation
episodes (other seeds), so a pick and its answer key share no sampling noise. The nearest-to-truth θ is
scored as a second reference, revealed only after every episode ran.

>>> g = Grid(("trim",), ((-0.1, 0.0, 0.1),))
>>> g.nearest({"trim": 0.04}), g.distance(0, 2), round(g.chance({1}, 1), 3)
([1], 2, 1.0)
>>> tuple(round(x, 3) for x in wilson(7, 10))
(0.397, 0.892)
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from proxybench.usefulness.metrics import pair_signs

__all__ = ["METRICS", "Grid", "best_available", "chance_rate", "disagreement_from_means", "mcnemar_p",
           "order_disagreement", "ordered_stats", "reference_stability", "wilson"]

Results = Mapping[str, np.ndarray]

#: (key in usefulness(), alternative key, label, +1 higher is better / −1 lower is better)
METRICS: tuple[tuple[str, str, str, int], ...] = (
    ("prpv", "prpv", "PRPV", -1),
    ("ppv", "ppv", "PPV", -1),
    ("pearson", "srcc", "SRCC (Pearson r)", +1),
    ("spearman", "spearman", "Spearman ρ", +1),
    ("kendall", "kendall", "Kendall τ", +1),
    ("mmrv_scaled", "mmrv", "MMRV", -1),  # per metric, scaled by the target's spread, averaged
)


@dataclass(frozen=True)
class Grid:
    """A full factorial grid of proxy θ: ``names[d]`` takes ``values[d]`` (sorted)."""

    names: tuple[str, ...]
    values: tuple[tuple[float, ...], ...]

    @classmethod
    def from_dict(cls, grid: Mapping[str, Sequence[float]]) -> Grid:
        return cls(tuple(grid), tuple(tuple(sorted(float(v) for v in vs)) for vs in grid.values()))

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(len(v) for v in self.values)

    @property
    def indices(self) -> list[tuple[int, ...]]:
        return list(itertools.product(*(range(n) for n in self.shape)))

    @property
    def points(self) -> list[dict[str, float]]:
        return [{n: self.values[d][i[d]] for d, n in enumerate(self.names)} for i in self.indices]

    def __len__(self) -> int:
        return int(np.prod(self.shape))

    def label(self, k: int) -> str:
        return ", ".join(f"{n}={v:g}" for n, v in self.points[k].items())

    def distance(self, a: int, b: int) -> int:
        """Grid steps between points a and b along the axis where they differ most (Chebyshev)."""
        ia, ib = self.indices[a], self.indices[b]
        return max(abs(x - y) for x, y in zip(ia, ib, strict=True))

    def steps(self) -> np.ndarray:
        return np.array([float(np.min(np.diff(v))) if len(v) > 1 else 1.0 for v in self.values])

    def nearest(self, truth: Mapping[str, float]) -> list[int]:
        """The grid points nearest ``truth``, distance measured in grid steps of each axis (ties: all)."""
        pts = np.array([[p[n] for n in self.names] for p in self.points])
        t = np.array([float(truth[n]) for n in self.names])
        d = np.sqrt((((pts - t) / self.steps()) ** 2).sum(1))
        return [int(i) for i in np.flatnonzero(np.isclose(d, d.min(), rtol=0, atol=1e-9))]

    def within(self, k: int, targets: set[int] | Sequence[int], tolerance: int) -> bool:
        return any(self.distance(k, t) <= tolerance for t in targets)

    def chance(self, targets: set[int] | Sequence[int], tolerance: int) -> float:
        """The share of grid points that satisfy the criterion: what a uniformly random pick scores."""
        return float(np.mean([self.within(k, targets, tolerance) for k in range(len(self))]))


def ordered_stats(res: Results, agents: Sequence[str], higher: Sequence[bool]) -> tuple[np.ndarray, np.ndarray]:
    """(means, standard errors), each (K, m), of per-agent results turned so that higher is better."""
    sign = np.where(np.asarray(higher), 1.0, -1.0)
    means, ses = [], []
    for a in agents:
        x = np.asarray(res[a], dtype=float)
        n = np.sum(np.isfinite(x), axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            means.append(np.nanmean(x, axis=0) * sign)
            sd = np.nanstd(x, axis=0, ddof=1) if x.shape[0] > 1 else np.zeros(x.shape[1])
        ses.append(np.nan_to_num(sd) / np.sqrt(np.maximum(n, 1)))
    return np.stack(means), np.stack(ses)


def disagreement_from_means(proxy_means: np.ndarray, target_means: np.ndarray, target_se: np.ndarray,
                            z: float = 1.96) -> tuple[np.ndarray, int]:
    """D of (…, K, m) proxy means (higher is better) against the target's (K, m) means and standard errors,
    and the number of (pair, metric) entries the target resolves."""
    dt = target_means[:, None, :] - target_means[None, :, :]
    se = np.sqrt(target_se[:, None, :] ** 2 + target_se[None, :, :] ** 2)
    k = target_means.shape[0]
    upper = np.triu(np.ones((k, k), dtype=bool), 1)[:, :, None]
    with np.errstate(invalid="ignore"):
        mask = np.isfinite(dt) & (np.abs(dt) > z * se) & (dt != 0) & upper
    sp = pair_signs(proxy_means, (True,) * proxy_means.shape[-1])  # a proxy mean without a value is worst
    wrong = np.where(sp == 0, 0.5, (sp != np.sign(np.nan_to_num(dt))).astype(float))
    return (wrong * mask).sum((-1, -2, -3)), int(mask.sum())


def order_disagreement(proxy: Results, target: Results, higher: Sequence[bool], z: float = 1.96
                       ) -> tuple[float, int]:
    """(D, number of resolved (pair, metric) entries): how often the proxy orders a pair the target's
    episodes resolve the other way (see the module docstring).

    >>> t = {"a": np.array([[3.0], [3.1]]), "b": np.array([[1.0], [1.1]]), "c": np.array([[2.0], [2.1]])}
    >>> p = {"a": np.array([[1.0]]), "b": np.array([[3.0]]), "c": np.array([[2.0]])}
    >>> order_disagreement(p, t, (True,)), order_disagreement(t, t, (True,))
    ((3.0, 3), (0.0, 3))
    """
    agents = list(target)
    tm, ts = ordered_stats(target, agents, higher)
    pm, _ = ordered_stats(proxy, agents, higher)
    d, n = disagreement_from_means(pm, tm, ts, z)
    return float(d), n


def best_available(proxies: Sequence[Results], target: Results, higher: Sequence[bool]) -> tuple[list[int], np.ndarray]:
    """(indices of the proxies with the smallest D, D of every proxy)."""
    d = np.array([order_disagreement(p, target, higher)[0] for p in proxies])
    return [int(i) for i in np.flatnonzero(np.isclose(d, d.min(), rtol=0, atol=1e-9))], d


def reference_stability(proxies: Sequence[Results], target: Results, higher: Sequence[bool], best: Sequence[int],
                        *, n_boot: int = 100, seed: int = 0) -> float:
    """Share of paired resamples of the reference episodes whose best-available set meets ``best``."""
    if n_boot <= 0:
        return float("nan")
    rng = np.random.default_rng([seed, 0x2EF])
    hits = 0
    for _ in range(n_boot):
        idx = {a: rng.integers(0, len(target[a]), len(target[a])) for a in target}
        t = {a: np.asarray(target[a])[idx[a]] for a in target}
        ps = [{a: np.asarray(p[a])[idx[a]] for a in target} for p in proxies]
        hits += bool(set(best_available(ps, t, higher)[0]) & set(best))
    return hits / n_boot


def chance_rate(grid: Grid, targets: Sequence[int], tolerance: int) -> float:
    return grid.chance(set(targets), tolerance)


def wilson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a proportion k/n."""
    if n == 0:
        return float("nan"), float("nan")
    from scipy.stats import binomtest

    ci = binomtest(k, n).proportion_ci(level, method="wilson")
    return float(ci.low), float(ci.high)


def mcnemar_p(a_hits: Sequence[bool], b_hits: Sequence[bool]) -> tuple[int, int, float]:
    """(a hit & b missed, a missed & b hit, exact two-sided McNemar p) over the same cases."""
    from scipy.stats import binomtest

    b = sum(bool(x) and not bool(y) for x, y in zip(a_hits, b_hits, strict=True))
    c = sum(bool(y) and not bool(x) for x, y in zip(a_hits, b_hits, strict=True))
    return b, c, (float(binomtest(b, b + c, 0.5).pvalue) if b + c else 1.0)
