"""How much of a PRPV is sampling noise: the target's own noise floor and paired comparisons of proxies.

Dominance follows :mod:`proxybench.usefulness.metrics` (one implementation: a missing value is worst).
Both resample episodes with replacement, per agent; the paired comparison resamples the *same* episode
indices in the target and in every proxy, which replay the target's episodes from the same starts and
seeds (``proxybench.targets``), so differences between θ values are not drowned by episode-to-episode
variation they share.

- **Noise floor**: PRPV between two independent resamples of the target's own episodes — what two
  replicates of the target, each with this many episodes per agent, differ by. A proxy whose PRPV lies
  within it cannot be told from a perfect proxy with these data.
- **Paired Δ**: for θ values a and b, ΔPRPV = PRPV(a) − PRPV(b) in each paired resample; "PRPV is lowest
  at a" is claimed only when the interval of Δ against each neighbour lies below 0.

>>> import numpy as np
>>> t = {"x": np.array([[3.0], [3.1]]), "y": np.array([[1.0], [1.2]])}
>>> prpv_from_means(np.array([[3.0], [1.0]]), np.array([[1.0], [3.0]]), (True,))
2.0
>>> noise_floor(t, (True,), n_boot=50).value
0.0
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from proxybench.usefulness.metrics import Estimate, dominance_from_means, prpv_from_means
from proxybench.usefulness.metrics import resampled_means as _resampled_means

__all__ = ["PairedComparison", "compare_paired", "dominance_from_means", "lowest_claim", "noise_floor",
           "paired_prpv_samples", "ppv_noise_floor", "prpv_from_means"]

Results = Mapping[str, np.ndarray]


def _level(samples: np.ndarray, level: float) -> tuple[float, float]:
    s = samples[np.isfinite(samples)]
    if not s.size:
        return float("nan"), float("nan")
    lo, hi = np.percentile(s, [100 * (1 - level) / 2, 100 * (1 + level) / 2])
    return float(lo), float(hi)


def _replicates(target: Results, n_boot: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Two independent (n_boot, K, m) resamples of the target's agent means (same episode count per agent)."""
    agents = list(target)
    rng = np.random.default_rng([seed, 0x4015E])
    a = np.stack([_resampled_means(np.asarray(target[k], float),
                                   rng.integers(0, len(target[k]), (n_boot, len(target[k])))) for k in agents], 1)
    b = np.stack([_resampled_means(np.asarray(target[k], float),
                                   rng.integers(0, len(target[k]), (n_boot, len(target[k])))) for k in agents], 1)
    return a, b


def noise_floor(target: Results, higher: Sequence[bool], *, n_boot: int = 300, level: float = 0.95,
                seed: int = 0) -> Estimate:
    """PRPV of the target against a replicate of itself: median and interval over pairs of resamples."""
    a, b = _replicates(target, n_boot, seed)
    samples = prpv_from_means(a, b, higher)
    lo, hi = _level(np.asarray(samples), level)
    return Estimate(float(np.median(samples)), lo, hi, "target vs a replicate of itself")


def ppv_noise_floor(target: Results, *, n_boot: int = 300, level: float = 0.95, seed: int = 0,
                    scale: np.ndarray | None = None) -> Estimate:
    """PPV (mean over agents, β fixed from the target) of the target against a replicate of itself.

    PPV sums |differences|, so noise alone makes it positive; a proxy whose PPV lies within this floor is
    as close to the target as the target's own replicates are (its interval cannot reach 0).
    """
    from proxybench.usefulness.metrics import agent_means, ppv_agents, target_scale

    if scale is None:
        scale = target_scale(agent_means(target, list(target)))[0]
    a, b = _replicates(target, n_boot, seed)
    with np.errstate(invalid="ignore"):
        samples = np.nanmean(ppv_agents(a, b, scale), -1)
    lo, hi = _level(samples, level)
    return Estimate(float(np.nanmedian(samples)), lo, hi, "target vs a replicate of itself")


def paired_prpv_samples(target: Results, proxies: Sequence[Results], higher: Sequence[bool], *, n_boot: int = 300,
                        seed: int = 0) -> np.ndarray:
    """(n_boot, P) PRPV of each proxy against the target, with the same episodes resampled in all of them.

    Every proxy must hold, for each agent, as many episodes as the target, in the target's order (episode
    i of a proxy replays episode i of the target).
    """
    agents = list(target)
    rng = np.random.default_rng([seed, 0xDA1])
    idx = {k: rng.integers(0, len(target[k]), (n_boot, len(target[k]))) for k in agents}
    for p in proxies:
        for k in agents:
            if len(p[k]) != len(target[k]):
                raise ValueError(f"agent {k!r}: a proxy has {len(p[k])} episodes, the target {len(target[k])}; "
                                 "paired resampling needs the proxies to replay the target's episodes")
    tm = np.stack([_resampled_means(np.asarray(target[k], float), idx[k]) for k in agents], 1)
    out = np.empty((n_boot, len(proxies)))
    for j, p in enumerate(proxies):
        pm = np.stack([_resampled_means(np.asarray(p[k], float), idx[k]) for k in agents], 1)
        out[:, j] = prpv_from_means(pm, tm, higher)
    return out


@dataclass(frozen=True)
class PairedComparison:
    """ΔPRPV = PRPV(a) − PRPV(b) over paired resamples: point value, interval, and whether it excludes 0."""

    a: str
    b: str
    delta: Estimate

    @property
    def a_lower(self) -> bool:
        return self.delta.high < 0

    @property
    def separated(self) -> bool:
        return self.delta.high < 0 or self.delta.low > 0


def compare_paired(labels: Sequence[str], points: Sequence[float], samples: np.ndarray, a: int, b: int,
                   level: float = 0.95) -> PairedComparison:
    """Paired comparison of entries ``a`` and ``b`` of :func:`paired_prpv_samples`' columns."""
    lo, hi = _level(samples[:, a] - samples[:, b], level)
    delta = float(points[a] - points[b])
    method = "percentile of paired resamples"
    if np.isfinite(delta) and np.isfinite(lo) and not lo <= delta <= hi:  # a plug-in PRPV is biased by noise
        lo, hi = min(lo, delta), max(hi, delta)
        method += "; widened to the estimate, which lies beyond the resamples"
    return PairedComparison(labels[a], labels[b], Estimate(delta, lo, hi, method))


def lowest_claim(labels: Sequence[str], points: Sequence[float], samples: np.ndarray,
                 level: float = 0.95) -> tuple[int, list[PairedComparison], list[int]]:
    """Where PRPV is lowest along one swept parameter, and what the data can say about it.

    Returns the index of the lowest point value, its paired comparisons with its neighbours in the sweep
    (the values next to it), and the indices of every value *not* separated from it (its plausible set).
    "Lowest at X" holds only if every neighbour comparison has ``a_lower``.
    """
    best = int(np.argmin(points))
    neigh = [j for j in (best - 1, best + 1) if 0 <= j < len(points)]
    comps = [compare_paired(labels, points, samples, best, j, level) for j in neigh]
    plausible = [j for j in range(len(points))
                 if j == best or not compare_paired(labels, points, samples, best, j, level).a_lower]
    return best, comps, plausible
