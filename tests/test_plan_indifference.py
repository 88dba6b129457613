"""ε-indifference, episode ranges from the pilot's posterior, and the sequential stopping rule with its simulation."""

from __future__ import annotations

import math
import runpy
import sys
from pathlib import Path

import numpy as np
import pytest

from proxybench.usefulness.indifference import (
    OPEN,
    TIE,
    Rule,
    episodes_to_settle,
    needs,
    semiorder_tolerances,
    settle_state,
)
from proxybench.usefulness.stopping import decide, look_schedule, run_until_settled

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def test_tolerances_are_the_benchmarks_scaled_to_the_episode_length():
    # AIDO LF: 0.62 m of distance and 2 s of survival per 60 s episode; the lane score takes survival's
    assert semiorder_tolerances(("driven_lanedir_consec", "survival_time"), 60.0) == (0.62, 2.0)
    eps = semiorder_tolerances(("driven_lanedir_consec", "lane_score", "deviation_heading"), 15.0)
    assert eps == pytest.approx((0.155, 0.5, 0.0))
    assert semiorder_tolerances(("lane_score",), 15.0, overrides={"lane_score": 0.0}) == (0.0,)


def test_a_pair_is_ordered_tied_or_open():
    r = Rule((1.0,))
    assert r.quantile(np.array([4.0, 30.0, np.inf]))[:2] == pytest.approx([2.776, 2.042], abs=1e-3)  # t, then z
    assert r.quantile(np.inf) == pytest.approx(1.960, abs=1e-3)
    df = np.array([20.0])
    assert settle_state(np.array([2.0]), np.array([0.5]), df, r)[0] == 1  # 2 ± 1.04: ordered, a better
    assert settle_state(np.array([-2.0]), np.array([0.5]), df, r)[0] == -1
    assert settle_state(np.array([0.1]), np.array([0.2]), df, r)[0] == TIE  # 0.1 ± 0.42 inside ±1
    assert settle_state(np.array([0.5]), np.array([0.5]), df, r)[0] == OPEN  # 0.5 ± 1.04: neither
    assert settle_state(np.array([0.5]), np.array([0.0]), df, r)[0] == TIE  # always alike within ε (a cap)
    assert settle_state(np.array([0.5]), np.array([np.nan]), df, r)[0] == OPEN  # one episode: no spread yet
    strict = Rule((0.0,))
    assert settle_state(np.array([0.1]), np.array([0.2]), df, strict)[0] == OPEN  # no tolerance: never a tie


def test_with_a_tolerance_every_pair_settles_with_finitely_many_episodes():
    r = Rule((0.5,))
    d = np.array([0.0, 0.25, 0.5, 1.0, 3.0])
    n = episodes_to_settle(d, np.full(d.shape, 2.0), 0.5, r)
    assert np.all(np.isfinite(n)) and n[-1] < n[-2] < n[1]  # far pairs are cheap; the worst is near ε/2
    assert n.max() < 4 * (2.0 + 1.0) ** 2 * 2.0 / 0.5 ** 2  # the bound of the docstring, roughly
    assert episodes_to_settle(np.array([0.0]), np.array([2.0]), 0.0, Rule((0.0,)))[0] == math.inf
    assert episodes_to_settle(np.array([0.3]), np.array([0.0]), 0.0, Rule((0.0,)))[0] == 0.0  # exact values


def test_episode_ranges_carry_the_pilots_uncertainty():
    rng = np.random.default_rng(3)
    big = {"a": rng.normal(0.0, 1.0, (400, 1)), "b": rng.normal(1.0, 1.0, (400, 1))}
    small = {a: v[:3] for a, v in big.items()}
    r = Rule((0.25,))
    wide, narrow = needs(small, (True,), r, seed=1), needs(big, (True,), r, seed=1)
    assert wide.high[0] / wide.low[0] > 5 * narrow.high[0] / narrow.low[0]  # 3 episodes: a wide range
    assert wide.all_pairs[1] <= wide.all_pairs[0] <= wide.all_pairs[2]


def test_the_loop_orders_far_pairs_ties_close_ones_and_stops():
    rng = np.random.default_rng(0)
    truth = {"a": 0.0, "b": 3.0, "c": 3.1}
    pilot = {a: rng.normal(mu, 1.0, (3, 1)) for a, mu in truth.items()}

    def fetch(picks):
        return [rng.normal(truth[a], 1.0, 1) for a in picks]

    res = run_until_settled(pilot, fetch, (True,), tolerances=(1.0,), budget=400, batch=3)
    # the better agent of each pair, or a tie
    assert res.stopped == "settled" and res.decisions == {("a", "b"): "b", ("a", "c"): "c", ("b", "c"): "tie"}
    assert res.spent < 400 and all(len(v) >= 3 for v in res.results.values())
    assert res.rule.looks == len(look_schedule(9, 400))
    short = run_until_settled(pilot, fetch, (True,), tolerances=(0.0,), budget=6, batch=3)
    assert short.stopped == "budget" and ("b", "c") in short.open_pairs() and short.spent == 6
    assert decide(pilot, (True,), Rule((0.0,)))[("b", "c")] == "open"


def test_look_schedule_grows_by_half_and_ends_at_the_budget():
    assert look_schedule(18, 60) == [18, 27, 41, 62, 78]
    assert look_schedule(10, 0) == [10]
    with pytest.raises(ValueError, match="growth"):
        look_schedule(10, 5, growth=1.0)


def test_stopping_benchmark_quick_prints_error_rates(capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["bench_stopping.py", "--quick"])
    runpy.run_path(str(BENCH / "bench_stopping.py"), run_name="__main__")
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| ") and "---" not in line][1:]
    assert len(rows) == 8 and {r.split("|")[3].strip() for r in rows} == {"split over looks", "no correction"}
    for r in rows:
        cells = [c.strip() for c in r.split("|")[4:-1]]
        assert all(0.0 <= float(c) <= 1.0 for c in cells[:5] + cells[-1:]), r
