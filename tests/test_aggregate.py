"""Per-agent aggregation over episodes and percentile-bootstrap intervals, against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from proxybench.tasks.aggregate import aggregate, bootstrap_ci, scores_by_agent
from proxybench.tasks.scoring import Criterion, leaderboard


def long_rows(data):
    """{(agent, domain): {metric: [values per episode]}} → long-format rows."""
    return [
        {"agent": a, "domain": dom, "episode": e, "metric": m, "value": v}
        for (a, dom), metrics in data.items()
        for m, values in metrics.items()
        for e, v in enumerate(values)
    ]


DATA = {
    ("pid", "sim"): {"survival_time": [60.0, 60.0, 12.0, 30.0], "driven_lanedir_consec": [10.0, 9.0, 2.0, 5.0]},
    ("pure", "sim"): {"survival_time": [60.0, 45.0, 60.0, 60.0], "driven_lanedir_consec": [12.0, 8.0, 11.0, 13.0]},
}


@pytest.fixture(scope="module")
def table():
    return aggregate(long_rows(DATA), n_resamples=500)


def test_hand_computed_statistics(table):
    pid = table[table.agent == "pid"].iloc[0]
    assert pid["episodes"] == 4
    assert pid["survival_time_mean"] == pytest.approx(40.5)  # (60 + 60 + 12 + 30) / 4
    assert pid["survival_time_median"] == pytest.approx(45.0)  # (30 + 60) / 2
    assert (pid["survival_time_min"], pid["survival_time_max"]) == (12.0, 60.0)
    assert pid["driven_lanedir_consec_mean"] == pytest.approx(6.5)
    assert pid["driven_lanedir_consec_median"] == pytest.approx(7.0)  # (5 + 9) / 2
    pure = table[table.agent == "pure"].iloc[0]
    assert pure["driven_lanedir_consec_median"] == pytest.approx(11.5)
    assert pure["survival_time_min"] == 45.0


def test_columns_and_intervals_contain_the_statistic(table):
    assert list(table["agent"]) == ["pid", "pure"]
    for m in ("survival_time", "driven_lanedir_consec"):
        for s in ("mean", "median", "min", "max"):
            assert f"{m}_{s}" in table.columns
        for s in ("mean", "median"):
            lo, hi, v = table[f"{m}_{s}_lo"], table[f"{m}_{s}_hi"], table[f"{m}_{s}"]
            assert np.all(lo <= v) and np.all(v <= hi)
        assert f"{m}_min_lo" not in table.columns
        assert list(table[f"{m}_n"]) == [4, 4]


def test_dataframe_and_row_input_agree_and_are_deterministic():
    rows = long_rows(DATA)
    a = aggregate(rows, n_resamples=300, seed=3)
    b = aggregate(pd.DataFrame(rows), n_resamples=300, seed=3)
    pd.testing.assert_frame_equal(a, b)
    c = aggregate(rows, n_resamples=300, seed=4)
    assert not np.allclose(a["survival_time_mean_lo"], c["survival_time_mean_lo"])


def test_an_agents_interval_does_not_depend_on_the_other_agents():
    both = aggregate(long_rows(DATA), n_resamples=300)
    alone = aggregate(long_rows({("pure", "sim"): DATA[("pure", "sim")]}), n_resamples=300)
    pd.testing.assert_series_equal(both.iloc[1], alone.iloc[0], check_names=False)


def test_nan_values_are_left_out_and_counted():
    rows = long_rows({("a", "sim"): {"distance": [1.0, float("nan"), 3.0]}})
    row = aggregate(rows, n_resamples=100).iloc[0]
    assert row["distance_mean"] == 2.0 and row["distance_n"] == 2 and row["episodes"] == 3


def test_per_domain_rows_and_scores_for_a_leaderboard():
    data = {**DATA, ("pid", "real"): {"survival_time": [20.0], "driven_lanedir_consec": [1.0]}}
    table = aggregate(long_rows(data), stats=("median",), ci=(), n_resamples=10)
    assert [(r.agent, r.domain) for r in table.itertuples()] == [("pid", "real"), ("pid", "sim"), ("pure", "sim")]
    assert "survival_time_mean" not in table.columns and "survival_time_median_lo" not in table.columns
    with pytest.raises(ValueError, match="say which one"):
        scores_by_agent(table)
    scores = scores_by_agent(table, "sim")
    assert scores["pid"]["driven_lanedir_consec_median"] == 7.0
    crit = [Criterion("driven_lanedir_consec_median", True, 0.62), Criterion("survival_time_median", True, 2.0)]
    assert [r.agent for r in leaderboard(scores, crit)] == ["pure", "pid"]


def test_bad_tables_are_rejected_with_the_reason():
    rows = long_rows(DATA)
    with pytest.raises(ValueError, match="missing column"):
        aggregate([{k: v for k, v in r.items() if k != "domain"} for r in rows])
    with pytest.raises(ValueError, match="more than one value"):
        aggregate([*rows, rows[0]])
    with pytest.raises(ValueError, match="unknown statistic"):
        aggregate(rows, stats=("p90",))
    with pytest.raises(ValueError, match="numeric"):
        aggregate([{**rows[0], "value": "fast"}])


# ---------------------------------------------------------------------------------------------------
# bootstrap_ci


def test_bootstrap_two_values_hand_computed():
    # resampled means of [0, 1] are 0, 0.5 or 1 with probability 1/4, 1/2, 1/4: the 95 % interval is [0, 1]
    assert bootstrap_ci([0.0, 1.0], np.mean, 0.95, 2000, rng=1) == (0.0, 1.0)
    # the 40 % interval lies strictly inside the middle half: both ends at 0.5
    assert bootstrap_ci([0.0, 1.0], np.mean, 0.40, 2000, rng=1) == (0.5, 0.5)


def test_bootstrap_is_the_percentile_method():
    values = np.array([3.0, 1.0, 4.0, 1.0, 5.0, 9.0, 2.0])
    expected_boot = np.median(values[np.random.default_rng(7).integers(0, 7, size=(1000, 7))], axis=1)
    expected = tuple(np.quantile(expected_boot, [0.05, 0.95]))
    assert bootstrap_ci(values, np.median, 0.90, 1000, rng=np.random.default_rng(7)) == pytest.approx(expected)


def test_bootstrap_degenerate_cases_and_custom_statistics():
    assert bootstrap_ci([2.5]) == (2.5, 2.5)
    assert bootstrap_ci([4.0] * 6, np.mean) == (4.0, 4.0)
    assert all(math.isnan(v) for v in bootstrap_ci([]))
    p90 = bootstrap_ci([1.0, 2.0, 3.0, 4.0], lambda v: np.percentile(v, 90), n=200)  # no axis argument
    assert 1.0 <= p90[0] <= p90[1] <= 4.0
    wide, narrow = bootstrap_ci(range(20), level=0.95, rng=2), bootstrap_ci(range(20), level=0.5, rng=2)
    assert wide[0] <= narrow[0] <= narrow[1] <= wide[1]
    with pytest.raises(ValueError, match="level"):
        bootstrap_ci([1.0], level=1.0)
    with pytest.raises(ValueError, match="n must"):
        bootstrap_ci([1.0], n=0)
