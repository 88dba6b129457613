"""Intervals for PLV: a percentile bootstrap over seeds, with the whole PLV computation inside each replicate.

What varies between seeds: for the target-only curve, the network's initialisation, the subset of
target data and the minibatch order; for a proxy, the pre-training (initialisation, minibatch order on
the proxy data) and the fine-tuning that follows it (a seed is one pre-training → fine-tuning chain).
The evaluation episodes are the same for every network (common random numbers), so they add no noise
*between* arms.

One replicate resamples the seeds with replacement, averages each rung over the drawn seeds, and
recomputes everything downstream: the converged score, the reference P, |D_target|, each proxy's
|D_proxy→target| (the same "reach and stay above" rule, :func:`proxybench.usefulness.plv.settled_rung`),
PLV and the reduction. Seeds shared by the target-only curve and a proxy (the same data subset for seed
s) are resampled *together* (paired), as the PLV compares the two routes on the same data.
The interval is the 2.5 … 97.5 % percentile of the replicates (Efron & Tibshirani 1993, ch. 13); a
replicate in which a proxy never settles above P counts as "not reached" (PLV −∞), so an interval
reads "[not reached, 900]" when that happens in more than 2.5 % of them.

Few seeds make any interval rough: the bootstrap of a mean of 3 seeds is, at 95 %, essentially the
range of the three, which covers the true median with probability 1 − 2·0.5³ = 75 %; with 5 seeds,
94 %. Agarwal et al. (2021, "Deep RL at the Edge of the Statistical Precipice") recommend exactly this
kind of bootstrap over runs for few-run learning experiments, and warn of the same limit.

>>> import numpy as np
>>> band = mean_band(np.array([1.0, 2.0, 3.0]), replicates=4000, seed=0)
>>> band[0], band[1] >= 1.0, band[2] <= 3.0        # a mean's band stays inside the seeds' range
(2.0, True, True)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from proxybench.usefulness.plv import reference_score, settled_rung

__all__ = ["Curve", "Interval", "PLVIntervals", "curves_from_runs", "mean_band", "plv_bootstrap"]

REPLICATES = 4000


@dataclass(frozen=True)
class Curve:
    """One arm's scores: ``scores[s, r]`` of seed ``seeds[s]`` at rung ``costs[r]`` (0 = zero-shot)."""

    costs: np.ndarray
    seeds: tuple[int, ...]
    scores: np.ndarray
    through_end: bool  # the rungs tried run to the end of the ladder

    def __post_init__(self) -> None:
        if self.scores.shape != (len(self.seeds), len(self.costs)):
            raise ValueError(f"scores must be seeds × rungs = {len(self.seeds)} × {len(self.costs)}, "
                             f"got {self.scores.shape}")

    def means(self) -> np.ndarray:
        return self.scores.mean(axis=0)


@dataclass(frozen=True)
class Interval:
    """A point estimate and its percentile interval; None stands for "not reached" (PLV −∞, samples +∞)."""

    estimate: float | None
    low: float | None
    high: float | None

    def label(self, fmt: str = "{:,.0f}", none: str = "not reached", scale: float = 1.0) -> str:
        """``estimate [low, high]`` in ``fmt`` (values times ``scale``), ``none`` for a missing end."""
        def one(v: float | None) -> str:
            return none if v is None else fmt.format(v * scale)

        if self.estimate is None and self.low is None and self.high is None:
            return none
        return f"{one(self.estimate)} [{one(self.low)}, {one(self.high)}]"


@dataclass
class PLVIntervals:
    """Bootstrap intervals of the reference, |D_target| and, per proxy, |D_proxy→target|, PLV and reduction."""

    reference: Interval
    target_needed: Interval
    needed: dict[str, Interval] = field(default_factory=dict)
    plv: dict[str, Interval] = field(default_factory=dict)
    reduction: dict[str, Interval] = field(default_factory=dict)
    reached: dict[str, float] = field(default_factory=dict)  # share of replicates in which the proxy settled
    replicates: int = REPLICATES
    level: float = 0.95
    paired: dict[str, bool] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        def iv(i: Interval) -> dict[str, Any]:
            return {"estimate": i.estimate, "low": i.low, "high": i.high}

        return {"reference": iv(self.reference), "target_needed": iv(self.target_needed),
                "needed": {k: iv(v) for k, v in self.needed.items()}, "plv": {k: iv(v) for k, v in self.plv.items()},
                "reduction": {k: iv(v) for k, v in self.reduction.items()}, "reached": self.reached,
                "replicates": self.replicates, "level": self.level, "paired": self.paired,
                "method": "percentile bootstrap over seeds"}


def curves_from_runs(runs: Sequence[dict[str, Any]], arm: str, ladder: Sequence[float],
                     zero_shot: dict[int, float] | None = None) -> Curve:
    """An arm's seeds × rungs matrix from the experiment's run records (``cost``, ``seed``, ``score``).

    ``zero_shot`` (seed → score) adds rung 0 for a proxy. Only seeds present on every rung are kept,
    so that each column averages the same seeds.
    """
    rows = [r for r in runs if r["arm"] == arm]
    zero_shot = None if zero_shot is None else {int(k): float(v) for k, v in zero_shot.items()}
    costs = sorted({float(r["cost"]) for r in rows})
    sets = [{int(r["seed"]) for r in rows if float(r["cost"]) == c} for c in costs]
    if zero_shot is not None:
        sets.append({int(s) for s in zero_shot})
    seeds = sorted(set.intersection(*sets)) if sets else []
    at = {(int(r["seed"]), float(r["cost"])): float(r["score"]) for r in rows}
    cols = [[at[(s, c)] for s in seeds] for c in costs]
    if zero_shot is not None:
        cols.insert(0, [float(zero_shot[s]) for s in seeds])
        costs.insert(0, 0.0)
    scores = np.array(cols, dtype=float).T.reshape(len(seeds), len(costs))
    top = max(float(c) for c in ladder) if ladder else 0.0
    ladder_costs = {float(r["cost"]) for r in rows if float(r["n"]) == top}
    return Curve(np.array(costs, dtype=float), tuple(seeds), scores, bool(ladder_costs))


def mean_band(values: np.ndarray, level: float = 0.95, replicates: int = REPLICATES,
              seed: int = 0) -> tuple[float, float, float]:
    """Mean of ``values`` (one per seed) and the percentile-bootstrap interval of that mean.

    The interval lies inside [min, max] of the values, so it never leaves the score's possible range.
    """
    v = np.asarray(values, dtype=float)
    m = float(v.mean())
    if v.size < 2:
        return m, m, m
    idx = np.random.default_rng(seed).integers(0, v.size, (replicates, v.size))
    lo, hi = _percentiles(v[idx].mean(axis=1), level)
    return m, float(lo), float(hi)


def _percentiles(x: np.ndarray, level: float) -> tuple[float, float]:
    """Order-statistic percentiles (no interpolation, so ±inf and ladder values stay what they are)."""
    s = np.sort(x)
    a = (1.0 - level) / 2.0
    lo = s[int(np.floor(a * (s.size - 1)))]
    hi = s[int(np.ceil((1.0 - a) * (s.size - 1)))]
    return float(lo), float(hi)


def _settled(costs: np.ndarray, means: np.ndarray, threshold: np.ndarray, confirm: int,
             through_end: bool) -> np.ndarray:
    """:func:`settled_rung` for every replicate (rows of ``means``): the cost, or +inf when not settled."""
    above = means >= threshold[:, None]
    tail = np.flip(np.cumprod(np.flip(above, axis=1), axis=1), axis=1).astype(bool)  # above from r to the end
    any_tail = tail.any(axis=1)
    k = np.where(any_tail, np.argmax(tail, axis=1), costs.size)
    confirmed = (costs.size - 1 - k >= confirm) | through_end
    ok = any_tail & confirmed
    return np.where(ok, costs[np.minimum(k, costs.size - 1)], np.inf)


def _interval(point: float | None, reps: np.ndarray, level: float, bad: float) -> Interval:
    lo, hi = _percentiles(reps, level)

    def clean(v: float) -> float | None:
        return None if not np.isfinite(v) or v == bad else float(v)

    return Interval(point, clean(lo), clean(hi))


def plv_bootstrap(target: Curve, proxies: dict[str, Curve], tolerance: float, confirm: int,
                  replicates: int = REPLICATES, level: float = 0.95, seed: int = 0) -> PLVIntervals:
    """Percentile-bootstrap intervals over seeds for P, |D_target|, and each proxy's needs, PLV and reduction."""
    rng = np.random.default_rng(seed)
    nt = len(target.seeds)
    it = rng.integers(0, nt, (replicates, nt))
    t_means = target.scores[it].mean(axis=1)  # replicates × rungs
    ref = np.array([reference_score(float(c), tolerance) for c in t_means[:, -1]])
    d_t = _settled(target.costs, t_means, ref, confirm, target.through_end)
    ref0 = reference_score(float(target.means()[-1]), tolerance)
    dt0 = settled_rung(target.costs, target.means(), ref0, confirm, target.through_end)
    lo, hi = _percentiles(ref, level)
    out = PLVIntervals(Interval(ref0, lo, hi), _interval(dt0, d_t, level, np.inf), replicates=replicates,
                       level=level)
    for name, curve in proxies.items():
        paired = curve.seeds == target.seeds
        ip = it if paired else rng.integers(0, len(curve.seeds), (replicates, len(curve.seeds)))
        d_p = _settled(curve.costs, curve.scores[ip].mean(axis=1), ref, confirm, curve.through_end)
        dp0 = settled_rung(curve.costs, curve.means(), ref0, confirm, curve.through_end)
        value = np.where(np.isfinite(d_t) & np.isfinite(d_p), d_t - d_p, -np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            red = np.where(np.isfinite(value) & (d_t > 0), value / np.where(d_t > 0, d_t, 1.0), -np.inf)
        v0 = None if dt0 is None or dp0 is None else float(dt0 - dp0)
        r0 = None if v0 is None or not dt0 else v0 / dt0
        out.needed[name] = _interval(dp0, d_p, level, np.inf)
        out.plv[name] = _interval(v0, value, level, -np.inf)
        out.reduction[name] = _interval(r0, red, level, -np.inf)
        out.reached[name] = float(np.isfinite(d_p).mean())
        out.paired[name] = paired
    return out
