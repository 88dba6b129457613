"""Agents as a sample too: family splits, a bootstrap over targets *and* agents, each agent's share of a gain.

The validation study (docs/validate.md) tunes θ on some agents and judges it on others. Two things make its
intervals conditional on the pool it drew: held-out agents that are siblings of the tuning ones (variants of one
controller), and a bootstrap that resamples targets only. This module holds the pure measures that answer both
(issue 35 item 3); it imports nothing above ``tasks/``.

- :func:`family_splits`: tune on one set of families, judge on the rest, and the other way round.
- :func:`two_way_bootstrap`: the mean of a per-target × per-agent statistic with a percentile interval, resampling
  targets, agents (or whole families), or both.
- :func:`agent_contributions`: how much of that mean rests on each agent (leave-one-agent-out), with intervals.
- :func:`prpv_agent_shares`: one target's PRPV split into per-agent shares, the contributions the study feeds in.

**The input** is a :class:`ContributionTable`: a (targets × agents) array whose entry [t, a] is agent a's
contribution at target t, NaN where a was not held out there (not in B_t). The statistic is the mean over targets
of the mean over that target's held-out agents, so a target counts once however many agents it judged. For the
study's gain of method X over method Y (regret X − regret Y; negative: X better), the contribution of held-out agent
a at target t is ``prpv_agent_shares(α_X) − prpv_agent_shares(α_Y)`` for the proxies X and Y picked, which averages
over B_t to exactly Q(X) − Q(Y) on the primary measure (the oracle's Q cancels in a difference of regrets).

>>> import numpy as np
>>> table = ContributionTable.from_records([("t1", "a", -1.0), ("t1", "b", 0.0), ("t2", "a", -0.5), ("t2", "c", 0.5)])
>>> table.values.tolist(), table.agents
([[-1.0, 0.0, nan], [-0.5, nan, 0.5]], ('a', 'b', 'c'))
>>> two_way_bootstrap(table, n_boot=200).mean
-0.25
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np

__all__ = ["AgentContribution", "ContributionTable", "Resampled", "agent_contributions", "family_splits",
           "prpv_agent_shares", "two_way_bootstrap"]

Resample = Literal["targets", "agents", "both"]
_RESAMPLE = ("targets", "agents", "both")


def family_splits(families: Mapping[str, str], rng: np.random.Generator, *,
                  n_splits: int = 1) -> list[tuple[list[str], list[str]]]:
    """``n_splits`` distinct random partitions of the families into two sides, each given both ways: a list of
    (tuning agents, judging agents), 2 × ``n_splits`` long, [(S, T), (T, S), …], agents in the mapping's order.

    No family is ever on both sides, so the agents judged are never variants of the agents tuned on. Families are
    shuffled and dealt in turn to the side with fewer agents so far, which keeps the sides near equal in agents.
    ``families``: agent → family (:func:`proxybench.agents.families.family_map`).
    """
    if n_splits < 1:
        raise ValueError(f"n_splits must be at least 1, got {n_splits}")
    names = sorted(set(families.values()))
    if len(names) < 2:
        raise ValueError(f"families: a family split needs at least 2 families, got {names}")
    size = {f: sum(1 for v in families.values() if v == f) for f in names}
    seen: set[frozenset[str]] = set()
    out: list[tuple[list[str], list[str]]] = []
    for _ in range(200 * n_splits):
        if len(out) == 2 * n_splits:
            break
        order = [names[i] for i in rng.permutation(len(names))]
        sides: tuple[set[str], set[str]] = (set(), set())
        counts = [0, 0]
        for f in order:
            k = 0 if counts[0] <= counts[1] else 1
            sides[k].add(f)
            counts[k] += size[f]
        key = frozenset(sides[0]) if names[0] in sides[0] else frozenset(sides[1])
        if key in seen:
            continue
        seen.add(key)
        first = [a for a, f in families.items() if f in sides[0]]
        second = [a for a, f in families.items() if f in sides[1]]
        out += [(first, second), (second, first)]
    if len(out) < 2 * n_splits:
        raise ValueError(f"n_splits: only {len(out) // 2} distinct balanced splits of {len(names)} families found, "
                         f"{n_splits} asked")
    return out


@dataclass(frozen=True)
class ContributionTable:
    """Per-target, per-agent contributions: ``values`` (targets × agents), NaN where the agent was not held out."""

    values: np.ndarray
    agents: tuple[str, ...]
    targets: tuple[str, ...]

    def __post_init__(self) -> None:
        v = np.asarray(self.values, float)
        if v.ndim != 2 or v.shape != (len(self.targets), len(self.agents)):
            raise ValueError(f"values: shape {v.shape} is not (targets, agents) = "
                             f"({len(self.targets)}, {len(self.agents)})")
        if np.isinf(v).any():
            raise ValueError("values: an infinite contribution (NaN means 'not held out'; inf is not allowed)")
        if len(set(self.agents)) != len(self.agents):
            raise ValueError(f"agents: a name repeats in {self.agents}")
        object.__setattr__(self, "values", v)

    @classmethod
    def from_records(cls, records: Iterable[tuple[str, str, float]]) -> ContributionTable:
        """From (target, agent, contribution) rows, one per held-out agent per target (a repeat is an error)."""
        rows = list(records)
        targets = tuple(dict.fromkeys(t for t, _, _ in rows))
        agents = tuple(dict.fromkeys(a for _, a, _ in rows))
        ti, ai = {t: i for i, t in enumerate(targets)}, {a: j for j, a in enumerate(agents)}
        values = np.full((len(targets), len(agents)), np.nan)
        for t, a, v in rows:
            if not np.isnan(values[ti[t], ai[a]]):
                raise ValueError(f"records: agent {a!r} appears twice at target {t!r}")
            if np.isnan(v):
                raise ValueError(f"records: contribution of agent {a!r} at target {t!r} is NaN")
            values[ti[t], ai[a]] = v
        return cls(values, agents, targets)

    def target_means(self) -> np.ndarray:
        """Each target's mean over its held-out agents (NaN for a target with none)."""
        held = ~np.isnan(self.values)
        with np.errstate(invalid="ignore"):
            return np.where(held, self.values, 0.0).sum(1) / held.sum(1)


@dataclass(frozen=True)
class Resampled:
    """A mean over targets of per-target agent means, with a percentile bootstrap interval."""

    mean: float
    low: float
    high: float
    resample: str  # "targets", "agents" or "both"
    by_family: bool  # agents were resampled as whole families
    n_targets: int
    n_agents: int
    n_boot: int
    level: float

    def as_dict(self) -> dict[str, float | int | str | bool]:
        return asdict(self)


@dataclass(frozen=True)
class AgentContribution:
    """How much of the pool's mean rests on one agent: ``loo`` = mean − mean without the agent."""

    agent: str
    family: str | None
    n_targets: int  # targets where it was held out
    own_mean: float  # mean of its own contributions
    loo: float
    low: float
    high: float

    def as_dict(self) -> dict[str, float | int | str | None]:
        return asdict(self)


def _agent_weights(table: ContributionTable, resample: str, groups: Mapping[str, str] | None, n_boot: int,
                   rng: np.random.Generator) -> np.ndarray:
    """(agents, n_boot) multiplicities: ones, or counts of a with-replacement draw of agents (or of families)."""
    n = len(table.agents)
    if resample == "targets":
        return np.ones((n, n_boot))
    if groups is None:
        draws = rng.integers(0, n, (n_boot, n))
        return np.stack([np.bincount(d, minlength=n) for d in draws], 1).astype(float)
    missing = [a for a in table.agents if a not in groups]
    if missing:
        raise ValueError(f"groups: no family for agents {missing}")
    fams = sorted({groups[a] for a in table.agents})
    member = np.array([[groups[a] == f for f in fams] for a in table.agents], float)  # (agents, families)
    draws = rng.integers(0, len(fams), (n_boot, len(fams)))
    fam_counts = np.stack([np.bincount(d, minlength=len(fams)) for d in draws], 1).astype(float)
    return member @ fam_counts


def _target_draws(n_targets: int, resample: str, n_boot: int, rng: np.random.Generator) -> np.ndarray:
    if resample == "agents":
        return np.tile(np.arange(n_targets)[:, None], (1, n_boot))
    return rng.integers(0, n_targets, (n_targets, n_boot))


def _stat(num: np.ndarray, den: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Per replicate: the mean over the drawn targets (``idx``, targets × n_boot) of num / den, empty ones left out."""
    cols = np.arange(num.shape[1])[None, :]
    n, d = num[idx, cols], den[idx, cols]
    kept = d > 0
    per = np.where(kept, n / np.where(kept, d, 1.0), 0.0)
    count = kept.sum(0)
    return np.where(count > 0, per.sum(0) / np.maximum(count, 1), np.nan)


def _check(table: ContributionTable, resample: str, n_boot: int, level: float) -> None:
    if resample not in _RESAMPLE:
        raise ValueError(f"resample must be one of {', '.join(_RESAMPLE)}, got {resample!r}")
    if n_boot < 1:
        raise ValueError(f"n_boot must be at least 1, got {n_boot}")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    if not (~np.isnan(table.values)).any():
        raise ValueError("values: no agent was held out at any target")


def _interval(boots: np.ndarray, level: float) -> tuple[float, float]:
    finite = boots[np.isfinite(boots)]
    if finite.size == 0:
        return float("nan"), float("nan")
    lo, hi = np.percentile(finite, [100 * (1 - level) / 2, 100 * (1 + level) / 2])
    return float(lo), float(hi)


def two_way_bootstrap(table: ContributionTable, *, resample: Resample = "both", groups: Mapping[str, str] | None = None,
                      n_boot: int = 2000, seed: int = 0, level: float = 0.95) -> Resampled:
    """The mean over targets of each target's mean over its held-out agents, with a percentile interval.

    ``resample``: "targets" (the pool fixed: what the study's target bootstrap gives), "agents" (the targets fixed)
    or "both" (a two-way bootstrap: each replicate draws targets with replacement *and* gives every agent the
    weight of how often a with-replacement draw of the pool picked it, so an agent drawn twice counts twice and one
    not drawn drops out at every target). With ``groups`` (agent → family) whole families are drawn instead of
    agents: the right unit when families are what the study holds out. A replicate in which a target keeps no
    held-out agent leaves that target out. Resampling agents asks: how would the mean move with another pool
    like this one? Its interval is wider than the targets-only one when agents differ in what they contribute.

    This is the "pigeonhole" bootstrap of a crossed design (Owen 2007, *Ann. Appl. Stat.* 1(1)). It is
    conservative: the target × agent interaction enters up to three times (McCullagh 2000, *Bernoulli* 6(2)), so
    where agents are alike and everything is interaction its interval is up to √3 ≈ 1.7 times as wide as the right
    one; where agents (or targets) differ, their variance dominates and the excess is small.
    """
    _check(table, resample, n_boot, level)
    rng = np.random.default_rng([seed, 0xA6E7])
    held = ~np.isnan(table.values)
    v = np.where(held, table.values, 0.0)
    weights = _agent_weights(table, resample, groups, n_boot, rng)
    num, den = v @ weights, held.astype(float) @ weights
    boots = _stat(num, den, _target_draws(len(table.targets), resample, n_boot, rng))
    mean = float(np.nanmean(table.target_means()))
    lo, hi = _interval(boots, level)
    return Resampled(mean, min(lo, mean), max(hi, mean), resample, groups is not None and resample != "targets",
                     len(table.targets), len(table.agents), n_boot, level)


def agent_contributions(table: ContributionTable, *, resample: Resample = "both",
                        groups: Mapping[str, str] | None = None, n_boot: int = 2000, seed: int = 0,
                        level: float = 0.95) -> list[AgentContribution]:
    """Each agent's leave-one-agent-out share of the mean: mean − (the same mean with the agent removed from every
    target), with a percentile interval over replicates that resample the targets and the *other* agents as
    :func:`two_way_bootstrap` does, the agent itself counted once in each (so the interval describes what it adds to
    pools like this one, not how often a draw would leave it out). An agent that carries the gain has a ``loo`` of
    the gain's sign and an interval away from 0; a bystander's is near 0. ``groups`` (agent → family)
    labels each row with its family and, as in :func:`two_way_bootstrap`, makes families the resampled unit.
    A target whose only held-out agent is the one removed drops out of the "without" mean.
    """
    _check(table, resample, n_boot, level)
    rng = np.random.default_rng([seed, 0xA6E7])
    held = ~np.isnan(table.values)
    v = np.where(held, table.values, 0.0)
    weights = _agent_weights(table, resample, groups, n_boot, rng)
    idx = _target_draws(len(table.targets), resample, n_boot, rng)
    num, den = v @ weights, held.astype(float) @ weights
    ones = np.ones((len(table.agents), 1))
    num1, den1 = v @ ones, held.astype(float) @ ones
    point_idx = np.arange(len(table.targets))[:, None]
    point_full = float(_stat(num1, den1, point_idx)[0])
    out = []
    for j, agent in enumerate(table.agents):
        # the agent counted once in every replicate (the others and the targets resampled), then removed
        rest_num = num - np.outer(v[:, j], weights[j])
        rest_den = den - np.outer(held[:, j].astype(float), weights[j])
        with_it = _stat(rest_num + v[:, [j]], rest_den + held[:, [j]].astype(float), idx)
        boots = with_it - _stat(rest_num, rest_den, idx)
        point = point_full - float(_stat(num1 - v[:, [j]], den1 - held[:, [j]].astype(float), point_idx)[0])
        lo, hi = _interval(boots, level)
        own = table.values[held[:, j], j]
        out.append(AgentContribution(agent, None if groups is None else groups.get(agent), int(held[:, j].sum()),
                                     float(own.mean()) if own.size else float("nan"), point, min(lo, point),
                                     max(hi, point)))
    return out


def prpv_agent_shares(alpha: np.ndarray, alpha_target: np.ndarray) -> np.ndarray:
    """Per agent i, its share of one target's normalised PRPV: Σ_j (|Δα_ij| + |Δα_ji|) / (2 (K − 1)) with
    Δα = α − α_target ((K, K) dominance matrices over the held-out agents, :func:`proxybench.usefulness.metrics.
    dominance_from_means`). The shares' mean is PRPV / K(K − 1), the study's primary quality.

    >>> a = np.array([[0.5, 1.0, 1.0], [0.0, 0.5, 1.0], [0.0, 0.0, 0.5]])
    >>> b = np.array([[0.5, 0.0, 1.0], [1.0, 0.5, 1.0], [0.0, 0.0, 0.5]])  # the first two swapped
    >>> prpv_agent_shares(a, b).tolist()
    [0.5, 0.5, 0.0]
    """
    a, t = np.asarray(alpha, float), np.asarray(alpha_target, float)
    if a.ndim != 2 or a.shape[0] != a.shape[1] or a.shape != t.shape:
        raise ValueError(f"alpha: need two (K, K) matrices of one shape, got {a.shape} and {t.shape}")
    k = a.shape[0]
    if k < 2:
        raise ValueError(f"alpha: need at least 2 agents, got {k}")
    d = np.abs(a - t)
    return (d.sum(1) + d.sum(0)) / (2.0 * (k - 1))

