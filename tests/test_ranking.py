"""`proxybench rank` (issue 34): pairwise decisions with a guarantee, the proxy as a PPI++ predictor, rank-sets,
the anytime-valid sequential mode, and the errors a user sees for bad input."""

from __future__ import annotations

import json
import os
import shlex
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.runner.jobs import AgentSpec
from proxybench.targets import RealityTarget
from proxybench.targets.record import record_target
from proxybench.usefulness.ranking import PairDecision, RankingError, decide, fixed_interval, rank, rank_sets
from proxybench.usefulness.ranking_check import coverage

runner = CliRunner()
EIGHT = ["straight", "bang-bang", "pid", "pid-fast", "pid-twitchy", "pure-pursuit", "vision", "random"]


# ------------------------------------------------------------------------------------------- the statistics
def test_the_proxy_weight_is_ppi_pythons_and_the_interval_its_own_widened_to_students_t():
    from ppi_py import ppi_mean_ci
    from scipy import stats

    rng = np.random.default_rng(0)
    d = rng.normal(size=(30, 4))
    d_hat = 0.8 * d + rng.normal(0, 0.5, d.shape)
    d_unl = rng.normal(size=(300, 4))
    _, lo, hi, lam = fixed_interval(d, d_hat, d_unl, 0.05)
    lo2, hi2 = ppi_mean_ci(d, d_hat, d_unl, alpha=0.05, lam_optim_mode="element")
    assert np.all((lam > 0) & (lam <= 1))
    assert np.allclose((hi - lo) / (hi2 - lo2), stats.t.ppf(0.975, 29) / stats.norm.ppf(0.975) * np.sqrt(30 / 29))


def test_a_proxy_that_anticorrelates_gets_no_weight_and_changes_nothing():
    rng = np.random.default_rng(1)
    d = rng.normal(size=(25, 3))
    _, lo, hi, lam = fixed_interval(d, -d + rng.normal(0, 0.1, d.shape), rng.normal(size=(200, 3)), 0.05)
    _, lo0, hi0, _ = fixed_interval(d, None, None, 0.05)
    assert np.all(lam == 0) and np.allclose(lo, lo0) and np.allclose(hi, hi0)


@pytest.mark.parametrize(("low", "high", "higher", "decision"), [
    (0.3, 0.9, True, "a>b"), (-0.9, -0.3, True, "b>a"), (-0.9, -0.3, False, "a>b"), (-0.1, 0.15, True, "tie"),
    (-0.1, 0.5, True, "undecided"), (0.1, 0.5, True, "undecided")])  # 0.1 is not beyond ε = 0.2
def test_an_interval_decides_by_the_tolerance(low, high, higher, decision):
    assert decide(low, high, 0.2, higher) == decision


def test_rank_sets_count_the_agents_decided_better_and_worse():
    p = [PairDecision("a", "b", "m", "a>b", 1, (0.5, 1.5), 9, 0),
         PairDecision("a", "c", "m", "a>b", 1, (0.5, 1.5), 9, 0),
         PairDecision("b", "c", "m", "undecided", 0, (-1, 1), 9, 0)]
    assert rank_sets(p, ["a", "b", "c"], "m") == {"a": (1, 1), "b": (2, 3), "c": (2, 3)}


@pytest.mark.parametrize("mode", ["fixed", "anytime"])
@pytest.mark.parametrize("proxy", ["good", "bad"])
def test_the_chance_of_any_wrong_decision_stays_within_alpha(mode, proxy):
    """Simulated worlds with a known order; anytime: a wrong decision at *any* episode count counts."""
    c = coverage(k=4, n=30, big_n=300, proxy=proxy, mode=mode, runs=150, alpha=0.1, seed=7)
    assert c.interval[0] <= c.alpha, f"{c.wrong} of {c.runs} worlds had a wrong decision"
    assert c.decided_with > 0.1  # and it decides something (a rule that never decides is trivially right)


def test_a_good_proxy_decides_more_pairs_from_the_same_target_episodes():
    from functools import partial

    import proxybench.usefulness.ranking_check as rc

    world = rc.draw_world
    try:
        rc.draw_world = partial(world, noise=0.25)  # the start explains most of an episode's score
        c = coverage(k=5, n=30, big_n=1000, proxy="good", mode="fixed", runs=60, alpha=0.1, seed=3)
    finally:
        rc.draw_world = world
    assert c.worth > 1.2 and c.decided_with > c.decided_alone


def test_bad_input_names_the_value():
    one = {"pid": {0: [1.0], 1: [2.0]}}
    two = {**one, "straight": {0: [0.0], 1: [0.5]}}
    with pytest.raises(RankingError, match="at least 2, got 1 \\(pid\\)"):
        rank(one, None, ["m"], [True], [0.0])
    with pytest.raises(RankingError, match=r"alpha: 1\.5 is not within"):
        rank(two, None, ["m"], [True], [0.0], 1.5)
    with pytest.raises(RankingError, match="proxy: no episodes of straight"):
        rank(two, {"pid": {0: [1.0]}}, ["m"], [True], [0.0])


# ------------------------------------------------------------------------------------------- the command
@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rec = tmp_path_factory.mktemp("rank") / "rec"
    record_target(rec, RealityTarget(), [AgentSpec(a) for a in EIGHT], episodes=4, seconds=2.0)
    return rec


def _rank(*args):
    return runner.invoke(app, ["rank", "--backend", "inline", *args])


def test_rank_on_a_recording_of_eight_agents_writes_every_pair_with_and_without_the_proxy(recording, tmp_path):
    res = _rank("--target", str(recording), "--proxy-episodes", "6", "--out", str(tmp_path / "r"))
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "r" / "rank.json").read_text())
    assert data["alpha"] == 0.05 and "family-wise" in data["error_control"]
    assert len(data["pairs"]) == len(data["target_only"]) == 28 * 2  # 8 agents, two metrics
    pair = data["pairs"][0]
    assert {"a", "b", "metric", "decision", "estimate", "interval"} <= set(pair)
    assert data["episodes"] == {"target": 32, "target_per_agent": dict.fromkeys(EIGHT, 4), "proxy_paired": 32,
                                "proxy_only": 48}
    assert data["target"]["kind"] == "recorded" and any("start distribution" in n for n in data["notes"])
    assert set(data["rank_sets"]["survival_time"]) == set(EIGHT)
    bt = data["bradley_terry"]["driven_lanedir_consec"]
    assert bt["reference"] == EIGHT[0] and len(bt["with_proxy"]) == len(bt["target_only"]) == 8
    assert 0.0 <= bt["weight"] <= 1.0 and all(lo <= s <= hi for _, s, lo, hi in bt["with_proxy"])
    html = (tmp_path / "r" / "rank.html").read_text()
    assert "rank-sets" in html and "data:image/png;base64" in html


@pytest.mark.parametrize(("args", "says"), [
    (["--agent", "pid"], "agents: ranking needs at least 2, got 1 (pid)"),
    (["--alpha", "1.5"], "alpha"),
    (["--metric", "survival_tme"], "unknown metric 'survival_tme'"),
    (["--episodes", "0-9"], "episodes: 4, 5, 6, 7, 8, 9 not in the recording"),
])
def test_bad_input_to_rank_is_a_one_line_error(recording, tmp_path, args, says):
    res = _rank("--target", str(recording), "--out", str(tmp_path / "r"), *args)
    assert res.exit_code != 0
    assert says in res.output and "Traceback" not in res.output
    assert "proxy" not in res.output  # refused before any proxy episode ran
    assert len([ln for ln in res.output.splitlines() if "error" in ln.lower()]) <= 2, res.output


def test_the_sequential_mode_replays_a_recording_and_resumes_from_its_cache(recording, tmp_path):
    out = tmp_path / "s"
    args = ["--target", str(recording), "--agent", "straight", "--agent", "pid", "--agent", "pid-fast",
            "--episodes", "2", "--sequential", "--budget", "4", "--proxy-episodes", "4", "--out", str(out)]
    first = _rank(*args)
    assert first.exit_code == 0, first.output
    data = json.loads((out / "rank.json").read_text())
    assert data["sequential"] and data["stopped"] in ("settled", "budget")
    assert len(data["steps"]) <= 4 and data["episodes"]["target"] == 6 + len(data["steps"])
    again = _rank(*args)  # every episode from the cache: the same choices, the same decisions
    assert json.loads((out / "rank.json").read_text())["pairs"] == data["pairs"], again.output


def test_rank_runs_against_a_robot_node(tmp_path):
    robot = shlex.join([sys.executable, "-m", "proxybench", "robot", "serve", "--param", "trim=0.05"])
    res = _rank("--target", f"robot:{robot}", "--agent", "straight", "--agent", "pid", "--episodes", "2",
                "--seconds", "2", "--proxy-episodes", "2", "--out", str(tmp_path / "r"))
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "r" / "rank.json").read_text())
    assert data["target"]["kind"] == "robot" and data["episodes"]["target"] == 4


def test_rank_runs_against_gym_duckietown(tmp_path):
    from proxybench.gym.environment import check_environment

    env = check_environment(render=False)
    if not env.ok:
        if os.environ.get("PROXYBENCH_REQUIRE_GYM") == "1":
            pytest.fail("; ".join(env.problems))
        pytest.skip("gym-duckietown's environment is not ready (run `proxybench gym setup`)")
    gym = shlex.join([sys.executable, "-m", "proxybench.cli", "gym", "serve", "--param", "camera_width=80",
                      "--param", "camera_height=60"])
    res = _rank("--target", f"robot:{gym}", "--agent", "straight", "--agent", "pid", "--episodes", "2",
                "--seconds", "2", "--proxy-episodes", "2", "--out", str(tmp_path / "r"))
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "r" / "rank.json").read_text())
    assert "gym" in data["target"]["statement"].lower() and len(data["pairs"]) == 2


def test_rank_check_judges_decisions_with_further_episodes_and_tries_an_adversarial_proxy(tmp_path):
    res = runner.invoke(app, ["rank-check", "--quick", "--backend", "inline", "--out", str(tmp_path / "c")])
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / "c" / "summary.json").read_text())
    assert summary["targets"] == 2 and summary["pairs"] == 2 * 3 * 2  # 3 agents: 3 pairs × 2 metrics
    for key in ("wrong_with", "wrong_alone", "wrong_bad", "anytime_wrong_with", "anytime_wrong_bad"):
        assert 0 <= summary[f"targets_{key}"]["count"] <= 2
    assert "SIMULATED" in summary["statement"] and "held-out" in res.output


def test_an_inverted_proxy_orders_the_agents_backwards():
    from proxybench.usefulness.ranking_check import inverted

    proxy = {"a": {0: [3.0], 1: [3.2]}, "b": {0: [2.0], 1: [2.1]}, "c": {0: [1.0], 1: [0.9]}}
    bad = inverted(proxy)
    assert [float(bad[x][0][0]) for x in "abc"] == [1.0, 2.0, 3.0]


def test_a_decision_is_contradicted_only_when_the_truths_interval_excludes_it():
    from proxybench.usefulness.ranking_check import contradicted

    rng = np.random.default_rng(0)
    truth = {"a": {e: [v] for e, v in enumerate(rng.normal(1.0, 0.1, 60))},
             "b": {e: [v] for e, v in enumerate(rng.normal(0.0, 0.1, 60))}}
    right, wrong, unsure = (PairDecision("a", "b", "m", d, 0, (0, 0), 5, 0) for d in ("a>b", "b>a", "undecided"))
    tie = PairDecision("a", "b", "m", "tie", 0, (0, 0), 5, 0)
    assert contradicted([right, unsure], truth, ["m"], [0.1], [True]) == 0
    assert contradicted([wrong, tie], truth, ["m"], [0.1], [True]) == 2


def test_the_sequential_mode_runs_live_episodes_where_pairs_are_open(tmp_path):
    res = _rank("--quick", "--sequential", "--budget", "3", "--out", str(tmp_path / "s"))
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "s" / "rank.json").read_text())
    assert data["sequential"] and data["target"]["kind"] == "reality-model" and len(data["steps"]) <= 3
    assert data["episodes"]["target"] == 4 * 4 + len(data["steps"])
    for step in data["steps"]:  # each chosen agent was in an open pair and ran its next episode id
        assert step["open_pairs"] > 0 and step["episode"] >= 4
