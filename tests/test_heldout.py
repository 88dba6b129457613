"""Held-out targets and the held-out experiment: hidden truths stay hidden, the scoring is what its docs say,
and `proxybench heldout --quick` runs end to end with a mixed agent set (zoo, checkpoint, node)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.experiments.config import ConfigError
from proxybench.experiments.heldout.run import load_heldout_config
from proxybench.runner.jobs import AgentSpec
from proxybench.targets.heldout import FAMILY_PARAMS, HeldOutTarget, draw_heldout, heldout_targets
from proxybench.usefulness.agent_sets import leave_one_out, order_structure, sensitivity
from proxybench.usefulness.heldout_scoring import Grid, best_available, mcnemar_p, order_disagreement, wilson
from support.checkpoints import untrained_checkpoint

runner = CliRunner()


# --- the family ------------------------------------------------------------------------------------


def test_heldout_draws_are_reproducible_distinct_and_in_range():
    a, b = draw_heldout(3, 0), draw_heldout(3, 1)
    assert a == draw_heldout(3, 0) and a != b and a != draw_heldout(4, 0)
    for d in (a, b):
        for name, (lo, hi) in FAMILY_PARAMS.items():
            value = d["command_delay_mean"] if name == "command_delay" else d[name]
            assert lo <= value <= hi
        assert d["lens_model"] in ("plumb_bob", "equidistant") and abs(d["camera_yaw"]) <= 3


def test_a_heldout_target_is_a_black_box_until_revealed(tmp_path):
    t = HeldOutTarget(11, 2)
    run = t.run([AgentSpec("pid")], map_name="loop_3x3", seconds=1.0, episodes=1, seed=0,
                metrics=("survival_time",), image_size=(32, 24), run_dir=tmp_path)
    assert run.truth == {} and run.params is None and run.info.simulated is True
    revealed = t.reveal()
    text = run.info.statement + run.info.label + json.dumps(run.info.details)
    assert f"{revealed['trim']:.3f}"[:5] not in text and "SIMULATED" in run.info.statement
    # the reveal gives the mean latency (what a proxy's fixed delay should match), and the fixed part
    assert revealed["command_delay"] >= revealed["command_delay_fixed"]
    assert [x.name for x in heldout_targets(2, 11)] == ["heldout-0", "heldout-1"]
    with pytest.raises(ValueError, match="targets"):
        heldout_targets(0, 11)


# --- scoring ---------------------------------------------------------------------------------------


def test_order_disagreement_counts_resolved_pairs_only():
    # a ≫ b on metric 0; c is within noise of b: (b, c) is not resolved and never scored
    t = {"a": np.array([[5.0], [5.1]]), "b": np.array([[1.0], [1.4]]), "c": np.array([[1.1], [1.3]])}
    good = {"a": np.array([[4.0]]), "b": np.array([[1.0]]), "c": np.array([[2.0]])}
    bad = {"a": np.array([[0.0]]), "b": np.array([[1.0]]), "c": np.array([[2.0]])}
    tie = {"a": np.array([[1.0]]), "b": np.array([[1.0]]), "c": np.array([[2.0]])}
    assert order_disagreement(good, t, (True,)) == (0.0, 2)
    assert order_disagreement(bad, t, (True,)) == (2.0, 2)
    assert order_disagreement(tie, t, (True,)) == (1.5, 2)  # a tie with b counts ½, a below c counts 1
    assert order_disagreement(bad, t, (False,))[0] == 2.0  # a disagreement whichever direction is better
    best, d = best_available([bad, good, tie], t, (True,))
    assert best == [1] and d.tolist() == [2.0, 0.0, 1.5]


def test_grid_distances_nearest_and_chance():
    g = Grid.from_dict({"trim": [0.1, -0.1, 0.0], "camera_pitch": [15.0, 19.0, 23.0]})
    assert g.values[0] == (-0.1, 0.0, 0.1) and len(g) == 9
    assert g.label(0) == "trim=-0.1, camera_pitch=15"
    assert g.nearest({"trim": 0.04, "camera_pitch": 22.0}) == [5]  # (0.0, 23)
    assert g.distance(0, 8) == 2 and g.within(0, [4], 1) and not g.within(0, [8], 1)
    assert g.chance({4}, 1) == 1.0 and g.chance({0}, 0) == pytest.approx(1 / 9)
    assert g.nearest({"trim": 0.05, "camera_pitch": 19.0}) == [4, 7]  # a tie: both


def test_wilson_and_mcnemar_against_hand_values():
    lo, hi = wilson(0, 10)
    assert lo == 0.0 and hi == pytest.approx(0.2775, abs=1e-4)
    lo, hi = wilson(10, 10)
    assert lo == pytest.approx(0.7225, abs=1e-4) and hi == 1.0
    assert mcnemar_p([1, 1, 1, 0], [0, 0, 0, 0]) == (3, 0, 0.25)  # 2 × 0.5³
    assert mcnemar_p([1, 0], [1, 0])[2] == 1.0


def test_agent_set_views():
    # three agents, one metric: the target orders a > b > c; proxy 0 swaps a and b, proxy 1 is right
    target = np.array([[3.0], [2.0], [1.0]])
    proxies = np.stack([np.array([[2.0], [3.0], [1.0]]), np.array([[3.0], [2.0], [1.0]])])
    rng = np.random.default_rng(0)
    # without a or without b the swap disappears and both proxies tie; without c, proxy 1 still wins
    loo = leave_one_out(proxies, target, (True,), rng)
    assert loo[2] == 1
    sens = sensitivity(["a", "b", "c"], proxies, target, (True,), n_boot=50)
    assert sens.full_argmin == 1 and sens.boot_prpv_norm.shape == (50, 2)
    lo, hi = sens.interval()
    assert lo[1] == hi[1] == 0.0 and hi[0] > 0
    s = order_structure({"a": np.array([[20.0, 5.0]]), "b": np.array([[20.0, 3.0]]), "c": np.array([[9.0, 6.0]])},
                        (True, True), caps=(20.0, None))
    assert (s["decided_by_one_metric"], s["incomparable"], s["both_agree"]) == (1, 2, 0)
    assert s["agents_at_cap_0"] == 2 and s["at_cap_0"] == pytest.approx(2 / 3)


def test_config_errors_name_the_field(tmp_path):
    with pytest.raises(ConfigError, match="grid"):
        load_heldout_config(None, {"grid": {"trim": [0.1]}})
    with pytest.raises(ConfigError, match="primary_task"):
        load_heldout_config(None, {"primary_task": "nope"})
    with pytest.raises(ConfigError, match="survival"):
        load_heldout_config(None, {"tasks": {"x": ["survival"]}})
    bad = tmp_path / "h.yaml"
    bad.write_text("targetz: 3\n")
    with pytest.raises(ConfigError, match="targetz"):
        load_heldout_config(bad)


# --- end to end ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    """An untrained behaviour-cloning network: a real checkpoint agent, driving badly."""
    return untrained_checkpoint(tmp_path_factory.mktemp("bc"))


TINY = ["--quick", "--targets", "1", "--episodes", "1", "--reference-episodes", "2", "--seconds", "2", "--grid",
        "trim=-0.2,0.2", "--grid", "camera_pitch=15.15,23.15", "--n-boot", "10", "--agent-boot", "10", "--backend",
        "inline"]


def test_heldout_quick_runs_end_to_end_with_the_negative_case(tmp_path):
    out = tmp_path / "h"
    args = ["heldout", *TINY, "--agent", "straight", "--agent", "pid", "--agent", "vision", "--out", str(out)]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert "SIMULATED" in res.output and "hit rates on 1 held-out targets" in res.output
    assert "Negative case (lens-negative)" in res.output
    crit = json.loads((out / "criteria.json").read_text())
    assert crit["settings"]["criteria"]["primary_tolerance_steps"] == 1 and "reference episodes" in \
        crit["best_available_definition"]
    # the criteria were on disk before any result
    assert (out / "criteria.json").stat().st_mtime <= min((out / "runs" / "run.json").stat().st_mtime,
                                                          (out / "cases.csv").stat().st_mtime)
    page = (out / "report.html").read_text()
    assert "Pass criteria, fixed before the run" in page and "SIMULATED TARGETS" in page
    assert "lens-negative" in page and "heldout-0" in page
    import pandas as pd

    cases = pd.read_csv(out / "cases.csv")
    assert set(cases.case) == {"heldout-0", "lens-negative"} and len(cases) == 4  # 2 cases × 2 tasks
    assert cases.truth_trim.notna().all()  # revealed for scoring, after the runs
    rates = pd.read_csv(out / "rates.csv")
    assert set(rates.metric) >= {"PRPV", "PPV", "Kendall τ", "MMRV"} and (rates.n == 1).all()
    assert ((rates.low <= rates.rate) & (rates.rate <= rates.high)).all()
    values = pd.read_csv(out / "values.csv")
    assert len(values) == 2 * 2 * 4  # cases × tasks × grid points
    for name in ("fig_hit_rates.png", "fig_prpv_maps.svg", "rates.parquet"):
        assert (out / name).stat().st_size > 0
    # a second run re-uses every episode
    again = runner.invoke(app, args)
    assert again.exit_code == 0 and "0 episodes simulated" in (out / "report.html").read_text()


@pytest.mark.slow
def test_heldout_with_a_mixed_agent_set_zoo_checkpoint_and_node(tmp_path, checkpoint):
    node = f"pixnode={sys.executable} {Path(__file__).parent / 'protocol_agents' / 'pixel_agent.py'} pixel"
    out = tmp_path / "mixed"
    res = runner.invoke(app, ["heldout", *TINY, "--no-negative-case", "--agent", "pid", "--agent", "vision",
                              "--agent", str(checkpoint), "--agent", node, "--out", str(out)])
    assert res.exit_code == 0, res.output
    import pandas as pd

    cases = pd.read_csv(out / "cases.csv")
    assert set(cases.case) == {"heldout-0"}
    settings = json.loads((out / "criteria.json").read_text())["settings"]
    assert settings["agents"] == ["pid", "vision", str(checkpoint), node]
    assert "4 agents" in (out / "report.html").read_text()


def test_heldout_cli_rejects_bad_options(tmp_path):
    res = runner.invoke(app, ["heldout", "--grid", "trim=a,b", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "--grid" in res.output
    res = runner.invoke(app, ["heldout", "--agent", "nobody-xyz", "--agent", "pid", "--out", str(tmp_path),
                              "--targets", "1"])
    assert res.exit_code == 2 and "nobody-xyz" in res.output


def test_predictivity_with_a_mixed_agent_set_reports_agent_set_sensitivity(tmp_path, checkpoint):
    from proxybench.experiments.config import ExperimentConfig
    from proxybench.experiments.predictivity.report import findings, write_report
    from proxybench.experiments.predictivity.run import run_predictivity

    cfg = ExperimentConfig(agents=["straight", "pid", "vision", str(checkpoint)], episodes=2, seconds=2.0,
                           metrics=("driven_lanedir_consec", "survival_time"), sweep={"trim": (-0.3, 0.0)}, n_boot=10,
                           pod_seconds=0.0)
    res = run_predictivity(cfg, tmp_path / "runs")
    assert set(res.target_scores) == {"straight", "pid", "vision", str(checkpoint)}
    sens = res.agent_sensitivity["trim"]
    assert len(sens.loo_argmin) == 4 and sens.boot_prpv_norm.shape == (10, 2) and sens.full_argmin in (0, 1)
    assert res.order["pairs"] == 6 and "agents_at_cap_1" in res.order
    lines = findings(res)
    assert any(line.startswith("trim, agent set: PRPV's smallest value") for line in lines)
    assert any(line.startswith("Task order on the target: of 6 agent pairs") for line in lines)
    assert "agent set" in write_report(res, tmp_path / "report")["html"].read_text()


def test_cached_episodes_are_scored_for_metrics_a_later_run_asks_for(tmp_path):
    from proxybench.runner.jobs import DomainSpec, Job
    from proxybench.runner.sweep import run_jobs

    def jobs(metrics):
        return [Job(AgentSpec("pid"), DomainSpec("nominal"), "loop_3x3", e, e, 2.0, metrics=metrics) for e in (0, 1)]

    first = run_jobs(jobs(("survival_time",)), tmp_path)
    again = run_jobs(jobs(("survival_time", "lane_score")), tmp_path)
    assert first.ran == 2 and again.ran == 0
    assert all(set(r.scores) >= {"survival_time", "lane_score"} for r in again.results)
    assert [r.scores["survival_time"] for r in again.results] == [r.scores["survival_time"] for r in first.results]


def test_heldout_config_refuses_an_image_size_theta_cannot_take():
    from proxybench.experiments.heldout.config import HeldOutConfig

    with pytest.raises(ConfigError, match="image_size: width and height must be within 8…4096 px, got 4×4"):
        load_heldout_config(None, {"image_size": [4, 4]})
    assert HeldOutConfig(image_size=(32, 24)).image_size == (32, 24)
