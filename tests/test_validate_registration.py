"""The validation study's pre-registration is tamper-evident (issue 35, item 1; issue 38's "validate resumes
without its secret"): criteria.json is never rewritten, a study without its secret stops, an interim look shows
no θ, and an edit of the look log, the criteria, a target's record, the scoring code or the order of criteria and
data is reported (the command exits non-zero). One quick study (3 targets, 4 agents of two families, episodes of
2 s) is run once; each test works on a copy of its folder."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from proxybench.cli import app

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("validate_registration")]

ENV = {"COLUMNS": "200", "NO_COLOR": "1"}
#: what is checked here does not depend on the pool's size: half of --quick's (two families, so every family split
#: has two agents a side), which halves the study's episodes
ARGS = ["validate", "--quick", "--targets", "3", "--agent", "pid", "--agent", "pid-twitchy", "--agent", "vision",
        "--agent", "vision-fast", "--backend", "inline"]


def _short_episodes(mp: pytest.MonkeyPatch) -> None:
    """--quick with 2-s episodes (what is checked here does not depend on their length)."""
    from proxybench.experiments.validate.run import FAMILIES

    modes = FAMILIES["heldout"]
    mp.setitem(FAMILIES, "heldout", modes.model_copy(update={"quick": modes.quick.model_copy(
        update={"seconds": 2.0})}))


def _validate(out: Path, *extra: str):
    return CliRunner().invoke(app, [*ARGS, "--out", str(out), *extra], env=ENV)


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("validate") / "study"
    with pytest.MonkeyPatch.context() as mp:
        _short_episodes(mp)
        res = _validate(out)
    assert res.exit_code == 0, res.output
    return out


@pytest.fixture
def study(finished: Path, tmp_path: Path, monkeypatch) -> Path:
    """A copy of the finished study (file times kept), to tamper with."""
    _short_episodes(monkeypatch)
    return Path(shutil.copytree(finished, tmp_path / "study"))


def _look_lines(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "looks.jsonl").read_text().splitlines()]


def _thetas(out: Path) -> list[str]:
    """The targets' hidden θ as a report would print them."""
    truths = json.loads((out / "summary.json").read_text())["truths"]
    assert truths and all(truths)
    return [f"{v}" for tr in truths for v in tr.values()]


def test_a_finished_study_resumes_with_its_settings_and_logs_every_target_and_look(study: Path):
    lines = _look_lines(study)
    assert [e["look"] for e in lines] == ["registered", "target", "target", "target", "final"]
    assert [e["target"] for e in lines if e["look"] == "target"] == [0, 1, 2]
    before = (study / "criteria.json").read_bytes()
    res = _validate(study)
    assert res.exit_code == 0, res.output
    assert "0 episodes run now" in res.output and "CHECK FAILED" not in res.output
    assert (study / "criteria.json").read_bytes() == before
    last = _look_lines(study)[-1]
    assert last["look"] == "final" and last["targets"] == 3 and len(last["summary_sha256"]) == 64
    assert json.loads((study / "summary.json").read_text())["criteria"]["problems"] == []


def test_other_settings_on_a_finished_study_are_refused_and_its_criteria_kept(study: Path):
    before = (study / "criteria.json").read_bytes()
    res = _validate(study, "--targets", "4")
    assert res.exit_code == 2
    assert "targets: the folder's criteria say 3, this run asks 4; use a new --out (or --new-study" in res.output
    for other in (["--seconds", "3"], ["--targets", "2", "--interim"], ["--tuning-share", "0.4", "--top-k", "2"]):
        res = _validate(study, *other)
        assert res.exit_code == 2 and "the folder's criteria say" in res.output, (other, res.output)
    assert "(and top_k)" in res.output  # every setting that differs is named
    res = _validate(study, "--multiplicity", "none")  # the registered Holm rule cannot be dropped afterwards
    assert res.exit_code == 2 and "primary: the folder's criteria say" in res.output
    assert (study / "criteria.json").read_bytes() == before


def test_new_study_moves_the_old_one_aside(study: Path):
    from proxybench.experiments.validate.config import ValidateConfig, settings_for
    from proxybench.experiments.validate.registration import open_study

    before = (study / "criteria.json").read_bytes()
    cfg = ValidateConfig(targets=2, new_study=True)
    criteria, _seed, notes = open_study(cfg, settings_for(cfg, True), study)  # registers; runs nothing
    old = next(study.glob("superseded-*"))
    assert (old / "criteria.json").read_bytes() == before and (old / "secret" / "draw_seed").exists()
    assert {p.name for p in old.iterdir()} >= {"looks.jsonl", "targets", "runs", "summary.json"}
    assert criteria["settings"]["targets"] == 2 and json.loads((study / "criteria.json").read_text()) == criteria
    assert [e["look"] for e in _look_lines(study)] == ["registered"] and not (study / "targets").exists()
    assert any("was moved to" in n for n in notes)


def test_a_study_without_its_secret_stops_and_reveals_nothing(study: Path):
    thetas = _thetas(study)
    before = {p: (study / p).read_bytes() for p in ("criteria.json", "summary.json", "report.html", "targets.csv")}
    log = (study / "looks.jsonl").read_bytes() if (study / "looks.jsonl").exists() else b""
    shutil.rmtree(study / "secret")
    for extra in (["--interim"], []):
        res = _validate(study, *extra)
        assert res.exit_code == 2, res.output
        assert "secret/draw_seed is missing" in res.output and "never drawn anew" in res.output
        assert not any(t in res.output for t in thetas)
        assert not (study / "secret").exists()  # no new draw
        assert {p: (study / p).read_bytes() for p in before} == before  # nothing rewritten, nothing revealed
        assert (study / "looks.jsonl").read_bytes() == log


def test_a_study_that_lost_its_criteria_is_refused(study: Path):
    (study / "criteria.json").unlink()
    res = _validate(study)
    assert res.exit_code == 2 and "but no criteria.json" in res.output, res.output
    assert not (study / "criteria.json").exists()


def test_an_interim_look_shows_no_theta(study: Path):
    thetas = _thetas(study)
    (study / "targets" / "002.json").unlink()
    res = _validate(study, "--interim")
    assert res.exit_code == 0, res.output
    assert "INTERIM LOOK, 2 of 3 pre-registered targets" in res.output
    summary = json.loads((study / "summary.json").read_text())
    assert summary["interim"] and summary["truths"] == []
    page = (study / "report.html").read_text()
    assert "Hidden until the final report" in page
    for text in (res.output, page, (study / "targets.csv").read_text(), json.dumps(summary)):
        assert not any(t in text for t in thetas)
    last = _look_lines(study)[-1]
    assert last["look"] == "interim" and last["targets"] == 2


@pytest.mark.parametrize("edit", ["middle", "last", "remove", "insert"])
def test_a_tampered_look_log_is_detected(study: Path, edit: str):
    path = study / "looks.jsonl"
    lines = path.read_text().splitlines()
    if edit == "middle":
        lines[2] = lines[2].replace('"targets": 2', '"targets": 7')
    elif edit == "last":
        lines[-1] = lines[-1].replace('"targets": 3', '"targets": 2').replace('"final"', '"interim"')
    elif edit == "remove":
        del lines[1]
    else:
        lines.insert(3, lines[2])
    path.write_text("\n".join(lines) + "\n")
    res = _validate(study)
    assert res.exit_code == 1, res.output
    assert "PRE-REGISTRATION CHECK FAILED: looks.jsonl line" in res.output and "the chain is broken" in res.output
    summary = json.loads((study / "summary.json").read_text())
    assert any("chain is broken" in p for p in summary["criteria"]["problems"])
    assert "PRE-REGISTRATION CHECK FAILED" in (study / "report.html").read_text()


def test_an_edited_criteria_file_is_detected(study: Path):
    path = study / "criteria.json"
    doc = json.loads(path.read_text())
    doc["minimum_detectable_effect"]["d_z"] = 0.01
    path.write_text(json.dumps(doc, indent=1))
    edited = path.read_bytes()
    res = _validate(study)
    assert res.exit_code == 1, res.output
    assert "minimum detectable effect (0.01) is not the one its settings give" in res.output
    assert "does not chain to criteria.json (the criteria were changed after they were registered)" in res.output
    assert path.read_bytes() == edited  # reported, not repaired
    doc["minimum_detectable_effect"]["d_z"] = json.loads(edited)["minimum_detectable_effect"]["d_z"]
    doc["written"] = "2020-01-01 00:00:00 +0000"  # the time alone
    path.write_text(json.dumps(doc, indent=1))
    res = _validate(study)
    assert res.exit_code == 1 and "the criteria were changed after they were registered" in res.output


def test_an_edited_target_record_is_detected(study: Path):
    path = study / "targets" / "000.json"
    rec = json.loads(path.read_text())
    rec["picks"]["prpv"]["index"] = (rec["picks"]["prpv"]["index"] + 1) % len(rec["candidates"])
    path.write_text(json.dumps(rec, indent=1))
    res = _validate(study, "--interim")
    assert res.exit_code == 1, res.output
    assert "targets/000.json is not the record looks.jsonl holds for target 0 (edited after it was scored): left " \
           "out of this look" in res.output
    assert "2 of 3 pre-registered targets" in res.output  # the edited record was not used


def test_criteria_newer_than_a_cached_episode_are_detected(study: Path):
    episode = next((study / "runs" / "episodes").glob("*.json"))
    os.utime(episode, (1.6e9, 1.6e9))
    res = _validate(study)
    assert res.exit_code == 1, res.output
    assert "is newer than cached episodes in runs/" in res.output


def test_changed_scoring_code_is_detected(study: Path, monkeypatch):
    from proxybench.experiments.validate import registration

    real = registration.scoring_hash
    monkeypatch.setattr(registration, "scoring_hash", lambda: {**real(), "usefulness/metrics.py": "0" * 64})
    res = _validate(study)
    assert res.exit_code == 1, res.output
    assert "the scoring code differs from the code criteria.json hashed (usefulness/metrics.py)" in res.output
    assert not json.loads((study / "summary.json").read_text())["criteria"]["scoring_unchanged"]


def test_the_scoring_hash_covers_every_module_scoring_touches(study: Path):
    from proxybench.experiments.validate.registration import scoring_files

    files = set(scoring_files())
    assert {"usefulness/validation.py", "usefulness/metrics.py", "usefulness/intervals.py",
            "usefulness/heldout_scoring.py", "tasks/metrics.py", "experiments/validate/scoring.py",
            "experiments/validate/measures.py"} <= files
    assert not files & {"experiments/validate/run.py", "experiments/validate/report.py"}
    assert set(json.loads((study / "criteria.json").read_text())["scoring_sha256"]) == files
