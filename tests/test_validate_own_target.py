"""`proxybench validate --target …` (issue 35 item 5): the study's design on one target — every agent run once,
every candidate replaying it, then many seeded A/B agent × E1/E2 episode splits — on a recording of the reality
model made here; the files it writes, the answer reproduced from the seed, and the errors a user sees."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.experiments.config import ConfigError
from proxybench.experiments.validate import own_target
from proxybench.experiments.validate.config import ValidateConfig
from proxybench.experiments.validate.own_target import OwnTargetSummary, run_own_target, write_own_target_report
from proxybench.runner.jobs import AgentSpec
from proxybench.targets import RealityTarget
from proxybench.targets.record import record_target

runner = CliRunner()
SIX = ("straight", "pid", "pid-fast", "pid-twitchy", "pure-pursuit", "bang-bang")
#: small and quick: 3 candidates (the nominal trim 0 among them), 2 + 2 episodes of the recording's 4, small images
SMALL = {"episodes_tune": 2, "episodes_eval": 2, "grid": {"trim": (-0.2, 0.0, 0.2)}, "image_size": (40, 30),
         "methods": ("prpv", "eps_prpv", "trajectory", "nominal")}


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rec = tmp_path_factory.mktemp("own") / "rec"
    record_target(rec, RealityTarget(), [AgentSpec(a) for a in SIX], episodes=4, seconds=2.0, image_size=(40, 30))
    return rec


def _run(rec, out, **kw):
    cfg = ValidateConfig(target=str(rec), **{**SMALL, **kw})
    return run_own_target(cfg, out, splits=24, boot=8, boot_splits=4)


def test_the_study_on_a_recording_writes_its_files_and_its_answer_comes_back_from_the_seed(recording, tmp_path,
                                                                                            monkeypatch):
    res = _run(recording, tmp_path / "a")
    files = write_own_target_report(res, tmp_path / "a")
    assert {p.name for p in files} == {"own_target.json", "splits.csv", "own_target_splits.png", "report.html"}
    summary = OwnTargetSummary.model_validate_json((tmp_path / "a" / "own_target.json").read_text())
    s = summary.settings
    assert s.agents == SIX and s.episodes == (0, 1, 2, 3) and s.tuning_agents == 3 and len(s.candidates) == 3
    assert s.candidates[s.nominal_index] == {"trim": 0.0}
    assert summary.simulated is True
    assert s.target_kind == summary.target_kind == "recorded (proxybench's reality model)"
    assert summary.answer.startswith("SIMULATED TARGET (recorded") and "over 24 splits" in summary.answer
    assert set(summary.methods) == {"prpv", "eps_prpv", "trajectory", "nominal"}
    for a in summary.methods.values():
        assert a.splits == 24 and abs(a.helped + a.hurt + a.tied - 1.0) < 1e-9
        assert a.range_low <= a.median <= a.range_high and a.median_low <= a.median_high
    nominal = summary.methods["nominal"]  # the nominal θ against itself: always tied
    assert nominal.tied == 1.0 and nominal.median == nominal.median_low == nominal.median_high == 0.0
    assert summary.episodes_run == 6 * 4 * 3  # every candidate replayed every recorded episode, nothing else ran
    rows = (tmp_path / "a" / "splits.csv").read_text().splitlines()
    assert rows[0].startswith("split,method,pick,pick_trim,ties") and len(rows) == 1 + 24 * 4
    for r in res.rows:  # A and B disjoint, E1 and E2 disjoint, of the sizes asked
        assert len(r.tuning_agents) == 3 and len(set(r.e1) | set(r.e2)) == 4 and len(r.e1) == 2
    page = (tmp_path / "a" / "report.html").read_text()
    assert "SIMULATED TARGET" in page and "data:image/png;base64" in page and "settings.json" in page
    settings = json.loads((tmp_path / "a" / "settings.json").read_text())
    assert settings["settings"]["seed"] == 0 and settings["settings"]["splits"] == 24

    again = _run(recording, tmp_path / "b")  # another folder, so the candidates replay again: the same answer
    assert again.rows == res.rows and again.summary.methods == res.summary.methods
    other = _run(recording, tmp_path / "c", seed=1)  # another seed: other splits
    assert [r.tuning_agents for r in other.rows] != [r.tuning_agents for r in res.rows]

    before = (tmp_path / "a" / "settings.json").read_bytes()  # other settings on the folder: refused, file untouched
    with pytest.raises(ConfigError, match=r"^seed: the folder's settings.json says 0, this run asks 1"):
        _run(recording, tmp_path / "a", seed=1)
    assert (tmp_path / "a" / "settings.json").read_bytes() == before
    resumed = _run(recording, tmp_path / "a")  # the same settings resume from the cache: nothing runs
    assert resumed.summary.episodes_run == 0 and resumed.rows == res.rows
    assert resumed.summary.scoring_unchanged
    monkeypatch.setattr(own_target, "_scoring_hash", lambda: "other code")  # changed code: said, not refused
    changed = _run(recording, tmp_path / "a")
    assert not changed.summary.scoring_unchanged and changed.rows == res.rows
    assert (tmp_path / "a" / "settings.json").read_bytes() == before


def test_the_splits_are_the_study_design_on_a_table_where_tuning_must_help():
    """A table built by hand: the nominal candidate orders every agent backwards, the other exactly: every split's
    PRPV pick is the right one, and tuned − nominal is −1 (all pairs wrong → none wrong) in every split."""
    k, e = 6, 4
    target = np.repeat(np.arange(k, dtype=float)[:, None, None], e, 1) + np.linspace(0, 0.1, e)[None, :, None]
    good, bad = target.copy(), target[::-1].copy()
    tab = own_target.Tables(tuple(f"a{i}" for i in range(k)), tuple(range(e)), target, np.stack([bad, good]),
                            np.full((2, k, e), np.nan))
    s = own_target.OwnTargetSettings(
        target="hand", target_kind="none", agents=tab.agents, tuning_agents=3, episodes=tab.episodes,
        episodes_tune=2, episodes_eval=2, seconds=1.0, map="loop_3x3", candidates=[{"trim": 0.0}, {"trim": 0.2}],
        nominal_index=0, metrics=("survival_time",), tolerances={"survival_time": 0.0}, methods=("prpv", "nominal"),
        top_k=3, n_boot=10, image_size=(40, 30), seed=3, splits=10, boot=5, boot_splits=3, range_percent=(5.0, 95.0),
        scoring_sha256="")
    rows, boots = own_target.evaluate_splits(tab, s)
    answers = own_target.summarize_splits(rows, boots, s)
    assert answers["prpv"].helped == 1.0 and answers["prpv"].median == -1.0
    assert answers["prpv"].median_low == answers["prpv"].median_high == -1.0
    assert answers["nominal"].tied == 1.0


def test_validate_target_on_the_command_line_writes_the_report(recording, tmp_path, monkeypatch):
    monkeypatch.setattr(own_target, "SPLITS", 12)
    monkeypatch.setattr(own_target, "BOOT", 4)
    monkeypatch.setattr(own_target, "BOOT_SPLITS", 3)
    cfg = tmp_path / "small.yaml"
    cfg.write_text("grid: {trim: [-0.2, 0.0, 0.2]}\n")
    res = runner.invoke(app, ["validate", "--backend", "inline", "--target", str(recording), "--config", str(cfg),
                              "--episodes-tune", "2", "--episodes-eval", "2", "--image-size", "40x30",
                              "--method", "prpv", "--method", "nominal", "--out", str(tmp_path / "o")])
    assert res.exit_code == 0, res.output
    assert "SIMULATED TARGET (recorded" in res.output and "over 12 splits" in res.output
    assert all((tmp_path / "o" / n).is_file() for n in ("settings.json", "own_target.json", "splits.csv",
                                                        "report.html"))


@pytest.mark.parametrize(("args", "says"), [
    (["--agent", "straight", "--agent", "pid", "--agent", "pid-fast", "--agent", "vision"],
     "agents: 'vision' not in the recording at"),
    (["--agent", "straight", "--agent", "pid", "--agent", "pid-fast"],
     "agents (--agent): Tuple should have at least 4"),
    (["--episodes-tune", "3", "--episodes-eval", "3"], "episodes_tune + episodes_eval: 6 episodes per agent asked, "
                                                       "the recording at"),
    (["--targets", "5"], "targets: the study on your own target has one target"),
])
def test_bad_input_is_a_one_line_error_before_anything_runs(recording, tmp_path, args, says):
    out = tmp_path / "o"
    res = runner.invoke(app, ["validate", "--backend", "inline", "--target", str(recording), "--out", str(out), *args])
    assert res.exit_code != 0
    assert says in res.output and "Traceback" not in res.output, res.output
    assert not (out / "settings.json").exists() and not (out / "runs").exists()  # nothing written, nothing ran


def test_a_recording_of_three_agents_is_refused(tmp_path):
    rec = tmp_path / "rec3"
    record_target(rec, RealityTarget(), [AgentSpec(a) for a in SIX[:3]], episodes=1, seconds=1.0, image_size=(40, 30))
    with pytest.raises(ConfigError, match=r"^agents: the study on one target needs at least 4 \(2 to tune, 2 to "
                                          r"judge\), got 3 \(straight, pid, pid-fast\)$"):
        run_own_target(ValidateConfig(target=str(rec), **SMALL), tmp_path / "o")


@pytest.mark.parametrize(("kind", "details", "words"), [
    ("recorded", {"source": "real"}, "recorded (real robots, as its manifest declares)"),
    ("recorded", {"source": "simulation"}, "recorded (another simulator)"),
    ("reality-model", {}, "reality model (proxybench's simulated stand-in for a Duckiebot)"),
    ("robot", {"command": "c", "kind": ""}, "robot node"),
    ("robot", {"command": "c", "kind": "simulation"}, "robot node, a simulator by its own word"),
    ("robot", {"command": "c", "kind": "simulation", "simulator": {"name": "gym"}},
     "robot node, simulated by another simulator"),
    ("robot", {"address": "a", "link": "dtps"}, "DTPS robot"),
])
def test_the_answer_names_the_targets_kind(kind, details, words):
    from proxybench.domain.kinds import DomainKind
    from proxybench.targets.base import TargetInfo

    assert own_target.kind_words(TargetInfo(DomainKind(kind), None, "x", "y", details)) == words


def test_the_calibration_competes_on_a_live_target_and_prpv_is_compared_with_it_per_split(tmp_path, monkeypatch):
    """A live target (the reality model with a hidden trim 0.12): the calibration drives it twice (straight, step),
    reads its trim off the drives, and its θ — off the grid — is judged on every split's held-out half beside
    PRPV's pick; PRPV − calibration is reported paired per split."""
    monkeypatch.setattr(own_target, "_open", lambda cfg, n: RealityTarget({"trim": 0.12}))
    cfg = ValidateConfig(target="reality", agents=("straight", "pid", "pure-pursuit", "bang-bang"), seconds=2.0,
                         **{**SMALL, "methods": ("prpv", "calibration", "nominal")})
    res = run_own_target(cfg, tmp_path, splits=12, boot=4, boot_splits=3)
    s = res.summary
    assert s.calibration is not None and abs(s.calibration.estimate["trim"] - 0.12) < 0.03
    assert s.calibration.theta == {"trim": pytest.approx(s.calibration.estimate["trim"])}  # inside the grid's range
    assert s.episodes_run == 4 * 4 + 2 * 2 + (3 + 1) * 4 * 4  # target, the drives, the grid and the calibrated θ
    calib_rows = [r for r in res.rows if r.method == "calibration"]
    assert len(calib_rows) == 12 and {r.pick for r in calib_rows} == {3}  # the candidate after the grid
    assert set(s.versus) == {"prpv-calibration"} and s.versus["prpv-calibration"].splits == 12
    by = {(r.split, r.method): r.quality_pick for r in res.rows}
    d = [by[(i, "prpv")] - by[(i, "calibration")] for i in range(12)]
    assert s.versus["prpv-calibration"].median == pytest.approx(float(np.median(d)))
    assert "prpv − calibration: median" in s.answer
    write_own_target_report(res, tmp_path)
    assert "trim=" in (tmp_path / "report.html").read_text() and "(paired)" in (tmp_path / "report.html").read_text()
    assert ",3,0.12" in (tmp_path / "splits.csv").read_text().replace(
        f"{s.calibration.theta['trim']}", "0.12")  # the calibrated θ is named in its rows


def test_the_calibration_on_a_recording_without_its_drives_says_why_and_the_rest_answers(recording, tmp_path):
    res = _run(recording, tmp_path, methods=("prpv", "calibration", "nominal"))
    s = res.summary
    assert s.calibration is not None and s.calibration.theta is None and "recording" in s.calibration.reason
    assert "calibration" not in s.methods and not s.versus and any(n.startswith("calibration:") for n in s.notes)
    assert set(s.methods) == {"prpv", "nominal"}


def test_trajectory_fit_is_refused_on_one_target_with_the_methods_that_run(recording, tmp_path):
    with pytest.raises(ConfigError, match="methods: trajectory_fit refits θ on every split"):
        _run(recording, tmp_path, methods=("prpv", "trajectory_fit", "nominal"))
