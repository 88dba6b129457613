"""Sample-size planning and sequential allocation, on synthetic data where the answer is known."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from proxybench.usefulness.plan import next_agents, pair_needs, plan, settle_probability

runner = CliRunner()


def normal_pilot(means, n, sd=1.0, seed=0):
    rng = np.random.default_rng(seed)
    return {a: rng.normal(mu, sd, (n, 1)) for a, mu in means.items()}


def test_settle_probability_is_the_two_sided_power():
    # difference 2.8 standard errors: power (0.8) of a two-sided 5 % test; an exact tie is settled
    assert settle_probability(2.8, 1.0) == pytest.approx(0.80, abs=0.01)
    assert settle_probability(0.0, 1.0) == pytest.approx(0.05, abs=0.001)
    assert settle_probability(0.0, 0.0) == 1.0


def test_pair_needs_follow_the_two_sample_formula():
    # δ = 1, σ = 1 per agent: n = (1.96 + 0.84)² · 2 / 1 ≈ 15.7 → 16 episodes per agent for 80 % power
    pilot = normal_pilot({"a": 1.0, "b": 0.0}, 4000, seed=1)
    pilot = {a: v - v.mean() + mu for (a, v), mu in zip(pilot.items(), (1.0, 0.0), strict=True)}  # exact means
    few = {a: v[:3] for a, v in pilot.items()}
    need = pair_needs({a: v for a, v in pilot.items()}, (True,), ("x",))[0]
    assert need.settled  # 4000 episodes settle it
    need = pair_needs(few, (True,), ("x",))[0]
    assert need.a == "a" and need.b == "b"
    exact = (1.96 + 0.8416) ** 2 * (few["a"].std(ddof=1) ** 2 + few["b"].std(ddof=1) ** 2) / (
        few["a"].mean() - few["b"].mean()) ** 2
    assert abs(need.plug_in - math.ceil(exact)) <= 2  # the pilot's point values (t, not z: a little more)
    assert need.episodes_low < need.plug_in < need.episodes_high  # a 3-episode pilot gives a range, not a point


def test_exact_ties_are_settled_and_ties_within_noise_need_a_tolerance_to_be_finite():
    tie = {"a": np.full((3, 1), 20.0), "b": np.full((3, 1), 20.0)}  # both always survive the whole episode
    assert pair_needs(tie, (True,), ("survival",))[0].settled
    noisy = {"a": np.array([[1.0], [2.0], [3.0]]), "b": np.array([[3.0], [2.0], [1.0]])}
    strict = pair_needs(noisy, (True,), ("x",))[0]
    assert not strict.settled and strict.plug_in == math.inf  # no tolerance: a tie is never settled
    tolerant = pair_needs(noisy, (True,), ("x",), tolerances=(1.0,))[0]
    assert not tolerant.settled and math.isfinite(tolerant.plug_in) and math.isfinite(tolerant.episodes_high)
    assert tolerant.episodes_high < strict.episodes_high


def test_plan_finds_the_episodes_for_a_width_near_the_analytic_answer():
    # two agents, δ = 1, σ = 1: the pair is settled (order range width 0) with probability 0.8 at n ≈ 16
    rng = np.random.default_rng(2)
    pilot = {a: rng.normal(0, 1, (300, 1)) for a in ("a", "b")}
    pilot = {"a": pilot["a"] - pilot["a"].mean() + 1.0, "b": pilot["b"] - pilot["b"].mean()}
    p = plan(pilot, (True,), ("x",), width=0.0, confidence=0.8, reps=600)
    assert 11 <= p.n_for_width <= 22, p.n_for_width
    widths = [r.width_mean for r in p.rows]
    assert widths[0] >= widths[-1] and p.rows[-1].p_width == 1.0


def test_plan_probability_of_the_right_candidate_grows_with_episodes():
    rng = np.random.default_rng(3)
    noise = {a: rng.normal(0.0, 1.0, (4, 1)) for a in "abc"}
    target = {a: mu + noise[a] - noise[a].mean() for a, mu in zip("abc", (3.0, 2.0, 1.0), strict=True)}  # exact means
    good = {a: v + rng.normal(0, 0.2, v.shape) for a, v in target.items()}  # replays: the same order
    bad = {"a": good["a"], "b": good["c"] - 0.5, "c": good["b"] + 0.5}  # b and c swapped
    p = plan(target, (True,), ("x",), proxies={"good": good, "bad": bad}, p_correct=0.9, reps=300)
    assert p.best == ["good"] and p.pilot_prpv["bad"] > p.pilot_prpv["good"]
    assert p.rows[-1].p_correct >= 0.95 and p.rows[0].p_correct < p.rows[-1].p_correct
    assert p.n_for_p_correct is not None and p.n_for_p_correct <= 80
    with pytest.raises(ValueError, match=r"at least 2 pilot episodes with values per agent.*c has fewer"):
        plan({**target, "c": target["c"][:1]}, (True,), ("x",))
    with pytest.raises(ValueError, match="must replay the pilot's episodes"):
        plan(target, (True,), ("x",), proxies={"short": {a: v[:2] for a, v in good.items()}})


def test_next_agents_spend_episodes_on_the_near_tie():
    rng = np.random.default_rng(4)
    results = {"far": rng.normal(10, 1, (4, 1)), "b": rng.normal(2.0, 1, (4, 1)), "c": rng.normal(2.4, 1, (4, 1))}
    picks = next_agents(results, (True,), k=4)
    assert len(picks) == 4 and set(picks) <= {"b", "c"}
    assert next_agents({**results, "new": np.array([[1.0]])}, (True,), k=1) == ["new"]  # no spread yet: first
    settled = {"x": np.array([[1.0], [1.1]]), "y": np.array([[5.0], [5.1]])}
    assert next_agents(settled, (True,)) == []


def test_sequential_loop_runs_the_chosen_agents_on_a_live_target(tmp_path):
    from proxybench.experiments.plan.sequential import run_sequential
    from proxybench.runner.jobs import AgentSpec
    from proxybench.targets import RealityTarget

    agents = [AgentSpec("straight"), AgentSpec("pid"), AgentSpec("pid-fast")]
    kw = dict(map_name="loop_3x3", seconds=2.0, seed=0, metrics=("driven_lanedir_consec",), image_size=(32, 24),
              run_dir=tmp_path / "runs", pilot=2, budget=2, batch=1)
    res = run_sequential(RealityTarget(), agents, **kw)
    extra = sum(len(h.agents) for h in res.history)
    assert sum(res.episodes.values()) == 6 + extra and extra <= 2
    assert all(len(res.results[a]) == res.episodes[a] for a in res.episodes)
    assert {(e.agent, e.episode) for e in res.run.episodes} == {(a, e) for a, n in res.episodes.items()
                                                                for e in range(n)}
    again = run_sequential(RealityTarget(), agents, **kw)  # every episode cached: the same choices, nothing run
    assert again.ran == 0 and again.episodes == res.episodes


def _lab(tmp_path, rng):
    """A recorded target with scores only: a clear order and one near tie (pid-fast vs pid)."""
    root = tmp_path / "lab"
    root.mkdir()
    means = {"straight": 1.0, "pid": 6.0, "pid-fast": 6.2, "pure-pursuit": 9.0}
    (root / "target.yaml").write_text(yaml.safe_dump(
        {"source": "real", "map": "loop_3x3", "seconds": 2.0, "agents": list(means), "episodes": [0, 1, 2, 3],
         "metrics_table": "s.csv"}))
    rows = ["agent,episode,driven_lanedir_consec"] + [f"{a},{e},{rng.normal(mu, 0.5):.4f}" for a, mu in means.items()
                                                      for e in range(4)]
    (root / "s.csv").write_text("\n".join(rows) + "\n")
    return root


def test_cli_plan_on_a_recorded_target_and_sequential_refused(tmp_path):
    from proxybench.cli import app

    root = _lab(tmp_path, np.random.default_rng(5))
    out = tmp_path / "plan"
    res = runner.invoke(app, ["plan", "--target", str(root), "--metric", "driven_lanedir_consec", "--width", "0",
                              "--reps", "100", "--out", str(out), "--backend", "inline"])
    assert res.exit_code == 0, res.output
    assert "episodes per agent" in res.output and "pid – pid-fast" in res.output
    data = json.loads((out / "plan.json").read_text())
    assert data["pilot_episodes"] == {"straight": 4, "pid": 4, "pid-fast": 4, "pure-pursuit": 4}
    assert data["pairs"][0]["a"] == "pid" and not data["pairs"][0]["settled"]
    assert (out / "plan.png").exists() and (out / "pairs.csv").exists()
    res = runner.invoke(app, ["plan", "--target", str(root), "--metric", "driven_lanedir_consec", "--sequential",
                              "--out", str(out), "--backend", "inline"])
    assert res.exit_code == 2 and "cannot run more episodes" in res.output
    res = runner.invoke(app, ["plan", "--confidence", "1.5"])
    assert res.exit_code == 2 and "between 0 and 1" in res.output


def test_planned_width_matches_the_order_range_usefulness_reports():
    """The planner's simulated width at n agrees with what `usefulness` reports on experiments of n episodes."""
    from proxybench.usefulness import PairedResults, usefulness

    rng = np.random.default_rng(6)
    k, n = 6, 8
    mu = np.stack([np.linspace(0, 2.5, k), np.linspace(0, 1.2, k)], 1)
    widths = []
    for r in range(25):
        t = {f"a{i}": mu[i] + rng.normal(0, 1, (n, 2)) for i in range(k)}
        p = {a: v + rng.normal(0, 0.3, v.shape) for a, v in t.items()}
        e = usefulness(PairedResults(p, t, (True, True)), n_boot=150, seed=r)["prpv"]
        widths.append(e.high - e.low)
    big = {f"a{i}": mu[i] + rng.normal(0, 1, (2000, 2)) for i in range(k)}  # a pilot as good as the truth
    planned = plan(big, (True, True), ("x", "y"), proxies={"p": {a: v + rng.normal(0, 0.3, v.shape)
                                                                 for a, v in big.items()}}, grid=[n], reps=300)
    row = next(r for r in planned.rows if r.n == n)
    assert row.width_mean == pytest.approx(np.mean(widths), rel=0.35), (row.width_mean, np.mean(widths))
