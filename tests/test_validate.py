"""The validation study end to end (quick, tiny): criteria before the first episode, picks judged on held-out
agents and fresh episodes against the nominal and oracle θ, a summary and a report; resumable; and its pure
scoring against hand-computed cases."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.usefulness.validation import (
    compare,
    minimum_detectable_effect,
    pick,
    quality,
    selection_scores,
    trajectory_error,
)


def _res(means: dict[str, float], n: int = 3) -> dict[str, np.ndarray]:
    return {a: np.array([[m, m]] * n) + np.arange(n)[:, None] * 0.01 for a, m in means.items()}


def test_settings_do_not_depend_on_how_proxybench_was_started():
    import sys

    from proxybench.experiments.validate.run import ValidateConfig, settings_for

    s = settings_for(ValidateConfig(), False).model_dump_json()
    assert sys.executable not in s and "{python} -m proxybench.protocol vision" in s  # filled in at run time


def test_quality_and_regret_measures_by_hand():
    target = _res({"a": 3.0, "b": 2.0, "c": 1.0})
    swapped = _res({"a": 2.0, "b": 3.0, "c": 1.0})
    q = quality(swapped, target, (True, True), k=2)
    assert q.prpv_norm == pytest.approx(2 / 6)  # one swapped pair of 3 agents
    assert q.top1_regret == pytest.approx(1.0)  # picks b (target 2.01) instead of a (3.01)
    assert q.topk_regret == pytest.approx(0.0)  # the top two are the same two agents
    assert quality(target, target, (True, True)).kendall_gap == pytest.approx(0.0)


def test_selection_methods_prefer_the_proxy_that_orders_like_the_target():
    target = _res({"a": 3.0, "b": 2.0, "c": 1.0, "d": 0.5})
    good, bad = _res({"a": 3.2, "b": 2.1, "c": 1.1, "d": 0.4}), _res({"a": 0.5, "b": 1.0, "c": 2.0, "d": 3.0})
    for method in ("prpv", "eps_prpv", "prob_prpv", "ppv", "pearson", "spearman", "kendall", "mmrv"):
        scores = selection_scores(method, [bad, good], target, (True, True), tolerances=[0.05, 0.05], n_boot=50)
        assert scores[1] < scores[0], method
    with pytest.raises(ValueError, match="unknown selection method"):
        selection_scores("nope", [good], target, (True,))


def test_ties_are_broken_at_random_and_counted():
    picks = {pick(np.array([1.0, 0.0, 0.0, 2.0]), np.random.default_rng(s))[0] for s in range(20)}
    assert picks == {1, 2} and pick(np.array([1.0, 0.0, 0.0]), np.random.default_rng(0))[1] == 2


def test_paired_comparison_and_minimum_detectable_effect():
    c = compare("a", "b", [0.0, 0.1, 0.0, 0.2, 0.1], [0.1, 0.3, 0.2, 0.2, 0.3])
    assert c.mean == pytest.approx(-0.14) and (c.wins, c.losses, c.ties) == (4, 0, 1)
    assert c.low <= c.mean <= c.high and c.p_wilcoxon < 0.1
    assert minimum_detectable_effect(40) == pytest.approx(0.40, abs=0.01)
    assert minimum_detectable_effect(10) > minimum_detectable_effect(40)


def test_trajectory_error_holds_a_replay_that_ended_early():
    recorded = np.column_stack([np.linspace(0, 2, 21), np.linspace(0, 2, 21), np.zeros(21)])
    assert trajectory_error(recorded, recorded) == 0.0
    short = recorded[:11]  # the replay stopped at x = 1 m
    assert trajectory_error(short, recorded) == pytest.approx(np.mean(np.clip(recorded[:, 1] - 1.0, 0, None)))


def test_the_quick_settings_of_every_family_are_valid():
    from proxybench.experiments.validate.run import FAMILIES, ValidateConfig, settings_for

    for family in FAMILIES:
        s = settings_for(ValidateConfig(family=family), True)  # the draws wider than the grids, known names
        assert s.quick and s.targets == 3 and len(s.agents) == 8 and s.seconds == 6.0, family


def _short_quick_episodes(monkeypatch, family: str, seconds: float = 2.0) -> None:
    """--quick with its episodes cut from 6 s to ``seconds``: what the end-to-end tests check does not depend on
    their length (the quick settings themselves: the test above), and the study runs a third as long."""
    from proxybench.experiments.validate.run import FAMILIES

    modes = FAMILIES[family]
    monkeypatch.setitem(FAMILIES, family, modes.model_copy(update={"quick": modes.quick.model_copy(
        update={"seconds": seconds})}))


@pytest.mark.slow
def test_validate_quick_end_to_end_writes_criteria_first_and_resumes(tmp_path, monkeypatch):
    _short_quick_episodes(monkeypatch, "heldout")
    out = tmp_path / "v"
    args = ["validate", "--quick", "--targets", "3", "--backend", "inline", "--out", str(out)]
    res = CliRunner().invoke(app, args, env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    criteria = json.loads((out / "criteria.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    assert "draw_seed_sha256" in criteria and "draw_seed" not in json.dumps(criteria["settings"])
    assert summary["criteria"]["scoring_unchanged"] and summary["targets"] == 3 and not summary["interim"]
    methods = summary["methods"]
    assert {"prpv", "nominal", "trajectory", "kendall"} <= set(methods)
    assert methods["nominal"]["prpv_norm"]["vs_nominal"]["mean"] == 0.0
    assert all(m["prpv_norm"]["mean_regret"] >= 0 for m in methods.values())  # nobody beats the oracle
    assert "primary" in summary and "tuning with prpv" in res.output.lower()
    assert (out / "report.html").exists() and (out / "targets.csv").exists()
    written = (out / "criteria.json").read_bytes()
    again = CliRunner().invoke(app, args, env={"COLUMNS": "200"})
    assert again.exit_code == 0, again.output
    assert (out / "criteria.json").read_bytes() == written  # resumed, criteria kept
    assert "0 episodes run now" in again.output
    # an interim look: only the finished targets, nothing run, the criteria untouched, no θ shown
    (out / "targets" / "002.json").unlink()
    look = CliRunner().invoke(app, [*args, "--interim"], env={"COLUMNS": "200"})
    assert look.exit_code == 0, look.output
    assert "INTERIM LOOK, 2 of 3 pre-registered targets" in look.output and "0 episodes run now" in look.output
    interim = json.loads((out / "summary.json").read_text())
    assert interim["interim"] and interim["targets"] == 2 and interim["truths"] == []
    assert not (out / "targets" / "002.json").exists()
    assert (out / "criteria.json").read_bytes() == written
    other = CliRunner().invoke(app, [*args[:3], "4", *args[4:], "--interim"], env={"COLUMNS": "200"})
    assert other.exit_code == 2 and "targets: the folder's criteria say 3, this run asks 4" in other.output
    none = CliRunner().invoke(app, ["validate", "--quick", "--interim", "--out", str(tmp_path / "none")])
    assert none.exit_code == 2 and "no study to look at" in none.output


@pytest.mark.slow
def test_validate_gym_family_quick_end_to_end(tmp_path, monkeypatch):
    """The gym family: gym-duckietown nodes with hidden θ (files of mode 600, only a hash in any report)."""
    import os
    import stat

    from proxybench.gym.environment import check_environment

    env = check_environment(render=False)
    if not env.ok:
        why = "gym-duckietown's environment is not ready (run `proxybench gym setup`): " + "; ".join(env.problems)
        if os.environ.get("PROXYBENCH_REQUIRE_GYM") == "1":
            pytest.fail(why)
        pytest.skip(why)
    _short_quick_episodes(monkeypatch, "gym")
    out = tmp_path / "g"
    res = CliRunner().invoke(app, ["validate", "--family", "gym", "--quick", "--targets", "2", "--backend", "inline",
                                   "--out", str(out)], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["family"] == "gym" and summary["targets"] == 2 and "prpv" in summary["methods"]
    secret = next((out / "secret" / "gym").glob("gym-*.yaml"))
    assert stat.S_IMODE(secret.stat().st_mode) == 0o600
    drawn = summary["truths"][0]["trim"]
    report = (out / "targets.csv").read_text() + (out / "criteria.json").read_text()
    assert f"{drawn}" not in report  # the hidden θ is only in the secret file and the revealed summary
