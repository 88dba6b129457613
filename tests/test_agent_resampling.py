"""Agent-level resampling (usefulness/agent_resampling.py) on synthetic tables whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from proxybench.usefulness.agent_resampling import (
    ContributionTable,
    agent_contributions,
    family_splits,
    prpv_agent_shares,
    two_way_bootstrap,
)
from proxybench.usefulness.metrics import dominance_from_means
from proxybench.usefulness.validation import quality

FAMILIES = {"pid": "pid", "pid-fast": "pid", "pp": "pursuit", "pp-fast": "pursuit", "vision": "vision",
            "vision-slow": "vision", "hough": "hough", "stanley": "stanley", "lqr": "lqr", "lqr-soft": "lqr"}


def _table(rng: np.random.Generator, effects: np.ndarray, n_targets: int, held: int, noise: float) -> ContributionTable:
    """Each target holds out ``held`` random agents; agent a contributes effects[a] + N(0, noise²) there."""
    n = len(effects)
    values = np.full((n_targets, n), np.nan)
    for t in range(n_targets):
        pick = rng.choice(n, held, replace=False)
        values[t, pick] = effects[pick] + rng.normal(0.0, noise, held)
    return ContributionTable(values, tuple(f"a{j}" for j in range(n)), tuple(f"t{i}" for i in range(n_targets)))


def test_family_splits_never_split_a_family_and_go_both_ways():
    splits = family_splits(FAMILIES, np.random.default_rng(3), n_splits=4)
    assert len(splits) == 8
    partitions = set()
    for k in range(0, 8, 2):
        tune, judge = splits[k]
        assert splits[k + 1] == (judge, tune)
        assert sorted(tune + judge) == sorted(FAMILIES)
        assert {FAMILIES[a] for a in tune}.isdisjoint({FAMILIES[a] for a in judge})
        assert abs(len(tune) - len(judge)) <= 2  # dealt to the smaller side: families here have 1–2 agents
        partitions.add(frozenset(tune) if "pid" in tune else frozenset(judge))
    assert len(partitions) == 4  # distinct
    assert family_splits(FAMILIES, np.random.default_rng(3), n_splits=4) == splits  # seeded


def test_family_splits_refuse_what_cannot_be_split():
    with pytest.raises(ValueError, match="at least 2 families"):
        family_splits({"pid": "pid", "pid-fast": "pid"}, np.random.default_rng(0))
    with pytest.raises(ValueError, match="n_splits: only 1 distinct"):
        family_splits({"a": "x", "b": "y"}, np.random.default_rng(0), n_splits=2)


def test_the_mean_weighs_targets_equally_whatever_their_number_of_agents():
    table = ContributionTable.from_records([("t1", "a", 1.0), ("t1", "b", 3.0), ("t1", "c", 5.0), ("t2", "a", 0.0)])
    for mode in ("targets", "agents", "both"):
        assert two_way_bootstrap(table, resample=mode, n_boot=50).mean == pytest.approx(1.5)


def test_records_are_checked():
    with pytest.raises(ValueError, match="agent 'a' appears twice at target 't1'"):
        ContributionTable.from_records([("t1", "a", 1.0), ("t1", "a", 2.0)])
    with pytest.raises(ValueError, match=r"values: shape \(2, 2\) is not"):
        ContributionTable(np.zeros((2, 2)), ("a",), ("t1", "t2"))
    with pytest.raises(ValueError, match="resample must be one of"):
        two_way_bootstrap(ContributionTable(np.zeros((1, 1)), ("a",), ("t",)), resample="pool")  # type: ignore[arg-type]


def test_two_way_interval_is_wider_than_targets_only_when_agents_differ():
    rng = np.random.default_rng(11)
    effects = rng.normal(-0.05, 0.15, 30)  # agents differ a lot; targets add little noise
    table = _table(rng, effects, n_targets=80, held=15, noise=0.02)
    t_only = two_way_bootstrap(table, resample="targets", n_boot=1000, seed=1)
    both = two_way_bootstrap(table, resample="both", n_boot=1000, seed=1)
    assert both.mean == t_only.mean
    assert both.high - both.low > 4.0 * (t_only.high - t_only.low)
    # the two-way interval covers the mean of the agents' effects (the pool's population here); targets-only need not
    assert both.low < effects.mean() < both.high


def test_two_way_interval_is_only_conservatively_wider_when_agents_are_alike():
    """All variation is target × agent interaction here, which the pigeonhole bootstrap counts up to three times:
    its interval is at most about √3 times the targets-only one (McCullagh 2000), far from the agents-differ case."""
    rng = np.random.default_rng(12)
    table = _table(rng, np.full(30, -0.05), n_targets=80, held=15, noise=0.1)
    t_only = two_way_bootstrap(table, resample="targets", n_boot=1000, seed=1)
    both = two_way_bootstrap(table, resample="both", n_boot=1000, seed=1)
    assert both.high - both.low < 2.2 * (t_only.high - t_only.low)


def test_resampling_whole_families_is_wider_than_single_agents_when_families_share_an_effect():
    rng = np.random.default_rng(5)
    fam_effect = rng.normal(0.0, 0.2, 6)
    groups = {f"a{j}": f"f{j % 6}" for j in range(30)}
    effects = np.array([fam_effect[j % 6] for j in range(30)])
    table = _table(rng, effects, n_targets=60, held=15, noise=0.02)
    agents = two_way_bootstrap(table, n_boot=1000, seed=2)
    fams = two_way_bootstrap(table, groups=groups, n_boot=1000, seed=2)
    assert fams.by_family and not agents.by_family
    assert fams.high - fams.low > 1.5 * (agents.high - agents.low)


def test_the_agent_that_carries_the_whole_effect_is_found():
    rng = np.random.default_rng(8)
    effects = np.zeros(20)
    effects[7] = -1.0  # tuning helps only where a7 is judged
    table = _table(rng, effects, n_targets=60, held=8, noise=0.01)
    rows = agent_contributions(table, n_boot=500, seed=4)
    by = {r.agent: r for r in rows}
    carrier = by["a7"]
    mean = two_way_bootstrap(table, n_boot=10).mean
    assert carrier.loo < 0 and carrier.high < 0  # the mean rests on it, and the interval says so
    assert carrier.loo == pytest.approx(mean, abs=0.03)  # without it, nothing is left
    assert carrier.own_mean == pytest.approx(-1.0, abs=0.01)
    others = [r for r in rows if r.agent != "a7"]
    assert max(abs(r.loo) for r in others) < 0.2 * abs(carrier.loo)
    assert sum(r.n_targets for r in rows) == 60 * 8


def test_prpv_shares_average_to_the_studys_primary_quality():
    rng = np.random.default_rng(2)
    agents = [f"a{j}" for j in range(6)]
    target = {a: rng.normal(j, 1.0, (4, 2)) for j, a in enumerate(agents)}
    proxy = {a: rng.normal(5 - j, 1.0, (4, 2)) for j, a in enumerate(agents)}
    higher = (True, False)
    means = lambda res: np.stack([res[a].mean(0) for a in agents])  # noqa: E731
    shares = prpv_agent_shares(dominance_from_means(means(proxy), higher), dominance_from_means(means(target), higher))
    assert shares.mean() == pytest.approx(quality(proxy, target, higher).prpv_norm)
    assert (shares >= 0).all()
    same = dominance_from_means(means(target), higher)
    assert prpv_agent_shares(same, same).tolist() == [0.0] * 6
