"""How often the sequential stopping rule declares a wrong order, and how often it settles: simulations with known
means.

K agents on one metric with known true means and spreads; each simulated experiment runs a pilot, then
:func:`~proxybench.usefulness.stopping.run_until_settled` with episodes drawn from the known distributions,
and its final decisions are scored against the truth:

- **wrong order**: a pair declared ordered against its true sign (or ordered at all when the true difference is
  exactly 0). Ordering a pair whose true difference is within ε the right way is not an error (indifference);
- **false tie**: a pair declared tied within ε whose true |difference| exceeds ε;
- **FWER**: the share of experiments with at least one wrong order or false tie;
- **power**: the share of pairs whose true |difference| exceeds ε that end correctly ordered;
- **settled**: the share of experiments in which every pair was settled within the budget;
- **range covers**: the share of (experiment, pair) in which the planner's range of episodes per agent, computed
  from the pilot alone (:func:`~proxybench.usefulness.indifference.needs`), holds the count the true means and
  spreads call for.

    python benchmarks/bench_stopping.py        # the table in docs/usefulness.md
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from proxybench.usefulness.indifference import Rule, episodes_to_settle, needs
from proxybench.usefulness.stopping import run_until_settled

__all__ = ["StopScenario", "check", "scenarios"]


@dataclass(frozen=True)
class StopScenario:
    """Known true means (K,) and spreads of K agents on one metric, its tolerance ε, and an optional cap (a metric
    like survival time: episodes at the cap are equal)."""

    name: str
    means: tuple[float, ...]
    sd: float = 1.0
    tolerance: float = 1.0
    cap: float | None = None

    def draw(self, agent: int, n: int, rng: np.random.Generator) -> np.ndarray:
        x = rng.normal(self.means[agent], self.sd, (n, 1))
        return np.minimum(x, self.cap) if self.cap is not None else x

    def truth(self, rng: np.random.Generator, n: int = 200_000) -> tuple[np.ndarray, np.ndarray]:
        """True means and variances (by simulation when capped)."""
        if self.cap is None:
            return np.asarray(self.means, float), np.full(len(self.means), self.sd ** 2)
        x = np.stack([self.draw(a, n, rng)[:, 0] for a in range(len(self.means))])
        means = x.mean(1)
        same = np.isclose(np.asarray(self.means)[:, None], np.asarray(self.means)[None, :])
        means = np.array([means[same[a]].mean() for a in range(len(means))])  # equal truths stay equal
        return means, x.var(1)


def scenarios(tolerance: float = 1.0) -> dict[str, StopScenario]:
    """Six agents, σ = 1, ε = ``tolerance``: clear orders; near ties (differences 0, ε/2, ε, 2ε); every agent
    alike (every order declared is wrong); agents at a cap (most episodes equal, as survival time)."""
    e = tolerance
    return {"spread": StopScenario("spread", (0.0, 1.0, 2.0, 3.0, 4.0, 5.0), tolerance=e),
            "near ties": StopScenario("near ties", (0.0, 0.0, e / 2, e, 2 * e, 4 * e), tolerance=e),
            "all alike": StopScenario("all alike", (0.0,) * 6, tolerance=e),
            "capped": StopScenario("capped", (1.0, 2.5, 3.0, 3.0, 3.5, 4.0), tolerance=e, cap=3.0)}


def check(scn: StopScenario, *, reps: int, pilot: int = 3, budget: int = 600, batch: int = 6, level: float = 0.95,
          correct: bool = True, power: float = 0.8, seed: int = 0) -> dict[str, float]:
    """The rates above over ``reps`` simulated experiments (keys: wrong_order, false_tie, fwer, power, settled,
    episodes (mean per agent, pilot included), range_covers, pairs_far (pairs with |d| > ε))."""
    rng = np.random.default_rng([seed, 0x57])
    mu, var = scn.truth(rng)
    k = len(mu)
    agents = [f"a{i}" for i in range(k)]
    iu = np.triu_indices(k, 1)
    d = mu[iu[0]] - mu[iu[1]]
    far = np.abs(d) > scn.tolerance + 1e-12
    true_n = episodes_to_settle(d, var[iu[0]] + var[iu[1]], scn.tolerance, Rule((scn.tolerance,), level), power)
    wrong = false_tie = right_far = fw = settled = covered = covered_of = 0
    spent = 0.0
    for r in range(reps):
        pilot_res = {a: scn.draw(i, pilot, rng) for i, a in enumerate(agents)}
        nd = needs(pilot_res, (True,), Rule((scn.tolerance,), level), power=power, draws=300, seed=r)
        ok = np.isfinite(true_n)
        covered += int(((nd.low <= true_n) & (true_n <= nd.high))[ok].sum())
        covered_of += int(ok.sum())

        def fetch(picks: list[str]) -> list[np.ndarray]:
            return [scn.draw(agents.index(a), 1, rng)[0] for a in picks]

        res = run_until_settled(pilot_res, fetch, (True,), tolerances=(scn.tolerance,), budget=budget, batch=batch,
                                level=level, correct=correct)
        spent += (pilot * k + res.spent) / k
        settled += int(res.stopped == "settled")
        bad = 0
        for q in range(len(d)):
            a, b = agents[iu[0][q]], agents[iu[1][q]]
            verdict = res.decisions[(a, b)]
            if verdict in (a, b):
                sign = 1.0 if verdict == a else -1.0
                if sign * d[q] < 0 or d[q] == 0:
                    wrong += 1
                    bad += 1
                elif far[q]:
                    right_far += 1
            elif verdict == "tie" and far[q]:
                false_tie += 1
                bad += 1
        fw += int(bad > 0)
    pairs = reps * len(d)
    return {"wrong_order": wrong / pairs, "false_tie": false_tie / max(reps * int(far.sum()), 1),
            "fwer": fw / reps, "power": right_far / max(reps * int(far.sum()), 1), "settled": settled / reps,
            "episodes": spent / reps, "range_covers": covered / max(covered_of, 1), "pairs_far": int(far.sum()),
            "pairs": len(d)}
