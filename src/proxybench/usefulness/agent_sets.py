"""How much a verdict depends on *which agents* were ranked, and whether the task's order uses all its metrics.

PRPV is "agent agnostic" in the thesis' sense (any agents will do), but its value and its argmin are
computed over one finite set of agents. Here the agents are treated as a sample of a population:

- **leave one agent out** (jackknife): the argmin over θ without each agent in turn;
- **bootstrap over agents**: agent sets drawn with replacement; the spread of PRPV/K(K−1) at each θ and
  how often the argmin stays where the full set puts it;
- **order structure**: for a task of several metrics, how many agent pairs each metric decides, how many
  pairs the metrics disagree on (incomparable), and how many agent-episodes sit at a metric's cap. A task
  whose second metric is constant for most agents (every good agent survives to the cap) is really a
  one-metric task, whatever its definition says.

Everything works from per-agent means (``prpv_from_means`` of :mod:`proxybench.usefulness.metrics`), so it
costs no simulation. Missing values follow :mod:`proxybench.usefulness.metrics`: no value is worst.

>>> import numpy as np
>>> t = {"a": np.array([[3.0, 1.0]]), "b": np.array([[2.0, 2.0]]), "c": np.array([[1.0, 1.0]])}
>>> s = order_structure(t, (True, True))
>>> s["pairs"], s["incomparable"], s["decided_by_one_metric"]
(3, 1, 1)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from proxybench.usefulness.metrics import agent_means, prpv_from_means

__all__ = ["AgentSensitivity", "agent_bootstrap", "argmin_random_ties", "leave_one_out", "means_of",
           "order_structure", "sensitivity"]

Results = Mapping[str, np.ndarray]


def means_of(res: Results, agents: Sequence[str]) -> np.ndarray:
    """(K, m) per-agent means over the episodes that have a value (NaN where none has: worst in PRPV)."""
    return agent_means(res, agents)


def argmin_random_ties(values: np.ndarray, rng: np.random.Generator) -> tuple[int, int]:
    """(index of the smallest value, how many were tied for it), ties broken uniformly at random; NaN is worst."""
    v = np.where(np.isfinite(values), values, np.inf)
    tied = np.flatnonzero(np.isclose(v, v.min(), rtol=0, atol=1e-9))
    return int(rng.choice(tied)), int(tied.size)


@dataclass(frozen=True)
class AgentSensitivity:
    """PRPV's argmin over θ under changes of the agent set.

    ``loo_argmin[k]``: the argmin without agent k; ``boot_argmin[b]``: with bootstrap agent set b;
    ``boot_prpv_norm``: (B, P) PRPV/K(K−1) of every θ in every agent set.
    """

    agents: tuple[str, ...]
    full_argmin: int
    loo_argmin: tuple[int, ...]
    boot_argmin: np.ndarray
    boot_prpv_norm: np.ndarray

    def interval(self, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
        """Per θ, the interval of PRPV/K(K−1) over agent sets."""
        q = 100 * (1 - level) / 2
        return (np.nanpercentile(self.boot_prpv_norm, q, axis=0),
                np.nanpercentile(self.boot_prpv_norm, 100 - q, axis=0))


def _prpv_norm(proxy_means: np.ndarray, target_means: np.ndarray, higher: Sequence[bool]) -> np.ndarray:
    """(P,) PRPV/K(K−1) of P proxies' (P, K, m) means against the target's (K, m)."""
    k = target_means.shape[0]
    return np.asarray(prpv_from_means(proxy_means, target_means[None], higher), dtype=float) / max(k * (k - 1), 1)


def leave_one_out(proxy_means: np.ndarray, target_means: np.ndarray, higher: Sequence[bool],
                  rng: np.random.Generator) -> list[int]:
    """PRPV's argmin over the P proxies with each of the K agents left out in turn."""
    k = target_means.shape[0]
    out = []
    for drop in range(k):
        keep = [i for i in range(k) if i != drop]
        out.append(argmin_random_ties(_prpv_norm(proxy_means[:, keep], target_means[keep], higher), rng)[0])
    return out


def agent_bootstrap(proxy_means: np.ndarray, target_means: np.ndarray, higher: Sequence[bool], n_boot: int,
                    rng: np.random.Generator, min_distinct: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indices (B, K) of the agent sets drawn, argmin (B,), PRPV/K(K−1) (B, P)) over agent sets drawn with
    replacement; sets with fewer than ``min_distinct`` different agents are drawn again."""
    k = target_means.shape[0]
    sets = np.empty((n_boot, k), dtype=np.int64)
    arg = np.empty(n_boot, dtype=np.int64)
    vals = np.empty((n_boot, proxy_means.shape[0]))
    for b in range(n_boot):
        idx = rng.integers(0, k, k)
        while np.unique(idx).size < min(min_distinct, k):
            idx = rng.integers(0, k, k)
        sets[b] = idx
        vals[b] = _prpv_norm(proxy_means[:, idx], target_means[idx], higher)
        arg[b] = argmin_random_ties(vals[b], rng)[0]
    return sets, arg, vals


def sensitivity(agents: Sequence[str], proxy_means: np.ndarray, target_means: np.ndarray, higher: Sequence[bool],
                *, n_boot: int = 200, seed: int = 0) -> AgentSensitivity:
    """Leave-one-out and bootstrap-over-agents views of PRPV's argmin (P proxies, K agents, m metrics)."""
    rng = np.random.default_rng([seed, 0xA6E7])
    full = argmin_random_ties(_prpv_norm(proxy_means, target_means, higher), rng)[0]
    loo = leave_one_out(proxy_means, target_means, higher, rng)
    _, arg, vals = agent_bootstrap(proxy_means, target_means, higher, n_boot, rng)
    return AgentSensitivity(tuple(agents), full, tuple(loo), arg, vals)


def order_structure(res: Results, higher: Sequence[bool], caps: Sequence[float | None] | None = None
                    ) -> dict[str, float]:
    """How the agents' mean scores order them under a task of m metrics.

    ``pairs``: K(K−1)/2; ``both_agree``: pairs every metric orders the same way (no ties);
    ``decided_by_one_metric``: pairs some metric ties and the others decide; ``incomparable``: pairs
    the metrics order in opposite directions; ``equal``: pairs tied on every metric. With ``caps``
    (one per metric, None for none), ``at_cap_m`` is the share of agent-episodes at metric m's cap and
    ``agents_at_cap_m`` the number of agents whose *every* episode is at it.
    """
    agents = list(res)
    means = means_of(res, agents) * np.where(np.asarray(higher), 1.0, -1.0)
    k = len(agents)
    counts = {"pairs": 0, "both_agree": 0, "decided_by_one_metric": 0, "incomparable": 0, "equal": 0}
    for i in range(k):
        for j in range(i + 1, k):
            d = np.sign(np.nan_to_num(means[i] - means[j]))
            counts["pairs"] += 1
            if np.all(d == 0):
                counts["equal"] += 1
            elif np.any(d > 0) and np.any(d < 0):
                counts["incomparable"] += 1
            elif np.any(d == 0):
                counts["decided_by_one_metric"] += 1
            else:
                counts["both_agree"] += 1
    out: dict[str, float] = dict(counts)
    for m, cap in enumerate(caps or ()):
        if cap is None:
            continue
        at = [np.asarray(res[a], dtype=float)[:, m] >= cap - 1e-6 for a in agents]
        out[f"at_cap_{m}"] = float(np.mean(np.concatenate(at)))
        out[f"agents_at_cap_{m}"] = float(sum(bool(np.all(x)) for x in at))
    return out
