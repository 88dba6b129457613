"""Which agent pairs a proxy orders differently from the target, by how much, and on which episode starts.

PRPV sums |α^proxy_ij − α^target_ij| over the pairs; this module opens the sum. A pair's cost is its share
of PRPV (2|Δα|: 2 for a swapped pair, 1 for a pair one domain calls a tie). Grouping the episodes (e.g. by
the direction a start faces around the map) recomputes each pair's order within each group, so that a
disagreement that lives on one kind of start (camera agents that leave the road on clockwise starts in the
target only) shows where it lives.

>>> import numpy as np
>>> target = {"a": np.array([[2.0], [2.0]]), "b": np.array([[1.0], [1.0]])}
>>> proxy = {"a": np.array([[1.0], [1.0]]), "b": np.array([[2.0], [2.0]])}
>>> [(d.a, d.b, d.cost) for d in pair_disagreements(proxy, target, (True,), ("m",))]
[('a', 'b', 2.0)]
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from proxybench.usefulness.metrics import agent_means, dominance_from_means

__all__ = ["PairDisagreement", "pair_disagreements"]

Results = Mapping[str, np.ndarray]


@dataclass(frozen=True)
class PairDisagreement:
    """One pair ordered differently: α_ab in each domain (1: a ahead, 0: b ahead, 0.5: tie or incomparable),
    its cost in PRPV, the mean differences a − b per metric in each domain, and the same within each group."""

    a: str
    b: str
    alpha_proxy: float
    alpha_target: float
    cost: float
    target_delta: dict[str, float]
    proxy_delta: dict[str, float]
    groups: dict[str, tuple[float, float, int]] = field(default_factory=dict)  # group → (α_proxy, α_target, n)

    def where(self) -> list[str]:
        """The groups in which the two domains order the pair differently."""
        return [g for g, (p, t, _) in self.groups.items() if p != t]


def _alpha(res: Results, agents: list[str], higher: Sequence[bool]) -> np.ndarray:
    return dominance_from_means(agent_means(res, agents), higher)


def _subset(res: Results, groups: Mapping[str, Sequence[str]], label: str) -> dict[str, np.ndarray]:
    return {a: np.asarray(v, float)[[g == label for g in groups[a]]] for a, v in res.items()}


def pair_disagreements(proxy: Results, target: Results, higher: Sequence[bool], metrics: Sequence[str], *,
                       groups: Mapping[str, Sequence[str]] | None = None) -> list[PairDisagreement]:
    """Every pair whose dominance differs between proxy and target, costliest first.

    ``groups[agent][k]``: the group of the agent's episode k (the same in both domains: proxies replay the
    target's episodes); within each group the pair's order is recomputed from that group's episodes (an
    agent with no episode in a group is worst there, as everywhere in PRPV).
    """
    agents = list(target)
    ap, at = _alpha(proxy, agents, higher), _alpha(target, agents, higher)
    pm, tm = agent_means(proxy, agents), agent_means(target, agents)
    labels = sorted({g for a in agents for g in (groups or {}).get(a, ())})
    per_group = {g: (_alpha(_subset(proxy, groups, g), agents, higher), _alpha(_subset(target, groups, g), agents,
                                                                                higher),
                     {a: sum(x == g for x in groups[a]) for a in agents}) for g in labels} if groups else {}
    out = []
    for i, j in zip(*np.triu_indices(len(agents), 1), strict=True):
        if ap[i, j] == at[i, j]:
            continue
        grouped = {g: (float(p[i, j]), float(t[i, j]), min(n[agents[i]], n[agents[j]]))
                   for g, (p, t, n) in per_group.items()}
        out.append(PairDisagreement(
            agents[i], agents[j], float(ap[i, j]), float(at[i, j]), 2 * abs(float(ap[i, j] - at[i, j])),
            dict(zip(metrics, (tm[i] - tm[j]).tolist(), strict=True)),
            dict(zip(metrics, (pm[i] - pm[j]).tolist(), strict=True)), grouped))
    return sorted(out, key=lambda d: (-d.cost, d.a, d.b))
