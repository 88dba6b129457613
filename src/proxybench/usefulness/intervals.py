"""Confidence intervals for the usefulness figures: a paired BCa bootstrap, and PRPV's order range.

Proxies replay the target's episodes (same start pose and seed), so episode i of an agent in a proxy
and episode i on the target share their start. Resampling therefore draws the *same* episode indices in
both domains (paired), separately for each agent (stratified), with ``scipy.stats.bootstrap``.

- **Smooth figures** — PPV (per agent, mean, sum), Pearson's r, Spearman's ρ, Kendall's τ, MMRV — get
  BCa intervals. Where BCa cannot be computed (a degenerate distribution, e.g. a metric every episode
  caps at the same value, or replicates in which a figure is undefined), or where its bias correction is
  so extreme that the interval misses its own estimate (near-degenerate resamples), the percentile
  interval over the replicates that define it is used instead, and ``Estimate.method`` says so. Every
  reported interval contains its estimate.
- **PRPV** is a step function of the signs of mean differences. Its plug-in value is biased upward by
  noise (a near tie flips at random), and a bootstrap replicate adds that noise once more — why percentile
  intervals could lie wholly above their own point value ("6.0 [8.0, 35.0]") and covered the true PRPV of
  a proxy identical to its target in 0 of 40 simulations. Its interval is instead the **order range**:
  the smallest and largest PRPV over every pair of orders the data cannot rule out. On each metric, the
  order of two agents in one domain is left open when their mean difference's sign is not settled: when
  more than (1 − level)/2 of the paired resamples give it another sign than the rest (a percentile
  interval of the difference that contains 0, or a tie that resampling breaks). Every other pair keeps
  its observed order. The range contains the plug-in value by construction, and is wide exactly when
  many pairs are near ties — which is what more episodes would settle (``proxybench plan``).

Agents with fewer than two episodes give no interval (NaN bounds and a note).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np

from proxybench.usefulness.metrics import (
    Estimate,
    PairedResults,
    agent_means,
    alpha_from_signs,
    constant_metrics,
    correlations,
    mmrv_from_means,
    pair_signs,
    ppv_agents,
    resampled_means,
    target_scale,
)

__all__ = ["OpenPair", "Usefulness", "order_range", "paired_bootstrap", "sign_sets", "usefulness"]

CORRELATIONS = ("pearson", "spearman", "kendall")


@dataclass(frozen=True)
class OpenPair:
    """Two agents whose order in one domain the data leave open (their difference's sign is not settled)."""

    domain: str  # "proxy" | "target"
    a: str
    b: str
    metrics: tuple[str, ...]


@dataclass(frozen=True)
class Usefulness(Mapping[str, Estimate]):
    """Every figure by name (``prpv``, ``ppv``, ``pearson_<metric>``, …) with its interval, plus what a table
    of names cannot hold: per-agent PPV, the PPV scale s_m (β_m = 1/s_m), notes, and the open pairs."""

    estimates: dict[str, Estimate]
    ppv_agents: dict[str, Estimate] = field(default_factory=dict)
    scale: dict[str, float] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    open_pairs: tuple[OpenPair, ...] = ()

    def __getitem__(self, key: str) -> Estimate:
        return self.estimates[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.estimates)

    def __len__(self) -> int:
        return len(self.estimates)


@dataclass
class Bootstrap:
    """Point values, intervals and replicates of a vector of figures (outputs on the first axis)."""

    point: np.ndarray
    low: np.ndarray
    high: np.ndarray
    method: list[str]
    replicates: np.ndarray  # (outputs, n_boot); empty when no interval could be made


def paired_bootstrap(pr: PairedResults, statistic: Callable[[np.ndarray, np.ndarray], np.ndarray], *,
                     n_boot: int, level: float, seed: int) -> Bootstrap:
    """BCa intervals (SciPy) of ``statistic(proxy_means, target_means) -> (outputs, …)`` over episodes
    resampled per agent, the same indices in proxy and target when the episodes are paired.

    An output whose BCa interval is undefined (degenerate, or NaN in some replicates) gets the percentile
    interval over its finite replicates. No agent may have fewer than two episodes (else NaN intervals).
    """
    from scipy.stats import bootstrap

    agents = pr.agents
    proxy = [np.asarray(pr.proxy[a], float) for a in agents]
    target = [np.asarray(pr.target[a], float) for a in agents]
    point = np.asarray(statistic(agent_means(pr.proxy, agents), agent_means(pr.target, agents)), float)
    k = len(agents)
    if pr.paired:
        data = tuple(np.arange(len(t)) for t in target)

        def stat(*idx, axis=-1):
            pm = np.stack([resampled_means(p, i) for p, i in zip(proxy, idx, strict=True)], -2)
            tm = np.stack([resampled_means(t, i) for t, i in zip(target, idx, strict=True)], -2)
            return statistic(pm, tm)
    else:
        data = tuple(np.arange(len(p)) for p in proxy) + tuple(np.arange(len(t)) for t in target)

        def stat(*idx, axis=-1):
            pm = np.stack([resampled_means(p, i) for p, i in zip(proxy, idx[:k], strict=True)], -2)
            tm = np.stack([resampled_means(t, i) for t, i in zip(target, idx[k:], strict=True)], -2)
            return statistic(pm, tm)

    nan = np.full(point.shape, np.nan)
    if min(len(d) for d in data) < 2:
        return Bootstrap(point, nan, nan.copy(), ["none (an agent has one episode)"] * len(point),
                         np.empty((len(point), 0)))
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")  # degenerate outputs: handled below, output by output
        res = bootstrap(data, stat, vectorized=True, n_resamples=n_boot, confidence_level=level, method="BCa",
                        rng=np.random.default_rng([seed, 0xBCA]))
    reps = np.asarray(res.bootstrap_distribution, float).reshape(len(point), -1)
    low = np.asarray(res.confidence_interval.low, float).reshape(-1)
    high = np.asarray(res.confidence_interval.high, float).reshape(-1)
    pairing = "paired" if pr.paired else "unpaired"
    method = [f"BCa, {pairing}"] * len(point)
    for j in range(len(point)):
        method[j], low[j], high[j] = _checked(point[j], low[j], high[j], reps[j], level, pairing)
    return Bootstrap(point, low, high, method, reps)


def _contains(point: float, low: float, high: float) -> bool:
    tol = 1e-9 * max(1.0, abs(point))
    return bool(low - tol <= point <= high + tol)


def _checked(point: float, low: float, high: float, reps: np.ndarray, level: float,
             pairing: str) -> tuple[str, float, float]:
    """(method, low, high) of one output: BCa where it is defined and contains its own estimate, else the
    percentile interval, saying why.

    BCa corrects for bias with z0 = Φ⁻¹(share of replicates below the estimate). On near-degenerate
    resamples (many tied or capped values, a correlation at ±1) almost every replicate lies on one side
    of the estimate, z0 is extreme and the corrected interval can miss the estimate it belongs to (seen:
    PPV "1.63 [1.57, 1.62]"). Such an interval is not reported; where even the percentile interval misses
    the estimate (every replicate on one side), it is widened to the estimate and says so.
    """
    finite = reps[np.isfinite(reps)]
    if not finite.size:
        return "none (undefined in every resample)", np.nan, np.nan
    missing = reps.size - finite.size
    if np.isfinite(low) and np.isfinite(high) and not missing and _contains(point, low, high):
        return f"BCa, {pairing}", low, high
    low, high = np.percentile(finite, [100 * (1 - level) / 2, 100 * (1 + level) / 2])
    if missing:
        why = f"{missing} of {reps.size} resamples undefined"
    elif not (np.isfinite(low) and np.isfinite(high)) or np.ptp(finite) == 0:
        why = "BCa undefined"
    else:
        below = float(np.mean(finite < point))
        why = f"BCa excluded its estimate: {100 * below:.0f} % of resamples below it"
    method = f"percentile, {pairing} ({why})"
    if np.isfinite(point) and not _contains(point, low, high):
        low, high = min(low, point), max(high, point)
        method += "; widened to the estimate, which lies beyond every resample it should centre"
    return method, float(low), float(high)


def sign_sets(point: np.ndarray, replicates: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest plausible sign (−1, 0, +1) of each difference: a sign is ruled out when at most
    (1 − level)/2 of the resamples lie beyond it; the observed sign always stays in."""
    tail = (1 - level) / 2
    if replicates.shape[-1] == 0:
        return point.copy(), point.copy()
    frac = {s: (replicates == s).mean(-1) for s in (-1.0, 0.0, 1.0)}
    lo = np.where(frac[-1.0] > tail, -1.0, np.where(frac[-1.0] + frac[0.0] > tail, 0.0, 1.0))
    hi = np.where(frac[1.0] > tail, 1.0, np.where(frac[1.0] + frac[0.0] > tail, 0.0, -1.0))
    return np.minimum(lo, point), np.maximum(hi, point)


def _alpha_options(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(P, 3) booleans: can α be 0, 0.5, 1 for each pair, given (P, m) plausible sign ranges [lo, hi]."""
    up, down = hi == 1, lo == -1
    can1 = np.all(hi >= 0, -1) & np.any(up, -1)
    can0 = np.all(lo <= 0, -1) & np.any(down, -1)
    mixed = up.sum(-1) * down.sum(-1) - (up & down).sum(-1) > 0  # +1 on one metric, −1 on another
    can_half = np.all((lo <= 0) & (hi >= 0), -1) | mixed
    return np.stack([can0, can_half, can1], -1)


def order_range(lo_p: np.ndarray, hi_p: np.ndarray, lo_t: np.ndarray, hi_t: np.ndarray) -> tuple[float, float]:
    """Smallest and largest PRPV over the orders allowed by (P, m) sign ranges of the K(K−1)/2 pairs."""
    if lo_p.shape[0] == 0:
        return 0.0, 0.0
    values = np.array([0.0, 0.5, 1.0])
    cost = 2 * np.abs(values[:, None] - values[None, :])  # both α_ij and α_ji
    allowed = _alpha_options(lo_p, hi_p)[:, :, None] & _alpha_options(lo_t, hi_t)[:, None, :]
    low = np.where(allowed, cost, np.inf).min((-1, -2)).sum()
    high = np.where(allowed, cost, -np.inf).max((-1, -2)).sum()
    return float(low), float(high)


class _Layout:
    """Names and slices of the outputs stacked into one statistic vector."""

    def __init__(self) -> None:
        self.slices: dict[str, slice] = {}
        self.size = 0

    def add(self, name: str, n: int) -> None:
        self.slices[name] = slice(self.size, self.size + n)
        self.size += n


def usefulness(pr: PairedResults, *, n_boot: int = 500, level: float = 0.95, seed: int = 0,
               scale: np.ndarray | None = None) -> Usefulness:
    """PRPV with its order range; PPV, correlations and MMRV with BCa intervals (see the module docstring).

    ``scale``: s_m per metric for PPV and scaled MMRV (β_m = 1/s_m); default :func:`target_scale` of the
    target's means, fixed once for the point value and every resample.
    """
    agents, names, higher = pr.agents, pr.metric_names, pr.higher_is_better
    k, m = len(agents), len(names)
    pm, tm = agent_means(pr.proxy, agents), agent_means(pr.target, agents)
    notes: list[str] = []
    if scale is None:
        scale, scale_notes = target_scale(tm, names)
        notes += scale_notes
    scale = np.asarray(scale, float)
    ok = np.isfinite(pm).all(1) & np.isfinite(tm).all(1)
    for who, means in (("target", tm), ("proxy", pm)):
        for i in np.flatnonzero(~np.isfinite(means).all(1)):
            gone = ", ".join(n for n, v in zip(names, means[i], strict=True) if not np.isfinite(v))
            notes.append(f"{agents[i]} has no value for {gone} in the {who}: worst on it in PRPV; left out of "
                         "PPV, correlations and MMRV")
    defined = ~(constant_metrics(tm[ok]) | constant_metrics(pm[ok])) if ok.sum() >= 2 else np.zeros(m, bool)
    for j in np.flatnonzero(~defined):
        where = " and ".join(w for w, c in (("target", tm), ("proxy", pm))
                             if ok.sum() < 2 or constant_metrics(c[ok])[j])
        notes.append(f"{names[j]} is the same for every agent in the {where}: no correlation for it"
                     + (f"; Pearson, Spearman and Kendall summarise {', '.join(np.array(names)[defined])}"
                        if defined.any() else "; no correlation summary"))
    pairs = np.triu_indices(k, 1)
    lay = _Layout()
    for name, n in (("ppv_agent", k), ("ppv", 1), ("ppv_sum", 1), *((c, 1) for c in CORRELATIONS),
                    *((f"{c}_m", m) for c in CORRELATIONS), ("mmrv_m", m), ("mmrv_scaled", 1),
                    ("sign_p", len(pairs[0]) * m), ("sign_t", len(pairs[0]) * m)):
        lay.add(name, n)

    def statistic(p: np.ndarray, t: np.ndarray) -> np.ndarray:
        out = np.empty((lay.size, *p.shape[:-2]))
        per = np.where(ok, ppv_agents(p, t, scale), np.nan)
        out[lay.slices["ppv_agent"]] = np.moveaxis(per, -1, 0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            out[lay.slices["ppv"]] = np.nanmean(per[..., ok], -1)[None] if ok.any() else np.nan
            out[lay.slices["ppv_sum"]] = per[..., ok].sum(-1)[None] if ok.any() else np.nan
        sp, st = p[..., ok, :] * np.where(higher, 1.0, -1.0), t[..., ok, :] * np.where(higher, 1.0, -1.0)
        corr = correlations(sp, st) if ok.sum() >= 2 else {c: np.full((*p.shape[:-2], m), np.nan)
                                                            for c in CORRELATIONS}
        for c in CORRELATIONS:
            vals = np.where(defined, corr[c], np.nan)
            out[lay.slices[f"{c}_m"]] = np.moveaxis(vals, -1, 0)
            out[lay.slices[c]] = (corr[c][..., defined].mean(-1) if defined.any() else np.nan)
        mm = mmrv_from_means(sp, st) if ok.sum() >= 2 else np.zeros((*p.shape[:-2], m))
        out[lay.slices["mmrv_m"]] = np.moveaxis(mm, -1, 0)
        out[lay.slices["mmrv_scaled"]] = (mm / scale).mean(-1)
        for key, means in (("sign_p", p), ("sign_t", t)):
            s = pair_signs(means, higher)[..., pairs[0], pairs[1], :]  # (…, P, m)
            out[lay.slices[key]] = np.moveaxis(s.reshape((*s.shape[:-2], -1)), -1, 0)
        return out

    boot = paired_bootstrap(pr, statistic, n_boot=n_boot, level=level, seed=seed)
    if np.isnan(boot.low[lay.slices["ppv"]]).all() and boot.replicates.shape[1] == 0:
        notes.append("no intervals: an agent has a single episode")

    def est(name: str, j: int = 0) -> Estimate:
        s = lay.slices[name].start + j
        return Estimate(float(boot.point[s]), float(boot.low[s]), float(boot.high[s]), boot.method[s])

    out: dict[str, Estimate] = {}
    prpv, rng, open_pairs = _prpv(boot, lay, pairs, agents, names, level)
    if not boot.replicates.shape[1]:
        rng = (float("nan"), float("nan"))
    out["prpv"] = Estimate(prpv, *rng, "order range" if boot.replicates.shape[1] else boot.method[0])
    norm = max(k * (k - 1), 1)
    out["prpv_norm"] = Estimate(prpv / norm, rng[0] / norm, rng[1] / norm, out["prpv"].method)
    out["ppv"], out["ppv_sum"] = est("ppv"), est("ppv_sum")
    for c in CORRELATIONS:
        out[c] = est(c)
    for c in CORRELATIONS:
        for j, n in enumerate(names):
            out[f"{c}_{n}"] = est(f"{c}_m", j)
    for j, n in enumerate(names):
        out[f"mmrv_{n}"] = est("mmrv_m", j)
    out["mmrv_scaled"] = est("mmrv_scaled")
    return Usefulness(out, {a: est("ppv_agent", i) for i, a in enumerate(agents)},
                      dict(zip(names, scale.tolist(), strict=True)), tuple(notes), tuple(open_pairs))


def _prpv(boot: Bootstrap, lay: _Layout, pairs, agents, names, level) -> tuple[float, tuple[float, float], list]:
    """Plug-in PRPV, its order range, and the pairs whose order is open in either domain."""
    n_pairs, m = len(pairs[0]), len(names)
    ranges, open_pairs = [], []
    for key, domain in (("sign_p", "proxy"), ("sign_t", "target")):
        sl = lay.slices[key]
        point = boot.point[sl].reshape(n_pairs, m)
        if boot.replicates.shape[1] and n_pairs:
            lo, hi = sign_sets(point, boot.replicates[sl].reshape(n_pairs, m, -1), level)
        else:
            lo, hi = point, point
        ranges.append((lo, hi, point))
        for q in np.flatnonzero(_alpha_options(lo, hi).sum(-1) > 1):  # α can take more than one value
            open_pairs.append(OpenPair(domain, agents[pairs[0][q]], agents[pairs[1][q]],
                                       tuple(n for n, o in zip(names, lo[q] != hi[q], strict=True) if o)))
    (lo_p, hi_p, pt_p), (lo_t, hi_t, pt_t) = ranges
    prpv = float(2 * np.abs(alpha_from_signs(pt_p) - alpha_from_signs(pt_t)).sum())
    return prpv, order_range(lo_p, hi_p, lo_t, hi_t), open_pairs
