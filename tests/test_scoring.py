"""Lexicographic semiorder, leaderboard and dominance matrices: properties and hand-made cases."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from proxybench.tasks.scoring import Criterion, compare, dominance_matrix, leaderboard, semiorder_matrix

METRIC_NAMES = ("m0", "m1", "m2")
NAN = float("nan")

any_float = st.floats(allow_nan=True, allow_infinity=True)
finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6)
small_int = st.integers(-3, 3).map(float)  # many exact ties


def score_dicts(values=any_float):
    return st.fixed_dictionaries({m: values for m in METRIC_NAMES})


TOLERANCES = st.floats(0.0, 10.0)


@st.composite
def criteria_lists(draw, tolerance=TOLERANCES):
    names = draw(st.lists(st.sampled_from(METRIC_NAMES), min_size=1, max_size=3, unique=True))
    return [Criterion(n, draw(st.booleans()), draw(tolerance)) for n in names]


@st.composite
def score_tables(draw, values=small_int, max_agents=6):
    n = draw(st.integers(1, max_agents))
    return {f"agent{k}": draw(score_dicts(values)) for k in range(n)}


def signed_tuple(x, criteria):
    return tuple(x[c.metric] if c.higher_is_better else -x[c.metric] for c in criteria)


# ---------------------------------------------------------------------------------------------------
# compare


@given(score_dicts(), score_dicts(), criteria_lists())
def test_compare_is_antisymmetric(x, y, criteria):
    assert compare(x, y, criteria) == -compare(y, x, criteria)


@given(score_dicts(), criteria_lists())
def test_compare_is_reflexive_tie(x, criteria):
    assert compare(x, x, criteria) == 0


@given(score_dicts(finite), score_dicts(finite), criteria_lists(tolerance=st.just(0.0)))
def test_zero_tolerance_is_plain_lexicographic_order(x, y, criteria):
    sx, sy = signed_tuple(x, criteria), signed_tuple(y, criteria)
    assert compare(x, y, criteria) == (sx > sy) - (sx < sy)


@given(finite, st.booleans(), st.floats(0.0, 100.0))
def test_nan_is_worst_whatever_direction_and_tolerance(v, higher, tol):
    crit = [Criterion("m0", higher, tol)]
    assert compare({"m0": NAN}, {"m0": v}, crit) == -1
    assert compare({"m0": v}, {"m0": NAN}, crit) == 1
    assert compare({"m0": NAN}, {"m0": NAN}, crit) == 0


def test_tolerance_means_strictly_more_than():
    crit = [Criterion("d", True, 0.5), Criterion("s", True, 0.0)]
    assert compare({"d": 1.5, "s": 0.0}, {"d": 1.0, "s": 1.0}, crit) == -1  # exactly 0.5 apart: s decides
    assert compare({"d": 1.75, "s": 0.0}, {"d": 1.0, "s": 1.0}, crit) == 1  # more than 0.5: d decides
    assert compare({"d": 1.0, "s": 1.0}, {"d": 1.0, "s": 1.0}, crit) == 0


def test_lower_is_better_direction():
    crit = [Criterion("dev", False, 0.01)]
    assert compare({"dev": 0.10}, {"dev": 0.20}, crit) == 1
    assert compare({"dev": 0.10}, {"dev": 0.105}, crit) == 0


def test_equal_infinities_tie_and_missing_metric_is_named():
    crit = [Criterion("m0", True, 1.0)]
    assert compare({"m0": math.inf}, {"m0": math.inf}, crit) == 0
    assert compare({"m0": math.inf}, {"m0": -math.inf}, crit) == 1
    with pytest.raises(KeyError, match="m0"):
        compare({"x": 1.0}, {"m0": 1.0}, crit)
    with pytest.raises(KeyError, match="agent 'b' has no score for m0"):
        leaderboard({"a": {"m0": 1.0}, "b": {"x": 1.0}}, crit)
    with pytest.raises(KeyError, match="agent 'b'"):
        dominance_matrix({"a": {"m0": 1.0}, "b": {"x": 1.0}}, [("m0", True)])


@pytest.mark.parametrize("tol", [-0.1, NAN, "1"])
def test_criterion_rejects_bad_tolerance(tol):
    with pytest.raises(ValueError, match="tolerance"):
        Criterion("m0", True, tol)


# ---------------------------------------------------------------------------------------------------
# leaderboard


def test_leaderboard_hand_example_with_shared_rank():
    crit = [Criterion("d", True, 0.5), Criterion("s", True, 1.0)]
    scores = {
        "zeta": {"d": 10.0, "s": 60.0},
        "alpha": {"d": 10.2, "s": 59.5},  # ties zeta within both tolerances
        "mid": {"d": 9.0, "s": 60.0},
        "low": {"d": 2.0, "s": 60.0},
    }
    rows = leaderboard(scores, crit)
    assert [(r.rank, r.agent) for r in rows] == [(1, "alpha"), (1, "zeta"), (3, "mid"), (4, "low")]
    assert (rows[0].wins, rows[0].losses, rows[0].ties, rows[0].copeland) == (2, 0, 1, 2)
    assert (rows[-1].wins, rows[-1].losses, rows[-1].ties, rows[-1].copeland) == (0, 3, 0, -3)


def test_leaderboard_cycle_is_a_three_way_tie():
    # within tolerance on d, a > b > c on s; but a and c differ on d by more than the tolerance: c > a
    crit = [Criterion("d", True, 1.0), Criterion("s", True, 0.0)]
    scores = {"c": {"d": 1.6, "s": 1.0}, "a": {"d": 0.0, "s": 3.0}, "b": {"d": 0.8, "s": 2.0}}
    assert compare(scores["a"], scores["b"], crit) == 1
    assert compare(scores["b"], scores["c"], crit) == 1
    assert compare(scores["c"], scores["a"], crit) == 1
    assert [(r.rank, r.agent, r.copeland) for r in leaderboard(scores, crit)] == [(1, "a", 0), (1, "b", 0), (1, "c", 0)]


@settings(max_examples=60)
@given(score_tables(), criteria_lists(), st.randoms(use_true_random=False))
def test_leaderboard_does_not_depend_on_input_order(scores, criteria, rnd):
    keys = list(scores)
    rnd.shuffle(keys)
    shuffled = {k: scores[k] for k in keys}
    assert leaderboard(scores, criteria) == leaderboard(shuffled, criteria)


@settings(max_examples=60)
@given(score_tables(), criteria_lists())
def test_tied_agents_are_listed_by_name(scores, criteria):
    rows = leaderboard(scores, criteria)
    assert [r.rank for r in rows] == sorted(r.rank for r in rows)
    for a, b in itertools.pairwise(rows):
        if a.rank == b.rank:
            assert a.copeland == b.copeland and str(a.agent) < str(b.agent)
        else:
            assert a.copeland > b.copeland


@settings(max_examples=60)
@given(score_tables(), criteria_lists(tolerance=st.just(0.0)))
def test_zero_tolerance_leaderboard_follows_the_lexicographic_order(scores, criteria):
    rank = {r.agent: r.rank for r in leaderboard(scores, criteria)}
    for a in scores:
        for b in scores:
            ta, tb = signed_tuple(scores[a], criteria), signed_tuple(scores[b], criteria)
            assert (rank[a] < rank[b]) == (ta > tb)


# ---------------------------------------------------------------------------------------------------
# matrices


def _off_diagonal_sums_to_one(d):
    k = d.shape[0]
    off = ~np.eye(k, dtype=bool)
    return np.all((d + d.T)[off] == 1.0) and np.all(np.diag(d) == 0.5)


@given(score_tables(st.one_of(small_int, st.just(NAN))), st.lists(st.booleans(), min_size=3, max_size=3))
def test_dominance_matrix_is_complementary(scores, directions):
    agents, d = dominance_matrix(scores, list(zip(METRIC_NAMES, directions, strict=True)))
    assert agents == list(scores)
    assert _off_diagonal_sums_to_one(d)
    assert set(np.unique(d)) <= {0.0, 0.5, 1.0}


@given(score_tables(), criteria_lists())
def test_semiorder_matrix_matches_compare(scores, criteria):
    agents, d = semiorder_matrix(scores, criteria)
    assert _off_diagonal_sums_to_one(d)
    for i, a in enumerate(agents):
        for j, b in enumerate(agents):
            if i != j:
                assert d[i, j] == {1: 1.0, -1: 0.0, 0: 0.5}[compare(scores[a], scores[b], criteria)]


def test_dominance_matrix_hand_example_with_nan_as_worst():
    scores = {
        "a": {"dist": 5.0, "dev": 0.1},
        "b": {"dist": 4.0, "dev": 0.1},  # dominated by a
        "c": {"dist": 6.0, "dev": 0.5},  # incomparable with a and b
        "d": {"dist": NAN, "dev": 0.5},  # NaN distance is worst: dominated by c
    }
    _, d = dominance_matrix(scores, [("dist", True), ("dev", False)])
    expected = np.array([
        [0.5, 1.0, 0.5, 1.0],
        [0.0, 0.5, 0.5, 1.0],
        [0.5, 0.5, 0.5, 1.0],
        [0.0, 0.0, 0.0, 0.5],
    ])
    np.testing.assert_array_equal(d, expected)


@settings(max_examples=300, deadline=None)  # the first example imports the usefulness package
@given(score_tables(st.one_of(small_int, st.just(NAN))), st.lists(st.booleans(), min_size=3, max_size=3))
def test_dominance_matrix_agrees_with_the_usefulness_module(scores, directions):
    """One rule for missing values: NaN is worst in the leaderboard's relations and in PRPV's (two NaNs tie)."""
    from proxybench.usefulness.metrics import dominance

    _, d = dominance_matrix(scores, list(zip(METRIC_NAMES, directions, strict=True)))
    res = {a: np.array([[s[m] for m in METRIC_NAMES]]) for a, s in scores.items()}
    np.testing.assert_array_equal(d, dominance(res, directions))


def test_semiorder_matrix_matches_pairwise_compare_on_random_scores():
    """The all-pairs array version gives exactly compare()'s verdicts, NaN, infinities and ties included."""
    import numpy as np

    from proxybench.tasks.scoring import Criterion, compare, semiorder_matrix

    rng = np.random.default_rng(0)
    pool = [0.0, 1.0, 1.5, 2.0, np.nan, np.inf, -np.inf, 0.1, 0.3]
    for trial in range(30):
        criteria = [Criterion(f"m{j}", bool(rng.integers(2)), float(rng.choice([0.0, 0.2, 0.5])))
                    for j in range(int(rng.integers(1, 4)))]
        scores = {f"a{i}": {c.metric: (float(rng.choice(pool)) if trial % 2 else float(rng.normal()))
                            for c in criteria} for i in range(12)}
        agents, d = semiorder_matrix(scores, criteria)
        for i, a in enumerate(agents):
            for j, b in enumerate(agents):
                expected = {1: 1.0, -1: 0.0, 0: 0.5}[compare(scores[a], scores[b], criteria)]
                assert d[i, j] == expected, (trial, a, b)


def test_copeland_counts_match_the_semiorder_matrix():
    """The compiled pair loop counts exactly what the all-pairs matrix says, NaN and infinities included."""
    from proxybench.tasks.scoring import copeland_counts

    rng = np.random.default_rng(1)
    pool = [0.0, 1.0, 1.5, 2.0, np.nan, np.inf, -np.inf, 0.1, 0.3]
    for trial in range(30):
        criteria = [Criterion(f"m{j}", bool(rng.integers(2)), float(rng.choice([0.0, 0.2, 0.5])))
                    for j in range(int(rng.integers(1, 5)))]
        scores = {f"a{i}": {c.metric: (float(rng.choice(pool)) if trial % 2 else float(rng.normal()))
                            for c in criteria} for i in range(int(rng.integers(1, 40)))}
        agents, d = semiorder_matrix(scores, criteria)
        off = ~np.eye(len(agents), dtype=bool)
        values = np.array([[scores[a][c.metric] for c in criteria] for a in agents])
        wins, losses, ties = copeland_counts(values, criteria)
        np.testing.assert_array_equal(wins, ((d == 1.0) & off).sum(axis=1))
        np.testing.assert_array_equal(losses, ((d == 0.0) & off).sum(axis=1))
        np.testing.assert_array_equal(ties, ((d == 0.5) & off).sum(axis=1))
