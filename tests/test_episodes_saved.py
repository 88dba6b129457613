"""The proxy's worth in target episodes (usefulness.episodes_saved): the variance ratio of PPI++ at the pooled λ,
and the plug-in episodes to decide a pair."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from proxybench.usefulness.episodes_saved import episodes_saved


def _world(rho: float, n: int = 4000, k: int = 4, seed: int = 0) -> tuple[dict, dict]:
    """k agents, agent i's mean i; the proxy's episode noise correlates ρ with the target's."""
    rng = np.random.default_rng(seed)
    shared = rng.normal(size=(n, k))
    own = rng.normal(size=(n, k))
    target = {f"a{i}": (i + shared[:, i])[:, None] for i in range(k)}
    proxy = {f"a{i}": (i + rho * shared[:, i] + np.sqrt(1 - rho**2) * own[:, i])[:, None] for i in range(k)}
    return target, proxy


@pytest.mark.parametrize("rho", [0.5, 0.8])
def test_worth_is_one_over_one_minus_rho_squared(rho: float) -> None:
    target, proxy = _world(rho)
    s = episodes_saved(target, proxy, (0.0,))
    assert s.worth == pytest.approx(1 / (1 - rho**2), rel=0.08)
    assert s.saved_share == pytest.approx(rho**2, abs=0.04)
    assert s.episodes_with < s.episodes_alone


def test_a_proxy_that_predicts_nothing_or_the_opposite_saves_nothing() -> None:
    target, proxy = _world(0.0)
    assert episodes_saved(target, proxy, (0.0,)).worth == pytest.approx(1.0, abs=0.02)
    target, proxy = _world(0.9)
    inverted = {a: -v for a, v in proxy.items()}
    s = episodes_saved(target, inverted, (0.0,))
    assert s.weights == (0.0,) and s.worth == pytest.approx(1.0) and s.saved_share == pytest.approx(0.0)


def test_episodes_alone_is_the_plug_in_sample_size() -> None:
    rng = np.random.default_rng(3)
    n = 20000
    target = {"a": 1.0 + rng.normal(size=(n, 1)), "b": rng.normal(size=(n, 1))}  # gap 1, Var(d) = 2
    s = episodes_saved(target, target, (0.25,), alpha=0.05)
    z = stats.norm.ppf(1 - 0.05 / 2)
    assert s.pairs == 1
    assert s.episodes_alone == pytest.approx((z * np.sqrt(2.0) / 0.75) ** 2, rel=0.05)


def test_pairs_within_tolerance_are_left_out_and_few_episodes_give_nan() -> None:
    target, proxy = _world(0.5, n=200)
    assert episodes_saved(target, proxy, (5.0,)).pairs == 0
    short = {a: v[:2] for a, v in target.items()}
    assert np.isnan(episodes_saved(short, short, (0.0,)).worth)


def test_a_proxy_without_an_agent_is_refused_by_name() -> None:
    target, proxy = _world(0.5, n=10)
    del proxy["a2"]
    with pytest.raises(ValueError, match="a2"):
        episodes_saved(target, proxy, (0.0,))


def test_with_three_episodes_a_useless_proxy_is_not_flattered() -> None:
    """In sample, a λ fitted to three episodes' noise made a proxy that predicts nothing look worth ~40 %; the
    leave-one-episode-out spread keeps it at or below nothing, and a good one (ρ = 0.8: 64 %) near its worth."""
    def median_share(rho: float) -> float:
        shares = []
        for seed in range(200):
            target, proxy = _world(rho, n=3, k=5, seed=seed)
            shares.append(episodes_saved(target, proxy, (0.0,)).saved_share)
        return float(np.median(shares))

    assert median_share(0.0) <= 0.02
    assert 0.4 <= median_share(0.8) <= 0.7
