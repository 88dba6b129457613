"""Bradley–Terry scores from paired episodes (proxybench.usefulness.bradley_terry): strengths recovered in a simulated
tournament, intervals that cover, provisional first places, fragility on hand-made examples, and the edge cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from proxybench.usefulness.bradley_terry import (
    EpisodeScores,
    bradley_terry,
    bradley_terry_lexicographic,
    fit_bradley_terry,
    lexicographic_outcomes,
    pairwise_outcomes,
)


def tournament(strengths, episodes: int, seed: int) -> dict[str, dict[int, float]]:
    """Per-episode values whose pairwise differences are logistic: exactly the Bradley–Terry model, with
    P(a beats b) = 1 / (1 + exp(s_b − s_a)) (the difference of two Gumbel variables is logistic)."""
    rng = np.random.default_rng(seed)
    return {f"a{i}": dict(enumerate(s + rng.gumbel(size=episodes))) for i, s in enumerate(strengths)}


def centred(values) -> np.ndarray:
    v = np.asarray(values, dtype=float)
    return v - v.mean()


def test_known_strengths_are_recovered():
    truth = centred([-1.2, -0.4, 0.0, 0.3, 0.9, 1.5])
    r = bradley_terry(tournament(truth, 3000, seed=1), resamples=50)
    got = r.by_agent()
    est = np.array([got[f"a{i}"].score for i in range(len(truth))])
    assert np.abs(est - truth).max() < 0.12
    assert [s.agent for s in r.scores] == [f"a{i}" for i in reversed(range(len(truth)))]
    assert all(s.lo < s.score < s.hi for s in r.scores)
    assert not r.provisional and r.leader == "a5" and r.fragility.removals is None  # 0.6 apart over 3,000 episodes
    assert r.episodes == 3000 and r.resamples == 50 and r.level == 0.95


def test_intervals_cover_the_true_strengths():
    """95 % percentile-bootstrap intervals over episodes, 30 tournaments of 4 agents × 300 episodes: the share of
    intervals that hold the true (centred) strength is near 95 % (binomial spread over 120 intervals ≈ ±4 %)."""
    truth = centred([-0.5, 0.0, 0.2, 0.6])
    hits = total = 0
    for seed in range(30):
        r = bradley_terry(tournament(truth, 300, seed), resamples=200, seed=seed)
        for s in r.scores:
            i = int(str(s.agent)[1:])
            hits += s.lo <= truth[i] <= s.hi
            total += 1
    assert 0.86 <= hits / total <= 1.0, hits / total


def test_provisional_when_the_top_two_overlap():
    close = bradley_terry(tournament([0.0, 1.0, 1.05], 200, seed=3))
    assert close.provisional and {s.agent for s in close.scores if s.contender} >= {"a1", "a2"}
    clear = bradley_terry(tournament([0.0, 0.2, 2.5], 200, seed=3))
    assert not clear.provisional and [s.agent for s in clear.scores if s.contender] == ["a2"]


def test_fragility_on_hand_examples():
    # a beats b in episodes 0 and 1 and ties the other three; c loses to both every time. Taking out 0 and 1
    # leaves a and b tied everywhere: first place changes (it is shared) after two removals, no fewer.
    values = {"a": {0: 5.0, 1: 5.0, 2: 3.0, 3: 3.0, 4: 3.0},
              "b": {0: 3.0, 1: 3.0, 2: 3.0, 3: 3.0, 4: 3.0},
              "c": {0: 0.0, 1: 0.0, 2: 0.0, 3: 0.0, 4: 0.0}}
    r = bradley_terry(values, resamples=0)
    assert r.leader == "a" and r.fragility.removals == 2 and set(r.fragility.removed) == {0, 1}
    assert str(r.fragility) == "2"
    values["a"][1] = 3.0  # now one episode is the whole lead
    one = bradley_terry(values, resamples=0)
    assert one.leader == "a" and one.fragility.removals == 1 and one.fragility.removed == (0,)
    strong = bradley_terry(tournament([0.0, 3.0], 400, seed=0), resamples=0, fragility_cap=5)
    assert strong.fragility.removals is None and str(strong.fragility) == "> 5" and len(strong.fragility.removed) == 5


def test_one_agent_and_agents_without_common_episodes():
    one = bradley_terry({"a": {0: 1.0, 1: 2.0}})
    assert one.scores[0].score is None and one.fragility is None and not one.provisional and one.leader is None
    assert any("one agent" in n for n in one.notes)
    apart = bradley_terry({"a": {0: 1.0, 1: 2.0}, "b": {2: 3.0, 3: 4.0}})
    assert all(s.score is None and s.comparisons == 0 for s in apart.scores) and apart.fragility is None
    # two groups that never met: scored within each group, flagged, and first place is provisional
    groups = bradley_terry({"a": {0: 1.0, 1: 2.0}, "b": {0: 0.0, 1: 0.0}, "c": {2: 9.0, 3: 9.0},
                            "d": {2: 0.0, 3: 0.0}, "loner": {7: 1.0}}, resamples=20)
    assert groups.provisional and any("2 groups" in n for n in groups.notes)
    assert groups.scores[-1].agent == "loner" and groups.scores[-1].score is None
    assert all(math.isfinite(s.score) for s in groups.scores[:-1])


def test_all_ties_and_a_perfect_record():
    ties = bradley_terry({a: {e: 1.0 + 0.01 * e for e in range(6)} for a in "abc"}, tolerance=0.1)
    assert all(abs(s.score) < 1e-9 and s.lo == pytest.approx(-s.hi) and s.hi > 0.5 for s in ties.scores)
    assert ties.provisional and ties.fragility.removals == 0 and all(s.contender for s in ties.scores)
    # a wins every comparison: the regularisation keeps its score finite
    record = bradley_terry({"a": {0: 9.0, 1: 9.0, 2: 9.0}, "b": {0: 1.0, 1: 2.0, 2: 0.0},
                            "c": {0: 0.0, 1: 1.0, 2: 1.0}})
    assert record.leader == "a" and all(math.isfinite(v) for s in record.scores for v in (s.score, s.lo, s.hi))
    assert record.scores[0].score > 1.0
    # every resample of three won episodes is the same three wins: the bootstrap alone would give a zero-width
    # interval; the model's own (Wald) interval keeps it honest about three episodes
    assert record.scores[0].hi - record.scores[0].lo > 1.0 and record.provisional


def test_missing_values_are_skipped_pair_by_pair():
    base = {"a": {0: 3.0, 1: 1.0, 2: 2.0}, "b": {0: 1.0, 1: 2.0, 2: 1.0}, "c": {0: 0.0, 1: 0.5, 2: 1.5}}
    with_nan = {**base, "a": {**base["a"], 1: math.nan}}
    without = {**base, "a": {0: 3.0, 2: 2.0}}
    o = pairwise_outcomes(with_nan)
    assert np.isnan(o.table[1, 0, 1]) and o.table[1, 1, 2] == 1.0  # only a's pairs lose episode 1
    assert o.compared[0, 1] == 2 and o.compared[1, 2] == 3
    r1, r2 = bradley_terry(with_nan, resamples=30), bradley_terry(without, resamples=30)
    assert [(s.agent, s.score, s.lo, s.hi) for s in r1.scores] == [(s.agent, s.score, s.lo, s.hi) for s in r2.scores]


def test_outcomes_direction_tolerance_and_lexicographic_order():
    o = pairwise_outcomes({"a": {0: 1.0, 1: 1.0}, "b": {0: 1.5, 1: 2.0}}, higher_is_better=False, tolerance=0.5)
    assert o.table[0, 0, 1] == 0.5 and o.table[1, 0, 1] == 1.0 and o.table[1, 1, 0] == 0.0  # |Δ| ≤ ε ties
    assert np.isnan(o.table[:, 0, 0]).all()
    first = EpisodeScores({"a": {0: 10.0, 1: 10.0}, "b": {0: 10.2, 1: 12.0}}, True, 0.5)
    second = EpisodeScores({"a": {0: 5.0, 1: 0.0}, "b": {0: 1.0, 1: 9.0}}, False, 0.0)
    lex = lexicographic_outcomes([first, second])
    assert lex.table[0, 0, 1] == 0.0  # a tie on the first: the second (lower is better) decides, b wins
    assert lex.table[1, 1, 0] == 1.0  # b better by 2 > 0.5 on the first: decided there
    r = bradley_terry_lexicographic([first, second], resamples=0)
    assert r.leader == "b"


def test_seeded_and_checked():
    values = tournament([0.0, 0.5, 1.0], 50, seed=4)
    assert bradley_terry(values, seed=7) == bradley_terry(values, seed=7)
    assert bradley_terry(values, resamples=0).scores[0].lo is None
    for bad in ({"alpha": 0.0}, {"level": 1.0}, {"resamples": -1}):
        with pytest.raises(ValueError):
            fit_bradley_terry(pairwise_outcomes(values), **bad)
    with pytest.raises(ValueError, match="tolerance"):
        pairwise_outcomes(values, tolerance=-1.0)
    with pytest.raises(ValueError, match="no metric"):
        lexicographic_outcomes([])
    assert bradley_terry(values).scores[0].text().count("[") == 1


# ---------------------------------------------------------------- PPI++ scores with a proxy as the predictor
def _ppi_world(rng, n=30, big_n=300, k=4, proxy_noise=0.3):
    strength = np.linspace(0.0, 1.0, k)
    start = rng.normal(size=(n + big_n, k))
    target = {f"a{i}": {e: strength[i] + 0.8 * start[e, i] + rng.normal() for e in range(n)} for i in range(k)}
    proxy = {f"a{i}": {(e if e < n else 100_000 + e): strength[i] + 0.8 * start[e, i] + proxy_noise * rng.normal()
                       for e in range(n + big_n)} for i in range(k)}
    return target, proxy


def test_ppi_scores_cover_the_truth_and_a_good_proxy_narrows_them():
    from proxybench.usefulness.bradley_terry import ppi_bradley_terry

    rng = np.random.default_rng(1)
    big, _ = _ppi_world(rng, n=5000, big_n=0)
    truth = np.array([s.score for s in ppi_bradley_terry(big, None, True, 0.1)[0][1:]])
    covered, alone_covered, ratio, runs = np.zeros(3), np.zeros(3), [], 60
    for _ in range(runs):
        target, proxy = _ppi_world(rng)
        with_, lam = ppi_bradley_terry(target, proxy, True, 0.1)
        alone, lam0 = ppi_bradley_terry(target, None, True, 0.1)
        assert 0.0 < lam <= 1.0 and lam0 == 0.0
        covered += [s.lo <= v <= s.hi for s, v in zip(with_[1:], truth, strict=True)]
        alone_covered += [s.lo <= v <= s.hi for s, v in zip(alone[1:], truth, strict=True)]
        ratio.append(np.mean([(b.hi - b.lo) / (a.hi - a.lo) for a, b in zip(with_[1:], alone[1:], strict=True)]))
    assert (covered / runs >= 0.85).all() and (alone_covered / runs >= 0.85).all()
    assert np.mean(ratio) > 1.05  # narrower with the proxy (1.12 in 200 worlds)


def test_ppi_scores_of_a_perfect_record_are_finite_and_unsure():
    from proxybench.usefulness.bradley_terry import ppi_bradley_terry

    target = {"a": {e: 0.0 for e in range(4)}, "b": {e: 1.0 for e in range(4)}}
    scores, _ = ppi_bradley_terry(target, None, True, 0.1)
    b = scores[1]
    assert b.agent == "b" and 0 < b.score < 10 and b.hi - b.lo > 1.0
