"""How often the usefulness intervals cover the truth: simulations with a known true PRPV and PPV.

A synthetic proxy and target: K agents with known mean performance on m metrics in each domain. An
episode's score is its agent's mean, plus a start effect that the proxy episode shares with the target
episode it replays (the pairing of :mod:`proxybench.targets`), plus independent noise. The true PRPV and
PPV follow from the means, so the share of simulated experiments whose interval holds them is the
interval's coverage. :func:`percentile_prpv` is the interval proxybench reported before the order range
(a percentile bootstrap resampling proxy and target independently), kept as the baseline.

    python benchmarks/bench_coverage.py        # the table in docs/usefulness.md
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from proxybench.usefulness.intervals import usefulness
from proxybench.usefulness.metrics import PairedResults, ppv_agents, prpv_from_means, resampled_means, target_scale

__all__ = ["Scenario", "coverage", "percentile_prpv", "sample", "scenarios"]


@dataclass(frozen=True)
class Scenario:
    """Known (K, m) means of the agents in the proxy and on the target, and the episode noise."""

    name: str
    proxy: np.ndarray
    target: np.ndarray
    sd_start: float = 0.3  # start effect, shared by a proxy episode and the target episode it replays
    sd: float = 0.3  # independent noise of each episode
    higher: tuple[bool, ...] = field(default=())

    @property
    def directions(self) -> tuple[bool, ...]:
        return self.higher or (True,) * self.target.shape[1]

    @property
    def scale(self) -> np.ndarray:
        """s_m of the true target means: the yardstick PPV is defined with (not an estimate under test)."""
        return target_scale(self.target)[0]

    def true_prpv(self) -> float:
        return float(prpv_from_means(self.proxy, self.target, self.directions))

    def true_ppv(self) -> float:
        return float(ppv_agents(self.proxy, self.target, self.scale).mean())


def scenarios(k: int = 6) -> dict[str, Scenario]:
    """Four cases: an identical proxy (true PRPV 0), near ties, a swapped pair, an offset proxy (PPV > 0)."""
    lin = np.linspace(0.0, 3.0, k)
    target = np.stack([lin, 0.5 * lin + np.resize([0.0, 0.1, 0.05, 0.3, 0.2, 0.4], k)], 1)
    near = target.copy()
    near[:, 0] = np.repeat(np.linspace(0.0, 3.0, (k + 1) // 2), 2)[:k] + np.resize([0.0, 0.08], k)
    swapped = target.copy()
    swapped[[1, k - 2]] = swapped[[k - 2, 1]]
    offset = target + np.stack([0.5 + 0.5 * np.arange(k) / k, np.full(k, -0.4)], 1)
    return {"identical": Scenario("identical", target.copy(), target),
            "near ties": Scenario("near ties", near.copy(), near),
            "swapped pair": Scenario("swapped pair", swapped, target),
            "offset": Scenario("offset", offset, target)}


def sample(scn: Scenario, n: int, rng: np.random.Generator) -> PairedResults:
    """One simulated experiment: n paired episodes per agent in the proxy and on the target."""
    k, m = scn.target.shape
    start = rng.normal(0.0, scn.sd_start, (k, n, m))
    proxy = scn.proxy[:, None, :] + start + rng.normal(0.0, scn.sd, (k, n, m))
    target = scn.target[:, None, :] + start + rng.normal(0.0, scn.sd, (k, n, m))
    names = [f"a{i}" for i in range(k)]
    return PairedResults(dict(zip(names, proxy, strict=True)), dict(zip(names, target, strict=True)), scn.directions)


def percentile_prpv(pr: PairedResults, *, n_boot: int, level: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """The former PRPV interval: percentile bootstrap, episodes resampled independently per agent and domain."""
    rng = np.random.default_rng(seed)
    agents = pr.agents
    pm = np.stack([resampled_means(pr.proxy[a], rng.integers(0, len(pr.proxy[a]), (n_boot, len(pr.proxy[a]))))
                   for a in agents], 1)
    tm = np.stack([resampled_means(pr.target[a], rng.integers(0, len(pr.target[a]), (n_boot, len(pr.target[a]))))
                   for a in agents], 1)
    lo, hi = np.percentile(prpv_from_means(pm, tm, pr.higher_is_better), [50 * (1 - level), 50 * (1 + level)])
    return float(lo), float(hi)


def coverage(scn: Scenario, n: int, reps: int, *, n_boot: int = 200, level: float = 0.95,
             seed: int = 0) -> dict[str, float]:
    """Share of ``reps`` simulated experiments whose interval holds the true value, and mean widths.

    Keys: ``prpv`` (the order range), ``prpv_percentile`` (the former interval), ``ppv`` (BCa, mean over
    agents), ``prpv_contains_point`` / ``prpv_percentile_contains_point`` (does the interval hold its own
    point value), ``*_width``.
    """
    rng = np.random.default_rng([seed, n])
    true_prpv, true_ppv = scn.true_prpv(), scn.true_ppv()
    hits = dict.fromkeys(("prpv", "prpv_percentile", "ppv", "prpv_contains_point",
                          "prpv_percentile_contains_point"), 0)
    width = dict.fromkeys(("prpv", "prpv_percentile", "ppv"), 0.0)
    for r in range(reps):
        pr = sample(scn, n, rng)
        est = usefulness(pr, n_boot=n_boot, level=level, seed=r, scale=scn.scale)
        old = percentile_prpv(pr, n_boot=n_boot, level=level, seed=r)
        point = est["prpv"].value
        for key, (lo, hi), truth in (("prpv", (est["prpv"].low, est["prpv"].high), true_prpv),
                                     ("prpv_percentile", old, true_prpv),
                                     ("ppv", (est["ppv"].low, est["ppv"].high), true_ppv)):
            hits[key] += int(lo - 1e-9 <= truth <= hi + 1e-9)
            width[key] += (hi - lo) / reps
            if key.startswith("prpv"):
                hits[f"{key}_contains_point"] += int(lo - 1e-9 <= point <= hi + 1e-9)
    out = {k: v / reps for k, v in hits.items()}
    out.update({f"{k}_width": v for k, v in width.items()})
    out.update({"true_prpv": true_prpv, "true_ppv": true_ppv})
    return out
