"""`proxybench optimize --objective plv`: argmax PLV over proxies (thesis eq. 3.6.2) from the command line, with
a tiny learning setting; what PLV cannot do, or a missing PyTorch, is a clear error."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from proxybench.cli import app

runner = CliRunner()
ENV = {"COLUMNS": "200"}
#: seconds, not minutes: 32×24 frames, two rungs, two seeds, two gradient steps per training run
TINY = """
plv:
  width: 32
  height: 24
  ladder: [40, 80]
  seeds: [0, 1]
  proxy_samples: 80
  model: {channels: [8, 8, 8, 8, 8], hidden: [16]}
  train: {min_steps: 2, max_steps: 2}
  pretrain: {min_steps: 2, max_steps: 2}
  finetune: {min_steps: 2, max_steps: 2}
  collect: {robots: 8, episode_frames: 20}
  eval: {episodes: 2, seconds: 1.0}
  replicates: 200
"""


@pytest.fixture
def exp(tmp_path: Path) -> Path:
    path = tmp_path / "exp.yaml"
    path.write_text(TINY)
    return path


def test_optimize_plv_through_the_cli(tmp_path: Path, exp: Path) -> None:
    pytest.importorskip("torch")
    out = tmp_path / "out"
    args = ["optimize", "--objective", "plv", "--config", str(exp), "--param", "camera_pitch=15:23", "--trials", "2",
            "--sampler", "random", "--storage", str(tmp_path / "study.db"), "--agent", "pid", "--out", str(out)]
    res = runner.invoke(app, args, env=ENV)
    assert res.exit_code == 0, res.output
    assert "SIMULATED stand-in" in res.output and "PLV [95% CI]" in res.output and "not used by --objective plv" \
        in res.output and "agents" in res.output
    assert "the target's known value 19.15 (not used by the search)" in res.output
    trials = json.loads((out / "trials.json").read_text())
    assert [t["number"] for t in trials] == [0, 1] and all("plv_ci" in t and "plv_status" in t for t in trials)
    pitches = [json.loads(t["proposal"])["camera_pitch"] for t in trials]
    assert all(15.0 <= p <= 23.0 for p in pitches)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["objective"] == "plv" and summary["target"].startswith("reality model (a simulated")
    assert isinstance(summary["separated"], bool) and summary["plv_config"]["ladder"] == [40, 80]
    assert summary["best"]["number"] in (0, 1) and summary["truth"] == {"camera_pitch": 19.15}
    assert (out / "plv_search.png").stat().st_size > 0 and (out / "plv_search.svg").exists()
    best = summary["best"]
    if best["plv"] is not None:  # the table marks the best, and says whether its interval stands apart
        assert ("best, stands apart" if summary["separated"] else "best (not separated)") in res.output
        assert f"PLV {best['plv_ci']}" in res.output  # with its interval, as printed (not eaten as markup)
    again = runner.invoke(app, args, env=ENV)  # the stored study has its trials: nothing is trained again
    assert again.exit_code == 0 and json.loads((out / "trials.json").read_text()) == trials
    fam = runner.invoke(app, [*args[:-1], str(tmp_path / "fam"), "--family", "--trials", "1",
                              "--study-name", "fam"], env=ENV)
    assert fam.exit_code == 0, fam.output
    (t,) = json.loads((tmp_path / "fam" / "trials.json").read_text())
    lo, hi = json.loads(t["proposal"])["camera_pitch"]["uniform"]
    assert 15.0 <= lo <= hi <= 23.0 and "U[" in fam.output


@pytest.mark.parametrize(("args", "says"), [
    (["--target", "robot:x"], "target: the PLV objective trains on target samples"),
    (["--target-param", "trim=0.1"], "target_params: the PLV objective's target is the reality model"),
    (["--sampler", "gp"], "search.sampler: the PLV search takes tpe or random"),
])
def test_what_plv_cannot_do_is_an_error_naming_the_field(tmp_path: Path, exp: Path, args, says) -> None:
    pytest.importorskip("torch")
    res = runner.invoke(app, ["optimize", "--objective", "plv", "--config", str(exp), *args, "--out",
                              str(tmp_path / "out")], env=ENV)
    assert res.exit_code == 2 and says in res.output, res.output
    assert not (tmp_path / "out" / "trials.json").exists()


def test_bad_plv_settings_and_family_without_plv(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    exp = tmp_path / "exp.yaml"
    exp.write_text("plv: {ladderr: [10, 20]}\n")
    res = runner.invoke(app, ["optimize", "--objective", "plv", "--config", str(exp), "--out", str(tmp_path / "o")],
                        env=ENV)
    assert res.exit_code == 2 and "plv: unknown PLV setting 'ladderr'" in res.output, res.output
    res = runner.invoke(app, ["optimize", "--family", "--out", str(tmp_path / "o")], env=ENV)
    assert res.exit_code == 2 and "family: searching families p(θ) needs objective plv" in res.output, res.output


def test_without_pytorch_the_plv_objective_says_which_extra(tmp_path: Path, monkeypatch) -> None:
    import proxybench.experiments.optimize.plv_search as optimize_plv

    monkeypatch.setattr(optimize_plv, "torch_available", lambda: False)
    res = runner.invoke(app, ["optimize", "--objective", "plv", "--out", str(tmp_path / "o")], env=ENV)
    assert res.exit_code == 2 and "needs PyTorch" in res.output and "proxybench[learning]" in res.output


def test_the_prpv_optimiser_refuses_the_plv_objective(tmp_path: Path) -> None:
    from proxybench.experiments.config import ExperimentConfig, SearchConfig
    from proxybench.experiments.optimize.run import optimize_proxy

    with pytest.raises(ValueError, match="run_plv_search"):
        optimize_proxy(ExperimentConfig(search=SearchConfig(objective="plv")), tmp_path / "runs")
