"""The usefulness definitions against the thesis, on hand-computed cases; missing values; intervals and coverage."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from proxybench.usefulness import PairedResults, dominance, ppv_agents, ppv_value, target_scale, usefulness
from proxybench.usefulness.intervals import order_range, sign_sets
from proxybench.usefulness.metrics import agent_means, correlations, dominance_from_means, mmrv_from_means
from proxybench.usefulness.noise import noise_floor

NAN = float("nan")


def res(**agents):
    return {a: np.atleast_2d(np.asarray(v, dtype=float)) for a, v in agents.items()}


# --------------------------------------------------------------------------------------------------
# PPV (thesis eq. 3.4.1): per agent, β fixed from the target


def test_ppv_per_agent_by_hand_with_mixed_units():
    # distance [m] and survival [s]; target spread (population std across agents): 1 m and 10 s
    target = res(a=[[3.0, 60.0]], b=[[1.0, 40.0]])
    proxy = res(a=[[2.5, 60.0]], b=[[1.0, 20.0]])
    scale, notes = target_scale(agent_means(target, ["a", "b"]))
    np.testing.assert_allclose(scale, [1.0, 10.0]) and not notes
    per = ppv_agents(agent_means(proxy, ["a", "b"]), agent_means(target, ["a", "b"]), scale)
    np.testing.assert_allclose(per, [0.5 / 1 + 0 / 10, 0 / 1 + 20 / 10])  # a: 0.5, b: 2.0
    assert ppv_value(proxy, target) == pytest.approx(1.25)  # the mean over agents
    est = usefulness(PairedResults(proxy, target, (True, True), ("distance", "survival")), n_boot=20)
    assert est["ppv"].value == pytest.approx(1.25) and est["ppv_sum"].value == pytest.approx(2.5)
    assert est.ppv_agents["a"].value == pytest.approx(0.5) and est.ppv_agents["b"].value == pytest.approx(2.0)
    assert est.scale == {"distance": 1.0, "survival": 10.0}


def test_ppv_scale_is_fixed_from_the_target_not_re_estimated_per_resample():
    # the proxy is the target plus a constant offset in every episode: with β fixed, every paired resample
    # gives the same PPV, so the interval is the point; a β re-estimated per resample would make it vary
    rng = np.random.default_rng(0)
    target = {f"a{i}": rng.normal(i, 1.0, (6, 1)) for i in range(4)}
    proxy = {a: v + 0.5 for a, v in target.items()}
    est = usefulness(PairedResults(proxy, target, (True,)), n_boot=200)
    s = np.std(agent_means(target, list(target))[:, 0])
    assert est["ppv"].value == pytest.approx(0.5 / s)
    assert est["ppv"].low == pytest.approx(0.5 / s) and est["ppv"].high == pytest.approx(0.5 / s)


def test_ppv_scale_of_a_metric_that_does_not_vary_on_the_target_is_said():
    target = res(a=[[3.0, 20.0]], b=[[1.0, 20.0]])  # every agent survives the whole 20 s
    scale, notes = target_scale(agent_means(target, ["a", "b"]), ["distance", "survival"])
    np.testing.assert_allclose(scale, [1.0, 20.0])
    assert len(notes) == 1 and "survival does not vary across agents" in notes[0] and "relative error" in notes[0]


# --------------------------------------------------------------------------------------------------
# MMRV per metric, correlations named for what they are


def test_mmrv_is_per_metric_in_its_own_unit():
    target = np.array([[3.0, 60.0], [2.0, 30.0], [1.0, 10.0]])  # metres, seconds
    proxy = np.array([[2.0, 30.0], [3.0, 60.0], [1.0, 10.0]])  # agents a and b swapped on both
    np.testing.assert_allclose(mmrv_from_means(proxy, target), [2 / 3, 20.0])  # (1 + 1 + 0)/3 m, (30 + 30 + 0)/3 s
    names = ("distance", "survival")
    pr = PairedResults({k: proxy[i][None] for i, k in enumerate("abc")},
                       {k: target[i][None] for i, k in enumerate("abc")}, (True, True), names)
    est = usefulness(pr, n_boot=10)
    assert est["mmrv_distance"].value == pytest.approx(2 / 3) and est["mmrv_survival"].value == pytest.approx(20.0)
    s = target.std(0)
    assert est["mmrv_scaled"].value == pytest.approx(np.mean([2 / 3 / s[0], 20.0 / s[1]]))
    assert "mmrv" not in est and "srcc" not in est  # no figure that mixes units, no misleading name


def test_correlations_per_metric_match_scipy():
    rng = np.random.default_rng(3)
    x, y = rng.normal(size=(7, 2)), rng.normal(size=(7, 2))
    x[2, 1] = x[4, 1]  # a tie: Kendall's τ_b and Spearman's ρ handle it as SciPy does
    c = correlations(x, y)
    for m in range(2):
        assert c["pearson"][m] == pytest.approx(stats.pearsonr(x[:, m], y[:, m])[0])
        assert c["spearman"][m] == pytest.approx(stats.spearmanr(x[:, m], y[:, m])[0])
        assert c["kendall"][m] == pytest.approx(stats.kendalltau(x[:, m], y[:, m])[0])
    batch = correlations(np.stack([x, y]), np.stack([y, x]))  # vectorised over resamples
    np.testing.assert_allclose(batch["kendall"][0], c["kendall"])


def test_a_constant_metric_has_no_correlation_and_the_notes_say_so():
    target = res(a=[[3.0, 20.0]], b=[[2.0, 20.0]], c=[[1.0, 20.0]])
    proxy = res(a=[[2.9, 20.0]], b=[[2.2, 19.0]], c=[[1.1, 20.0]])
    est = usefulness(PairedResults(proxy, target, (True, True), ("distance", "survival")), n_boot=10)
    assert np.isnan(est["pearson_survival"].value) and est["pearson_distance"].value > 0.9
    assert est["pearson"].value == pytest.approx(est["pearson_distance"].value)  # summary over defined metrics
    note = next(n for n in est.notes if n.startswith("survival is the same for every agent"))
    assert "in the target" in note and "summarise distance" in note


# --------------------------------------------------------------------------------------------------
# missing values: left out of a mean, worst when an agent has none — as the benchmark's semiorder


def test_missing_values_are_left_out_of_means_and_worst_when_all_missing():
    r = res(a=[[1.0], [NAN], [3.0]], b=[[NAN], [NAN]], c=[[0.5], [0.5]])
    np.testing.assert_allclose(agent_means(r, ["a", "b", "c"]), [[2.0], [NAN], [0.5]])
    alpha = dominance(r, [True])
    assert alpha[0, 1] == 1.0 and alpha[2, 1] == 1.0  # b has no value: worst
    low = dominance(r, [False])  # whatever the direction
    assert low[2, 1] == 1.0 and low[1, 2] == 0.0
    both = dominance(res(x=[[NAN]], y=[[NAN]]), [True])
    assert both[0, 1] == 0.5  # two missing values tie
    sig = dominance(r, [True], significance=0.05)
    assert sig[0, 1] == 1.0  # no test for a missing agent: still worst


def test_one_missing_value_rule_in_usefulness_noise_and_scoring():
    from proxybench.tasks.scoring import dominance_matrix

    means = np.array([[5.0, 0.1], [4.0, 0.1], [6.0, 0.5], [NAN, 0.5], [NAN, NAN]])
    scores = {f"a{i}": {"dist": v[0], "dev": v[1]} for i, v in enumerate(means)}
    _, d_scoring = dominance_matrix(scores, [("dist", True), ("dev", False)])
    d_means = dominance_from_means(means, (True, False))
    d_episodes = dominance({k: np.array([[s["dist"], s["dev"]]]) for k, s in scores.items()}, (True, False))
    np.testing.assert_array_equal(d_means, d_scoring)
    np.testing.assert_array_equal(d_episodes, d_scoring)
    assert d_scoring[2, 3] == 1.0  # NaN distance is worst: a3 is dominated by a2 (same deviation)


def test_an_agent_refused_in_the_proxy_costs_prpv_and_is_named():
    target = res(a=[[3.0], [3.1]], b=[[2.0], [2.1]], c=[[1.0], [1.1]])
    proxy = res(a=[[NAN], [NAN]], b=[[2.0], [2.1]], c=[[1.0], [1.1]])  # a refused: worst in the proxy
    est = usefulness(PairedResults(proxy, target, (True,), ("distance",)), n_boot=50)
    assert est["prpv"].value == 4.0  # a is last instead of first: pairs (a, b) and (a, c) swapped
    assert any(n.startswith("a has no value for distance in the proxy") for n in est.notes)
    assert est.ppv_agents["a"].value != est.ppv_agents["a"].value  # NaN: no distance for a
    assert est["ppv"].value == pytest.approx(0.0)  # b and c match exactly


def test_ppv_noise_floor_is_zero_without_noise_and_positive_with_it():
    from proxybench.usefulness.noise import ppv_noise_floor

    exact = res(a=[[3.0], [3.0]], b=[[1.0], [1.0]])
    assert ppv_noise_floor(exact, n_boot=20).value == 0.0
    rng = np.random.default_rng(7)
    noisy = {a: rng.normal(mu, 1.0, (4, 1)) for a, mu in (("a", 3.0), ("b", 1.0))}
    floor = ppv_noise_floor(noisy, n_boot=100)
    assert 0.0 < floor.low <= floor.value <= floor.high


def test_noise_floor_with_a_missing_agent():
    target = res(a=[[3.0], [3.1]], b=[[NAN], [NAN]])
    assert noise_floor(target, (True,), n_boot=20).value == 0.0  # b is always worst: the order never changes


# --------------------------------------------------------------------------------------------------
# PRPV's interval: the order range


def test_sign_sets_rule_out_a_sign_only_with_enough_resamples_against_it():
    point = np.array([1.0, 1.0, 0.0])
    reps = np.array([[1.0] * 99 + [-1.0],  # 1 % against: settled
                     [1.0] * 90 + [-1.0] * 10,  # 10 % against: open down to −1
                     [0.0] * 100])  # an exact tie in every resample
    lo, hi = sign_sets(point, reps, 0.95)
    np.testing.assert_array_equal(lo, [1.0, -1.0, 0.0])
    np.testing.assert_array_equal(hi, [1.0, 1.0, 0.0])


def test_order_range_by_hand():
    settled = (np.array([[1.0, 1.0]]), np.array([[1.0, 1.0]]))  # i dominates j on both metrics
    # proxy settled, target: metric 2 open in both directions → α_t ∈ {1, 0.5}: contributions 0 or 1
    assert order_range(*settled, np.array([[1.0, -1.0]]), np.array([[1.0, 1.0]])) == (0.0, 1.0)
    # target fully open: α_t ∈ {0, 0.5, 1}: contributions 0 … 2
    assert order_range(*settled, np.array([[-1.0, -1.0]]), np.array([[1.0, 1.0]])) == (0.0, 2.0)
    # two pairs add up; no pair: (0, 0)
    lo = np.array([[1.0], [-1.0]])
    assert order_range(lo, lo, lo, lo) == (0.0, 0.0)
    assert order_range(np.empty((0, 1)), np.empty((0, 1)), np.empty((0, 1)), np.empty((0, 1))) == (0.0, 0.0)


def test_a_near_tie_on_the_target_opens_the_range_and_the_point_stays_inside():
    rng = np.random.default_rng(4)
    target = {"a": rng.normal(10, 0.3, (6, 1)), "b": rng.normal(5.0, 1.0, (6, 1)), "c": rng.normal(5.05, 1.0, (6, 1))}
    proxy = {"a": target["a"] + 0.1, "b": target["b"] * 0 + 6.0, "c": target["c"] * 0 + 4.0}  # proxy: b > c, sure
    est = usefulness(PairedResults(proxy, target, (True,)), n_boot=300)
    assert (est["prpv"].low, est["prpv"].high) == (0.0, 2.0)  # only the (b, c) order is open, on the target
    assert est["prpv"].low <= est["prpv"].value <= est["prpv"].high
    assert [(p.domain, p.a, p.b) for p in est.open_pairs] == [("target", "b", "c")]


def test_prpv_interval_always_holds_its_point_value():
    rng = np.random.default_rng(5)
    for _ in range(15):
        k = int(rng.integers(2, 7))
        target = {f"a{i}": rng.normal(rng.uniform(0, 2), 1.0, (int(rng.integers(2, 6)), 2)) for i in range(k)}
        proxy = {a: v + rng.normal(0, 1.0, v.shape) for a, v in target.items()}
        e = usefulness(PairedResults(proxy, target, (True, False)), n_boot=60, seed=int(rng.integers(1000)))["prpv"]
        assert e.low <= e.value <= e.high, e


def test_one_episode_gives_no_interval_but_a_note():
    est = usefulness(PairedResults(res(x=[[1.0]], y=[[2.0]]), res(x=[[2.0]], y=[[1.0]]), (True,)), n_boot=20)
    assert est["prpv"].value == 2.0 and np.isnan(est["ppv"].low) and "single episode" in " ".join(est.notes)


def test_unpaired_results_are_resampled_independently():
    rng = np.random.default_rng(6)
    target = {f"a{i}": rng.normal(i, 0.2, (4, 1)) for i in range(3)}
    proxy = {f"a{i}": rng.normal(i, 0.2, (3, 1)) for i in range(3)}  # fewer proxy episodes: no pairing
    est = usefulness(PairedResults(proxy, target, (True,)), n_boot=50)
    assert "unpaired" in est["ppv"].method


# --------------------------------------------------------------------------------------------------
# coverage: how often the intervals hold the true value (known by construction)


def test_order_range_covers_the_true_prpv_where_the_former_interval_did_not():
    from proxybench.usefulness.coverage import coverage, scenarios

    # the review's case: a proxy identical to its target, 12 agents, 3 episodes each
    c = coverage(scenarios(12)["identical"], n=3, reps=20, n_boot=150)
    assert c["true_prpv"] == 0.0
    assert c["prpv_percentile"] <= 0.1  # the former percentile interval: almost never
    assert c["prpv"] >= 0.9 and c["prpv_contains_point"] == 1.0
    for name in ("near ties", "swapped pair"):
        c = coverage(scenarios(6)[name], n=5, reps=30, n_boot=150)
        assert c["prpv"] >= 0.9, (name, c)


def test_ppv_bca_coverage_is_near_nominal_away_from_zero():
    from proxybench.usefulness.coverage import coverage, scenarios

    c = coverage(scenarios(6)["offset"], n=10, reps=40, n_boot=300)
    assert c["true_ppv"] > 1.0 and 0.8 <= c["ppv"] <= 1.0, c
