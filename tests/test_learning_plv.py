"""PLV arithmetic, the summary of a PLV run (including "not reached"), and a tiny end-to-end run via the CLI."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from proxybench.experiments.plv.report import figure_3_6, figure_plv, findings, score_range, summarize, table_rows
from proxybench.experiments.plv.run import PLVConfig, PLVResult
from proxybench.usefulness.plv import DataCost, first_reaching, mean_ci, plv, reference_score


def test_plv_and_reduction():
    r = plv(DataCost(9000), DataCost(500))
    assert r.status == "ok" and r.value == 8500 and r.reduction == pytest.approx(8500 / 9000)
    assert r.label == "8,500" and r.reduction_label == "94 %"
    assert plv(DataCost(1000), DataCost(2000)).value == -1000  # a harmful proxy has a negative PLV


def test_plv_not_reached_is_not_a_number():
    r = plv(DataCost(4000), None)
    assert r.status == "not reached" and r.value is None and r.reduction is None
    assert r.label == "not reached" and r.reduction_label == "–"
    assert plv(None, DataCost(10)).status == "target not reached"


def test_generalised_plv_weighs_on_and_off_policy_samples():
    target, proxy = DataCost(off_policy=1000, on_policy=1000), DataCost(off_policy=100, on_policy=300)
    assert plv(target, proxy).value == 1600
    r = plv(target, proxy, eta_on=3.0, eta_off=1.0)
    assert r.value == (3 * 1000 + 1000) - (3 * 300 + 100)
    assert r.target_cost == 4000 and r.proxy_cost == 1000


def test_first_reaching_and_reference():
    assert first_reaching([1000, 250, 500], [9.0, 1.0, 8.0], 8.0) == 500  # ladder order, not list order
    assert first_reaching([250, 500], [1.0, float("nan")], 0.5) == 250
    assert first_reaching([250, 500], [1.0, 2.0], 5.0) is None
    assert reference_score(20.0, 0.05) == pytest.approx(19.0)
    assert reference_score(-10.0, 0.1) == pytest.approx(-11.0)
    m, lo, hi = mean_ci([1.0, 2.0, 3.0])
    assert m == 2.0 and lo < 2.0 < hi and mean_ci([4.0]) == (4.0, 4.0, 4.0)


def _runs(arm, curve):
    return [{"arm": arm, "n": n, "seed": s, "off_policy": n, "on_policy": 0, "cost": float(n), "score": v + 0.1 * s}
            for n, v in curve for s in (0, 1)]


def _proxy(spec, zero_shot):
    return {"spec": spec, "zero_shot": zero_shot + 0.05, "in_proxy": 24.0,
            "zero_shot_by_seed": {"0": zero_shot, "1": zero_shot + 0.1}}


def test_summary_counts_a_rung_only_when_the_score_stays_above_the_reference():
    """Hand-computed: seeds score v and v + 0.1, so each rung's mean is v + 0.05; P = 0.95 · 20.05 = 19.0475."""
    cfg = PLVConfig(width=32, height=24, ladder=(250, 500, 1000, 2000), seeds=(0, 1), confirm=2,
                    proxies={"good": "proxy", "flaky": "proxy:trim=0.1", "bad": "proxy:camera_pitch=35",
                             "free": "randomized"})
    runs = (_runs("target-only", [(250, 5.0), (500, 19.5), (1000, 18.0), (2000, 20.0)])  # 500 reaches P once
            + _runs("good", [(250, 19.8), (500, 19.9), (1000, 19.5)])
            + _runs("flaky", [(250, 15.0), (500, 19.5), (1000, 19.5), (2000, 19.5)])
            + _runs("bad", [(250, 2.0), (500, 3.0), (1000, 4.0), (2000, 5.0)])
            + _runs("free", [(250, 19.5), (500, 19.5)]))
    proxies = {"good": _proxy("proxy", 8.0), "flaky": _proxy("proxy:trim=0.1", 19.5),
               "bad": _proxy("proxy:camera_pitch=35", 12.0), "free": _proxy("randomized", 19.5)}
    res = PLVResult(cfg, runs, proxies, expert_score=21.0)
    s = summarize(res)
    assert s.ladder_reference == pytest.approx(0.95 * 20.05) and not s.converged_ok  # 18.05 → 20.05 is > 5 %
    assert s.target_first == DataCost(500) and s.target_needed == DataCost(2000)  # 500 fell below P at 1,000
    rows = {r.proxy: r for r in s.rows}
    good, flaky, bad, free = rows["good"], rows["flaky"], rows["bad"], rows["free"]
    assert good.ladder_needed == 250 and good.ladder_plv == 1750 and good.ladder_reduction_label == "88 %"
    assert flaky.first_reached == 0 and flaky.ladder_needed == 500  # zero-shot reached P, then fell
    assert flaky.ladder_plv == 1500
    assert bad.ladder_plv is None and bad.ladder_plv_label == "not reached"
    assert bad.ladder_needed_label == "not reached" and bad.tried_up_to == 2000
    assert free.ladder_needed == 0 and free.ladder_reduction_label == "100 %"  # zero-shot, and it stays
    # every seed sits 0.05 from its rung's mean, far from P: the bootstrap cannot move any answer
    assert good.ladder_plv_ci == "1,750 [1,750, 1,750]" and bad.ladder_plv_ci == "not reached"
    assert free.ladder_reached_share == 1.0 and bad.ladder_reached_share == 0.0
    assert s.intervals.target_needed.label() == "2,000 [2,000, 2,000]"
    # the fitted curves: a bad proxy stays far below P (not reached); the others reach it, each with a number
    assert bad.plv is None and bad.status == "not reached" and bad.plv_label == "not reached"
    assert good.status == "ok" and good.plv == pytest.approx(s.target_cost - good.needed)
    assert free.needed == 0.0 and free.reduction == pytest.approx(1.0)  # above P from zero-shot on
    text = "\n".join(findings(res, s))
    assert "flaky" in text and "the ladder rule" in text and "Fitted target-only curve" in text
    assert "bad: zero-shot 12.05 [12.00, 12.10]; P not reached" in text and "Spearman" in text
    table = table_rows(res, s)
    assert table[0]["ladder: samples (reach and stay)"] == "2,000 [2,000, 2,000]"
    assert table[2]["zero-shot score [95 % CI]"] == "19.55 [19.50, 19.60]"


def test_score_bands_never_leave_the_seeds_range_or_the_possible_scores(tmp_path):
    """Two seeds far apart gave t-bands below −T (the 'PLV bands below zero' report); bootstrap bands cannot."""
    cfg = PLVConfig.from_dict({"ladder": [50, 100], "seeds": [0, 1, 2], "proxies": {"p": "proxy"},
                               "eval": {"episodes": 2, "seconds": 10.0}})
    runs = [{"arm": "target-only", "n": n, "seed": s, "off_policy": n, "on_policy": 0, "cost": float(n),
             "score": v} for n, vs in ((50, (-9.5, 9.9, 0.0)), (100, (9.0, 9.5, 9.8))) for s, v in enumerate(vs)]
    runs += [{**r, "arm": "p"} for r in runs if r["n"] == 50]
    res = PLVResult(cfg, runs, {"p": {"spec": "proxy", "zero_shot": -3.0, "in_proxy": 5.0,
                                      "zero_shot_by_seed": {"0": -10.0, "1": 1.0, "2": 0.0}}}, expert_score=9.0)
    s = summarize(res)
    for curve in s.curves.values():
        for c in curve:
            assert min(c.scores) <= c.low <= c.mean <= c.high <= max(c.scores)
    lo, hi = score_range(res)
    assert (lo, hi) == (-10.0, 10.0)
    from proxybench.usefulness.plv import mean_ci

    assert mean_ci([-9.5, 9.9, 0.0])[1] < lo  # the old Student-t band left the possible range
    assert figure_3_6(res, s, tmp_path / "f.png").stat().st_size > 0
    assert figure_plv(res, s, tmp_path / "g.png").stat().st_size > 0 and (tmp_path / "g.svg").exists()


def test_config_from_dict_rejects_unknown_keys_and_merges_nested():
    cfg = PLVConfig.from_dict({"ladder": [10, 20], "train": {"max_steps": 7}}, PLVConfig.quick())
    assert cfg.ladder == (10, 20) and cfg.train.max_steps == 7 and cfg.train.min_steps == 60
    assert cfg.model.width == 40
    with pytest.raises(ValueError, match="unknown PLV setting 'ladderr'"):
        PLVConfig.from_dict({"ladderr": [1]})
    assert PLVConfig(use_dagger=True, on_fraction=0.25).split(400) == DataCost(300, 100)


def test_plv_command_runs_a_tiny_experiment_and_writes_the_report(tmp_path):
    from proxybench.cli import learning  # noqa: F401 - registers the commands
    from proxybench.cli.app import app

    tiny = {"width": 32, "height": 24, "ladder": [40, 80], "seeds": [0, 1], "proxy_samples": 120,
            "proxies": {"pitch 35°": "proxy:camera_pitch=35"},
            "model": {"channels": [8, 8, 8, 8, 8], "hidden": [16]},
            "train": {"min_steps": 3, "max_steps": 3}, "pretrain": {"min_steps": 3, "max_steps": 3},
            "finetune": {"min_steps": 3, "max_steps": 3}, "collect": {"robots": 8, "episode_frames": 20},
            "eval": {"episodes": 2, "seconds": 1.0}, "use_dagger": True, "dagger": {"rounds": 1}}
    (tmp_path / "tiny.json").write_text(json.dumps(tiny))
    out = tmp_path / "plv"
    args = ["plv", "--quick", "--out", str(out), "--config", str(tmp_path / "tiny.json"), "--eta-on", "2"]
    res = CliRunner().invoke(app, args)  # the quick mode, shrunk further by the file
    assert res.exit_code == 0, res.output
    assert "Table 3.1" in res.output and "target only" in res.output and "bootstrap" in res.output
    for name in ("report.html", "fig3_6_learning_curves.png", "fig3_6_learning_curves.svg", "table3_1.csv",
                 "fig_plv_intervals.png", "plv_runs.csv", "plv.json"):
        assert (out / name).stat().st_size > 0, name
    blob = json.loads((out / "plv.json").read_text())
    assert blob["config"]["eta_on"] == 2.0 and {r["arm"] for r in blob["runs"]} >= {"target-only"}
    assert all(r["on_policy"] > 0 for r in blob["runs"])  # DAgger spent part of each rung on-policy
    assert blob["config"]["width"] == 32 and blob["config"]["replicates"] == 2000  # quick's, where not overridden
    assert set(blob["proxies"]["pitch 35°"]["zero_shot_by_seed"]) == {"0", "1"}  # one pre-training per seed
    assert blob["summary"]["intervals"]["method"] == "percentile bootstrap over seeds"  # the ladder rule's
    assert "saturating power law" in blob["summary"]["fitted"]["method"]
    assert "simulated stand-in" in (out / "report.html").read_text()
    again = CliRunner().invoke(app, args)
    assert again.exit_code == 0 and "units from the cache" in again.output  # resumed from the cache


def test_learn_commands_collect_train_finetune_and_evaluate(tmp_path):
    from proxybench.cli import learning  # noqa: F401 - registers the commands
    from proxybench.cli.app import app

    cli = CliRunner()
    small = ["--width", "32", "--height", "24", "--robots", "8"]
    for domain, name in (("proxy:camera_pitch=35", "p35"), ("reality", "target")):
        res = cli.invoke(app, ["learn", "dataset", domain, "--samples", "64", "--out", str(tmp_path / name), *small])
        assert res.exit_code == 0, res.output
        assert (tmp_path / name / "dataset.json").exists()
    res = cli.invoke(app, ["learn", "train", str(tmp_path / "p35"), "--out", str(tmp_path / "pre.pt"),
                           "--max-steps", "3"])
    assert res.exit_code == 0, res.output
    res = cli.invoke(app, ["learn", "train", str(tmp_path / "target"), "--init", str(tmp_path / "pre.pt"),
                           "--samples", "32", "--out", str(tmp_path / "ft.pt"), "--max-steps", "3"])
    assert res.exit_code == 0 and "wrote" in res.output, res.output
    assert "fine-tuning 3/3" in res.output  # off a terminal the bar prints plain lines (cli.progress)
    info = json.loads((tmp_path / "ft.json").read_text())
    assert info["init"].endswith("pre.pt") and info["data"]["samples"] == 32
    res = cli.invoke(app, ["learn", "evaluate", str(tmp_path / "ft.pt"), "--episodes", "2", "--seconds", "1"])
    assert res.exit_code == 0 and "lane score" in res.output and "simulated stand-in" in res.output, res.output
    res = cli.invoke(app, ["learn", "dataset", "mars", "--out", str(tmp_path / "x")])
    assert res.exit_code == 2 and "unknown domain" in res.output
