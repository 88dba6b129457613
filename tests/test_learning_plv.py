"""PLV arithmetic, the summary of a PLV run (including "not reached"), and a tiny end-to-end run via the CLI."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from proxybench.learning.experiment import PLVConfig, PLVResult
from proxybench.learning.report import findings, summarize
from proxybench.learning.value import DataCost, first_reaching, mean_ci, plv, reference_score


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


def test_summary_of_a_run_where_one_proxy_never_reaches_the_target_score():
    cfg = PLVConfig(width=32, height=24, ladder=(250, 500, 1000, 2000), seeds=(0, 1),
                    proxies={"good": "proxy", "bad": "proxy:camera_pitch=35", "free": "randomized"})
    runs = (_runs("target-only", [(250, 5.0), (500, 10.0), (1000, 19.0), (2000, 20.0)])
            + _runs("good", [(250, 19.8)]) + _runs("bad", [(250, 2.0), (500, 3.0), (1000, 4.0), (2000, 5.0)]))
    proxies = {"good": {"spec": "proxy", "zero_shot": 8.0, "in_proxy": 25.0},
               "bad": {"spec": "proxy:camera_pitch=35", "zero_shot": 12.0, "in_proxy": 24.0},
               "free": {"spec": "randomized", "zero_shot": 19.5, "in_proxy": 22.0}}
    s = summarize(PLVResult(cfg, runs, proxies, expert_score=21.0))
    assert s.reference == pytest.approx(0.95 * 20.05) and s.converged_ok
    assert s.target_needed == DataCost(1000)
    rows = {r["proxy"]: r for r in s.rows}
    assert rows["good"]["plv"] == 750 and rows["good"]["reduction_label"] == "75 %"
    assert rows["bad"]["plv"] is None and rows["bad"]["plv_label"] == "not reached"
    assert rows["bad"]["needed_label"] == "not reached" and rows["bad"]["tried_up_to"] == 2000
    assert rows["free"]["needed"] == 0 and rows["free"]["reduction_label"] == "100 %"  # zero-shot already there
    text = "\n".join(findings(PLVResult(cfg, runs, proxies, expert_score=21.0)))
    assert "bad: zero-shot 12.00; P not reached with up to 2,000" in text and "Spearman" in text


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

    tiny = {"width": 32, "height": 24, "ladder": [40, 80], "seeds": [0], "proxy_samples": 120,
            "proxies": {"pitch 35°": "proxy:camera_pitch=35"},
            "model": {"channels": [8, 8, 8, 8, 8], "hidden": [16]},
            "train": {"min_steps": 3, "max_steps": 3}, "pretrain": {"min_steps": 3, "max_steps": 3},
            "finetune": {"min_steps": 3, "max_steps": 3}, "collect": {"robots": 8, "episode_frames": 20},
            "eval": {"episodes": 2, "seconds": 1.0}, "use_dagger": True, "dagger": {"rounds": 1}}
    (tmp_path / "tiny.json").write_text(json.dumps(tiny))
    out = tmp_path / "plv"
    res = CliRunner().invoke(app, ["plv", "--out", str(out), "--config", str(tmp_path / "tiny.json"), "--eta-on", "2"])
    assert res.exit_code == 0, res.output
    assert "Table 3.1" in res.output and "target only" in res.output
    for name in ("report.html", "fig3_6_learning_curves.png", "fig3_6_learning_curves.svg", "table3_1.csv",
                 "plv_runs.csv", "plv.json"):
        assert (out / name).stat().st_size > 0, name
    blob = json.loads((out / "plv.json").read_text())
    assert blob["config"]["eta_on"] == 2.0 and {r["arm"] for r in blob["runs"]} >= {"target-only"}
    assert all(r["on_policy"] > 0 for r in blob["runs"])  # DAgger spent part of each rung on-policy
    assert "simulated stand-in" in (out / "report.html").read_text()
    again = CliRunner().invoke(app, ["plv", "--out", str(out), "--config", str(tmp_path / "tiny.json"),
                                     "--eta-on", "2"])
    assert again.exit_code == 0  # resumed from the cache


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
    assert res.exit_code == 0 and "fine-tuning" not in res.output, res.output  # the bar is transient
    info = json.loads((tmp_path / "ft.json").read_text())
    assert info["init"].endswith("pre.pt") and info["data"]["samples"] == 32
    res = cli.invoke(app, ["learn", "evaluate", str(tmp_path / "ft.pt"), "--episodes", "2", "--seconds", "1"])
    assert res.exit_code == 0 and "lane score" in res.output and "simulated stand-in" in res.output, res.output
    res = cli.invoke(app, ["learn", "dataset", "mars", "--out", str(tmp_path / "x")])
    assert res.exit_code == 2 and "unknown domain" in res.output
