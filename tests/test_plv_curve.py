"""PLV from fitted learning curves: the fit, the continuous crossing point, the interval and its coverage check, and
argmin PRPV against argmax PLV on one target."""

from __future__ import annotations

import json
import runpy
import sys
from pathlib import Path

import numpy as np
import pytest

from proxybench.usefulness.plv_curve import Fit, crossing, curve_plv, expanded_level, fit
from proxybench.usefulness.plv_intervals import Curve

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
LADDER = np.array([50.0, 100, 250, 500, 1000, 2000, 4000, 9000])


def test_the_fit_recovers_a_known_curve_and_its_crossing_is_continuous():
    truth = Fit(28.0, 30.0, 1.0, 50.0)
    f = fit(LADDER, truth(LADDER)[None], np.ones(LADDER.size), 50.0).one()
    assert (f.a, f.b, f.c) == pytest.approx((28.0, 30.0, 1.0), rel=1e-3)
    p = 0.95 * float(truth(9000.0))
    n = f.crossing(p, 9000.0)
    assert 500 < n < 1000 and n != round(n, -1) and float(truth(n)) == pytest.approx(p, abs=1e-3)  # not a rung


def test_crossing_rules_rising_falling_and_never():
    a, b, c = np.array([28.0, 28.0, 25.0, 25.0]), np.array([30.0, -2.0, 20.0, -5.0]), np.ones(4)
    out = crossing(a, b, c, 50.0, np.full(4, 26.0), 9000.0)
    assert 0 < out[0] < 9000  # rising through P
    assert out[1] == 0.0  # falling from 30 to 28, always above P: zero-shot is enough
    assert out[2] == np.inf  # rising to 25 < P: never
    assert out[3] == np.inf  # falling from 30 to 25: above P at first, but it does not stay


def test_interval_is_paired_refits_and_says_not_reached():
    rng = np.random.default_rng(0)
    seeds = tuple(range(15))
    t = Fit(28.0, 30.0, 1.0, 50.0)(LADDER)[None] + rng.normal(0, 0.5, (15, LADDER.size))
    costs = np.concatenate([[0.0], LADDER[:4]])
    good = Fit(28.5, 4.5, 1.0, 50.0)(costs)[None] + rng.normal(0, 0.5, (15, costs.size))
    bad = Fit(24.0, 20.0, 1.0, 50.0)(costs)[None] + rng.normal(0, 0.5, (15, costs.size))
    res = curve_plv(Curve(LADDER, seeds, t, True), {"good": Curve(costs, seeds, good, False),
                                                   "bad": Curve(costs, seeds, bad, False)}, 0.05, replicates=400)
    iv = res.plv["good"]
    assert iv.low < iv.estimate < iv.high and res.reached["good"] == 1.0
    assert res.target_needed.low < res.target_needed.estimate < res.target_needed.high
    assert res.plv["bad"].estimate is None and res.plv["bad"].high is None and res.reached["bad"] == 0.0
    assert set(json.loads(json.dumps(res.to_dict()))) >= {"fits", "plv", "lack_of_fit_p", "method"}
    assert expanded_level(0.95, 15) > 0.95 > expanded_level(0.95, 1) - 1e-12


def test_coverage_benchmark_quick(capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["bench_plv_coverage.py", "--quick"])
    runpy.run_path(str(BENCH / "bench_plv_coverage.py"), run_name="__main__")
    rows = [r for r in capsys.readouterr().out.splitlines() if r.startswith("| ") and "---" not in r][1:]
    assert len(rows) == 8
    for r in rows:
        cells = [c.strip() for c in r.split("|")[1:-1]]
        assert 0.0 <= float(cells[3].split()[0]) <= 1.0 and 0.0 <= float(cells[5].split()[0]) <= 1.0, r


def test_plv_vs_prpv_reports_both_picks(tmp_path):
    pytest.importorskip("torch")
    import yaml
    from typer.testing import CliRunner

    from proxybench.cli import learning  # noqa: F401 - registers the command
    from proxybench.cli.app import app

    tiny = {"width": 32, "height": 24, "ladder": [40, 80], "seeds": [0, 1], "proxy_samples": 80,
            "model": {"channels": [8, 8, 8, 8, 8], "hidden": [16]}, "train": {"min_steps": 2, "max_steps": 2},
            "pretrain": {"min_steps": 2, "max_steps": 2}, "finetune": {"min_steps": 2, "max_steps": 2},
            "collect": {"robots": 8, "episode_frames": 20}, "eval": {"episodes": 2, "seconds": 1.0},
            "replicates": 200}
    exp = {"agents": ["straight", "pid", "pure-pursuit"], "episodes": 2, "seconds": 2.0, "image_size": [32, 24],
           "n_boot": 50, "plv": tiny}
    (tmp_path / "exp.yaml").write_text(yaml.safe_dump(exp))
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["plv-vs-prpv", "--quick", "--config", str(tmp_path / "exp.yaml"), "--sweep",
                                   "camera_pitch=12,19.15", "--out", str(out), "--backend", "inline"])
    assert res.exit_code == 0, res.output
    assert "argmin PRPV" in res.output and "argmax PLV" in res.output
    data = json.loads((out / "choice.json").read_text())
    assert [c["label"] for c in data["candidates"]] == ["camera_pitch=12", "nominal"]
    assert data["prpv_pick"] in data["prpv_tied"] and "verdict" in data and (out / "choice.png").exists()
    assert all("plv_label" in c and "delta" in c for c in data["candidates"])
    bad = CliRunner().invoke(app, ["plv-vs-prpv", "--target", str(tmp_path), "--out", str(out)])
    assert bad.exit_code == 2 and "live one" in bad.output


def _finished_plv_run(folder):
    """A finished `proxybench plv` report: the study's canned result (pitch-19 = the nominal, pitch-35), written by
    the PLV report (nothing trains)."""
    from proxybench.experiments.plv.study import PLVStudy

    study = PLVStudy()
    study.write_report(study.example(), folder)
    return folder


def test_plv_vs_prpv_takes_plv_from_a_finished_run(tmp_path):
    """The 15-seed PLV run need not be trained again: plv-vs-prpv replays the agents on that run's proxies for PRPV
    and reads each proxy's PLV, interval and all, from the run."""
    import yaml
    from typer.testing import CliRunner

    from proxybench.cli import learning  # noqa: F401 - registers the command
    from proxybench.cli.app import app
    from proxybench.experiments.plv.measures import summarize
    from proxybench.experiments.plv.study import PLVStudy

    run = _finished_plv_run(tmp_path / "plv")
    exp = {"agents": ["straight", "pid", "pure-pursuit"], "episodes": 2, "seconds": 2.0, "image_size": [32, 24],
           "n_boot": 50, "plv": {"from_run": str(run)}}
    (tmp_path / "exp.yaml").write_text(yaml.safe_dump(exp))
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["plv-vs-prpv", "--config", str(tmp_path / "exp.yaml"), "--out", str(out),
                                   "--backend", "inline"])
    assert res.exit_code == 0, res.output
    data = json.loads((out / "choice.json").read_text())
    assert [c["label"] for c in data["candidates"]] == ["nominal", "camera_pitch=35"]
    rows = {r.proxy: r for r in summarize(PLVStudy().example()).rows}
    by = {c["label"]: c for c in data["candidates"]}
    assert by["nominal"]["plv"] == pytest.approx(rows["pitch-19"].plv)
    assert by["camera_pitch=35"]["plv_label"] == (rows["pitch-35"].plv_ci or rows["pitch-35"].plv_label)
    assert data["plv_seeds"] == 2 and data["extra"]["plv_from_run"] == str(run)
    assert not (out / "plv").exists()  # nothing was trained


def test_plv_vs_prpv_from_a_run_refuses_a_candidate_the_run_lacks(tmp_path):
    from typer.testing import CliRunner

    from proxybench.cli import learning  # noqa: F401 - registers the command
    from proxybench.cli.app import app

    run = _finished_plv_run(tmp_path / "plv")
    res = CliRunner().invoke(app, ["plv-vs-prpv", "--plv", f"from_run={run}", "--sweep", "camera_pitch=12",
                                   "--agent", "straight", "--agent", "pid", "--episodes", "1", "--seconds", "1",
                                   "--out", str(tmp_path / "out"), "--backend", "inline"])
    assert res.exit_code == 2
    assert "has no proxy with θ camera_pitch=12" in res.output and "pitch-35 (proxy:camera_pitch=35)" in res.output
    res = CliRunner().invoke(app, ["plv-vs-prpv", "--plv", f"from_run={run}", "--plv", "seeds=[0]",
                                   "--out", str(tmp_path / "out2")])
    assert res.exit_code == 2 and "plv.seeds: with plv.from_run the PLV settings are the run's" in res.output
