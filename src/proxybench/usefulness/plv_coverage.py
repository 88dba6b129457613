"""How often PLV's intervals hold the true PLV: simulated learning curves with known shape and seed noise.

A target-only curve and a proxy's curve are known functions of the target samples n; each seed's score at a
rung is the curve plus seed noise whose spread falls with n, as in the real runs (at 50 samples the full
run's seeds spanned −4 … 13, at 1,000 and more within ±1), correlated across the rungs of one seed (a seed is
one data subset, or one pre-trained network fine-tuned up the ladder) and heavy-tailed (Student t, 4 df).
The true P, samples needed and PLV follow from the known curves (P = 95 % of the target's score at the
largest rung; needed = where the curve reaches P and stays there). A proxy's ladder stops as the experiment's
does (:func:`~proxybench.usefulness.plv.ladder_done`).

Two estimators are scored: the fitted-curve PLV (:mod:`~proxybench.usefulness.plv_curve`) and the ladder rule
(:func:`~proxybench.usefulness.plv_intervals.plv_bootstrap`), each with its percentile-bootstrap interval over
seeds; "covers" is the share of simulated experiments whose 95 % interval holds the true (continuous) PLV.

    python benchmarks/bench_plv_coverage.py      # the table in docs/learning.md
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from proxybench.usefulness.plv import ladder_done, reference_score
from proxybench.usefulness.plv_curve import Fit, curve_plv
from proxybench.usefulness.plv_intervals import Curve, plv_bootstrap

__all__ = ["FULL_LADDER", "PLVScenario", "check", "scenarios"]

FULL_LADDER = (50, 100, 250, 500, 1000, 2000, 4000, 9000)


@dataclass(frozen=True)
class PLVScenario:
    """Known curves (score as a function of target samples) of target-only training and one proxy."""

    name: str
    target: Callable[[np.ndarray], np.ndarray]
    proxy: Callable[[np.ndarray], np.ndarray]
    ladder: tuple[int, ...] = FULL_LADDER
    noise_small: float = 6.0  # seed spread near n = 0
    noise_floor: float = 0.6  # seed spread at large n
    rho: float = 0.5  # correlation of one seed's noise across its rungs
    tolerance: float = 0.05

    def sd(self, n: np.ndarray) -> np.ndarray:
        return self.noise_small / (1.0 + np.asarray(n, float) / self.ladder[0]) + self.noise_floor

    def truth(self) -> tuple[float, float, float | None]:
        """(P, target samples needed, PLV or None when the proxy never settles above P), on a fine grid."""
        top = float(self.ladder[-1])
        grid = np.concatenate([[0.0], np.geomspace(1.0, top, 20_000)])
        p = reference_score(float(self.target(np.array([top]))[0]), self.tolerance)

        def needed(f, end: float) -> float | None:
            g = grid[grid <= end]
            above = f(g) >= p
            if not above[-1]:
                return None
            k = int(above.size - np.argmin(above[::-1])) if not above.all() else 0
            return float(g[k])

        nt = needed(self.target, top)
        np_ = needed(self.proxy, top)
        return p, float(nt), None if np_ is None else float(nt - np_)

    def sample(self, seeds: int, rng: np.random.Generator) -> tuple[Curve, Curve]:
        """One experiment: seeds × rungs scores of target-only training and of the proxy (zero-shot at n = 0),
        the proxy's ladder stopped once settled above the experiment's own P."""
        n = np.asarray(self.ladder, float)
        t = self.target(n)[None] + self.sd(n)[None] * self._noise(seeds, n.size, rng)
        ref = reference_score(float(t[:, -1].mean()), self.tolerance)
        pn = np.concatenate([[0.0], n])
        p = self.proxy(pn)[None] + self.sd(pn)[None] * self._noise(seeds, pn.size, rng)
        means = p.mean(0)
        stop = next((k for k in range(2, pn.size + 1) if ladder_done(means[:k], ref, 2)), pn.size)
        ids = tuple(range(seeds))
        return (Curve(n, ids, t, through_end=True),
                Curve(pn[:stop], ids, p[:, :stop], through_end=stop == pn.size))

    def _noise(self, seeds: int, rungs: int, rng: np.random.Generator) -> np.ndarray:
        common = rng.standard_t(4, (seeds, 1)) / np.sqrt(2.0)
        own = rng.standard_t(4, (seeds, rungs)) / np.sqrt(2.0)
        return np.sqrt(self.rho) * common + np.sqrt(1.0 - self.rho) * own


def _power(a: float, b: float, c: float, n0: float = 50.0) -> Callable[[np.ndarray], np.ndarray]:
    return Fit(a, b, c, n0)


def scenarios() -> dict[str, PLVScenario]:
    """Target-only curves like the full run's (≈ 1,000 samples to reach P, converging near 28 of 30), proxies that
    save most, some or none of them, and a target curve that peaks and falls back (the real one does; the
    fitted curve cannot follow it)."""
    target = _power(28.0, 30.0, 1.0)

    def bump(n: np.ndarray) -> np.ndarray:
        n = np.asarray(n, float)
        return target(n) + 2.5 * np.exp(-0.5 * (np.log(np.maximum(n, 1.0) / 1500.0) / 0.7) ** 2)

    return {"good proxy": PLVScenario("good proxy", target, _power(28.5, 4.5, 1.0)),
            "mis-pitched proxy": PLVScenario("mis-pitched proxy", target, _power(28.0, 24.0, 1.2)),
            "proxy below P": PLVScenario("proxy below P", target, _power(25.5, 20.0, 1.0)),
            "target peaks (misfit)": PLVScenario("target peaks (misfit)", bump, _power(28.5, 4.5, 1.0))}


def _holds(iv, truth: float | None) -> bool:
    """Whether an interval (None ends: "not reached") holds the truth (None: the proxy never settles)."""
    if truth is None:
        return iv.low is None
    lo = -np.inf if iv.low is None else iv.low
    hi = -np.inf if iv.high is None else iv.high
    return lo - 1e-9 <= truth <= hi + 1e-9


def check(scn: PLVScenario, *, seeds: int, reps: int, replicates: int = 1000, seed: int = 0) -> dict[str, float]:
    """Coverage and mean width of both intervals over ``reps`` experiments; the true PLV; the fitted estimate's
    mean error. Widths count only intervals with two finite ends."""
    rng = np.random.default_rng([seed, seeds])
    _, _, true_plv = scn.truth()
    hits = {"curve": 0, "ladder": 0}
    widths: dict[str, list[float]] = {"curve": [], "ladder": []}
    errors: list[float] = []
    for r in range(reps):
        t, p = scn.sample(seeds, rng)
        fitted = curve_plv(t, {"p": p}, scn.tolerance, replicates=replicates, seed=r)
        ladder = plv_bootstrap(t, {"p": p}, scn.tolerance, 2, replicates=replicates, seed=r)
        for key, iv in (("curve", fitted.plv["p"]), ("ladder", ladder.plv["p"])):
            hits[key] += int(_holds(iv, true_plv))
            if iv.low is not None and iv.high is not None:
                widths[key].append(iv.high - iv.low)
        est = fitted.plv["p"].estimate
        if est is not None and true_plv is not None:
            errors.append(est - true_plv)
    return {"true_plv": true_plv, "curve_covers": hits["curve"] / reps, "ladder_covers": hits["ladder"] / reps,
            "curve_width": float(np.mean(widths["curve"])) if widths["curve"] else float("nan"),
            "ladder_width": float(np.mean(widths["ladder"])) if widths["ladder"] else float("nan"),
            "curve_bias": float(np.mean(errors)) if errors else float("nan"),
            "curve_rmse": float(np.sqrt(np.mean(np.square(errors)))) if errors else float("nan")}

