"""The vectorised dominance and the NumPy correlations equal the pairwise loop and SciPy they replaced."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import kendalltau, pearsonr, spearmanr

from proxybench.usefulness.metrics import _compare, _correlations, _signed, dominance


def _dominance_pairwise(res, higher_is_better):
    agents = list(res)
    k = len(agents)
    alpha = np.full((k, k), 0.5)
    signed = {a: _signed(np.asarray(res[a], dtype=float), higher_is_better) for a in agents}
    for i in range(k):
        for j in range(i + 1, k):
            cmp = _compare(signed[agents[i]], signed[agents[j]], None)
            ge, le = np.all(cmp >= 0), np.all(cmp <= 0)
            if ge and not le:
                alpha[i, j], alpha[j, i] = 1.0, 0.0
            elif le and not ge:
                alpha[i, j], alpha[j, i] = 0.0, 1.0
    return alpha


@pytest.mark.parametrize("seed", range(6))
def test_dominance_equals_the_pairwise_comparison(seed):
    rng = np.random.default_rng(seed)
    res = {f"a{i}": rng.integers(0, 3, (3, 2)).astype(float) for i in range(9)}  # many ties
    res["a0"][:, 1] = np.nan  # an agent whose metric is all NaN: incomparable on it
    res["a1"][0, 0] = np.nan
    for hib in ([True, True], [True, False]):
        np.testing.assert_array_equal(dominance(res, hib), _dominance_pairwise(res, hib))
    assert dominance({}, [True]).shape == (0, 0)


@pytest.mark.parametrize("seed", range(8))
def test_correlations_equal_scipy(seed):
    rng = np.random.default_rng(seed)
    mp = rng.integers(0, 5, (12, 3)).astype(float) + (seed % 2) * rng.normal(0, 1, (12, 3))
    mt = mp + rng.normal(0, 1.5, mp.shape)
    mt[:, 2] = 1.0  # constant on one metric: no correlation there
    got = _correlations(mp, mt)
    for name, fn in (("srcc", pearsonr), ("spearman", spearmanr), ("kendall", kendalltau)):
        ref = np.mean([float(fn(mp[:, m], mt[:, m])[0]) for m in range(2)])
        assert got[name] == pytest.approx(ref, abs=1e-12), name
    assert all(np.isnan(v) for v in _correlations(mp[:, 2:], mt[:, 2:]).values())


@pytest.mark.parametrize("episodes", [(3, 3, 3), (12, 12, 12), (2, 5, 3)])
def test_means_equal_agent_by_agent(episodes):
    from proxybench.usefulness.metrics import _means

    rng = np.random.default_rng(len(episodes) + sum(episodes))
    res = {f"a{i}": rng.normal(0, 1e3, (e, 2)) for i, e in enumerate(episodes)}
    res["a1"][0, 0] = np.nan
    ref = np.stack([np.nanmean(res[a], axis=0) for a in res])
    np.testing.assert_array_equal(_means(res, list(res)), ref)
