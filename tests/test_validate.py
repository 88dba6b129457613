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


def test_the_margin_test_and_the_size_it_needs():
    from proxybench.usefulness.validation import margin_test, targets_needed

    assert targets_needed(0.02, 0.10) == 156  # the review's estimate: ~155
    assert targets_needed(0.04, 0.10) < targets_needed(0.02, 0.10) < targets_needed(0.02, 0.15)
    rng = np.random.default_rng(0)
    close = margin_test("prpv", "cal", rng.normal(0.1, 0.03, 200), np.full(200, 0.1), 0.02)
    assert close.noninferior and not close.superior and close.upper < 0.02
    better = margin_test("prpv", "cal", np.full(50, 0.05) + rng.normal(0, 0.01, 50), np.full(50, 0.1), 0.02)
    assert better.superior and better.noninferior
    worse = margin_test("prpv", "cal", np.full(50, 0.2), np.full(50, 0.1) + rng.normal(0, 0.01, 50), 0.02)
    assert not worse.noninferior and worse.mean > 0.09
    same = margin_test("prpv", "cal", [0.1, 0.2], [0.1, 0.2], 0.02, fallback_sd=0.1)
    assert same.upper > 0.02 and not same.noninferior  # no spread: the assumed SD, not a zero-width interval
    missing = margin_test("prpv", "cal", [0.1, 0.2, 0.3], [np.nan, 0.2, 0.3], 0.02)
    assert missing.n == 2


def test_holm_holds_four_tests_to_one_alpha_together():
    """One pass in four at α each is what chance gives: under Holm a comparison just inside the margin at α
    is not shown, a clear one is, and nothing after the first failure in p order is shown."""
    from proxybench.usefulness.validation import holm, margin_test

    rng = np.random.default_rng(1)
    base = np.full(20, 0.1)
    clear = base + rng.normal(-0.03, 0.02, 20)  # PRPV better by 0.03: non-inferior and superior even at α/4
    edge = base + rng.normal(0.0, 0.05, 20)  # noise about zero
    edge = edge - (margin_test("a", "b", edge, base, 0.02).upper - 0.019)  # its α bound just under the margin
    worse = base + rng.normal(0.06, 0.02, 20)
    values = [(clear, base), (edge, base), (worse, base), (worse + 0.01, base)]
    plain = [margin_test("prpv", "cal", a, b, 0.02) for a, b in values]
    assert [m.noninferior for m in plain] == [True, True, False, False]
    held = holm(plain, values, 0.05)
    assert [m.noninferior for m in held] == [True, False, False, False]
    assert held[0].superior and held[0].alpha == pytest.approx(0.05 / 4)  # the smallest p first, at α/4
    assert held[1].alpha == pytest.approx(0.05 / 3) and held[1].upper > plain[1].upper  # a stricter bound
    assert {m.alpha for m in held[2:]} == {0.05 / 2, 0.05}
    # a test whose own bound is under the margin is still not shown after an earlier one failed (step-down)
    from scipy.stats import t as student

    noise = rng.normal(0.0, 0.05, 20)
    noise = (noise - noise.mean()) / noise.std(ddof=1) * 0.05  # SD exactly 0.05: p is set by the mean alone
    at_p = [(base + noise + 0.02 + student.ppf(p, 19) * 0.05 / np.sqrt(20), base) for p in (0.03, 0.04)]
    stop = holm([margin_test("prpv", "cal", a, b, 0.02) for a, b in at_p], at_p, 0.05)
    assert stop[0].alpha == pytest.approx(0.025) and not stop[0].noninferior  # p 0.03 > 0.025: not shown
    assert stop[1].upper < 0.02 and not stop[1].noninferior  # p 0.04 < 0.05, but Holm stopped at the first
    assert holm([margin_test("a", "b", [0.1], [0.1], 0.02)], [([0.1], [0.1])], 0.05)[0].n == 1  # untested: no error


def test_a_study_registered_before_the_multiplicity_rule_resumes_uncorrected(tmp_path):
    """A folder whose criteria predate ``multiplicity`` keeps its registered rule (each test at α) when the run
    names none, so it resumes and is looked at as registered; a run that names a rule is compared as given."""
    from proxybench.experiments.validate.registration import registered_rule
    from proxybench.experiments.validate.run import ValidateConfig, settings_for

    cfg = ValidateConfig(family="gym")
    s = settings_for(cfg, False)
    assert registered_rule(cfg, s, tmp_path) is s  # no study there: a new one is corrected
    old = s.model_copy(update={"primary": s.primary.model_copy(update={"multiplicity": None})})
    (tmp_path / "criteria.json").write_text(json.dumps({"settings": old.model_dump(mode="json")}))
    assert registered_rule(cfg, s, tmp_path).model_dump(mode="json") == old.model_dump(mode="json")
    named = ValidateConfig(family="gym", multiplicity="holm")
    assert registered_rule(named, s, tmp_path) is s
    (tmp_path / "criteria.json").write_text(json.dumps({"settings": s.model_dump(mode="json")}))
    assert registered_rule(cfg, s, tmp_path) is s  # a corrected study stays corrected


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


def test_the_nominal_is_the_centre_candidate_of_every_family_and_an_off_centre_grid_is_refused():
    from proxybench.experiments.config import ConfigError
    from proxybench.experiments.proxies import proxy_params
    from proxybench.experiments.validate.run import FAMILIES, ValidateConfig, _candidates, settings_for

    for family in FAMILIES:
        for quick in (True, False):
            s = settings_for(ValidateConfig(family=family), quick)
            cands = _candidates(s)
            nominal = proxy_params(tuple(s.image_size))
            centre = cands[len(cands) // 2]
            assert len(cands) == 9 and centre == {n: float(getattr(nominal, n)) for n in s.grid}, (family, quick)
            assert cands.count(centre) == 1
    assert settings_for(ValidateConfig(family="gym"), False).grid["command_delay"] == (0.0, 0.10, 0.20)
    with pytest.raises(ConfigError, match=r"grid: command_delay's centre is 0.15, the nominal θ's is 0.1"):
        settings_for(ValidateConfig(family="gym", grid={"trim": (-0.2, 0.0, 0.2),
                                                         "command_delay": (0.05, 0.15, 0.25)}), True)
    with pytest.raises(ConfigError, match="grid: trim has 2 values and so no centre"):
        settings_for(ValidateConfig(grid={"trim": (-0.1, 0.1)}), True)


def test_the_criteria_plan_each_stratum_for_the_margin():
    from proxybench.experiments.validate.run import ValidateConfig, settings_for
    from proxybench.usefulness.validation import targets_needed

    s = settings_for(ValidateConfig(family="gym"), False)
    plan = s.primary
    assert plan.comparisons == ("calibration", "trajectory_fit") and plan.margin == 0.02 and plan.assumed_sd == 0.1
    assert set(plan.strata) == {"near", "far"}
    near, far = plan.strata["near"], plan.strata["far"]
    # uniform draw: trim in [-0.15, 0.35] (0.2 of 0.5 inside |trim| <= 0.1), delay in [0.02, 0.3] (0.18 of 0.28)
    assert near.share == pytest.approx(0.4 * 0.18 / 0.28, abs=1e-6) and near.share + far.share == pytest.approx(1)
    # Holm over 2 strata × 2 comparisons: the first test is held to α/4, and the sizes are planned for it
    assert plan.multiplicity == "holm" and plan.tests == 4 and plan.level(0.05) == pytest.approx(0.0125)
    assert near.needed == far.needed == targets_needed(0.02, 0.10, 0.0125) > 156
    uncorrected = settings_for(ValidateConfig(family="gym", multiplicity="none"), False).primary
    assert uncorrected.multiplicity is None and uncorrected.strata["near"].needed == 156  # one-sided t, α 0.05, 80 %
    assert "multiplicity" not in uncorrected.model_dump(mode="json")  # as studies registered before the rule
    (n_near, mde_near), (_, mde_far) = (st.planned(40, 0.05, 0.8, 0.1) for st in (near, far))
    assert n_near == pytest.approx(40 * near.share, abs=1e-3) and mde_near > mde_far > 0.02
    assert near.planned(4, 0.05, 0.8, 0.1)[1] is None  # under 2 targets expected: no MDE
    # the plan does not depend on the study's size: other targets differ in `targets` alone (criteria's message)
    assert settings_for(ValidateConfig(family="gym", targets=7), False).primary == plan


def test_per_stratum_declares_each_stratum_s_size_and_the_draw_fills_it():
    """The strata's sizes by design: the draw goes on until near and far each hold per_stratum targets, the
    criteria declare them (and the margin that many can show), and a study without it is pre-registered byte for
    byte as before the option existed."""
    from proxybench.experiments.config import ConfigError
    from proxybench.experiments.validate.config import stratum_of
    from proxybench.experiments.validate.run import ValidateConfig, drawn_theta, settings_for, stratified_draws

    for family in ("heldout", "gym"):
        s = settings_for(ValidateConfig(family=family, per_stratum=6), False)
        assert s.targets == 12 and {st.allocated for st in s.primary.strata.values()} == {6}
        assert s.primary.strata["near"].planned(12, 0.05, 0.8, 0.1)[0] == 6  # not 12 × its share
        kept = stratified_draws(s, 4321)
        assert len(set(kept)) == 12
        strata = [stratum_of(drawn_theta(s, 4321, i), s.near) for i in kept]
        assert strata.count("near") == strata.count("far") == 6
        assert "allocated" in s.primary.model_dump(mode="json")["strata"]["near"]
    plain = settings_for(ValidateConfig(family="gym"), False)
    assert stratified_draws(plain, 4321) is None
    assert "allocated" not in json.dumps(plain.model_dump(mode="json"))  # old studies' keys unchanged
    with pytest.raises(ConfigError, match=r"targets: 5 is not 2 × per_stratum \(6\)"):
        settings_for(ValidateConfig(family="gym", per_stratum=3, targets=5), False)
    with pytest.raises(ConfigError, match="per_stratum: the draw puts no target in the near stratum"):
        settings_for(ValidateConfig(family="heldout", per_stratum=3, draw={"trim": (0.15, 0.35)}), False)


@pytest.mark.slow
def test_a_stratified_quick_study_holds_its_declared_strata(tmp_path, monkeypatch):
    _short_quick_episodes(monkeypatch, "heldout")
    out = tmp_path / "v"
    pool = ["--agent", "pid", "--agent", "pid-twitchy", "--agent", "vision", "--agent", "vision-fast"]  # half of
    # --quick's, two families (two agents a side in every split): the strata do not depend on the pool
    res = CliRunner().invoke(app, ["validate", "--quick", "--per-stratum", "2", *pool, "--backend", "inline", "--out",
                                   str(out)], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    criteria = json.loads((out / "criteria.json").read_text())
    assert criteria["settings"]["targets"] == 4
    assert {st["allocated"] for st in criteria["settings"]["primary"]["strata"].values()} == {2}
    summary = json.loads((out / "summary.json").read_text())
    assert sorted(summary["strata"]) == ["far", "far", "near", "near"]
    assert summary["planned"]["near"]["targets"] == 2


def _drive(trim: float, delay: float, step_time: float = 0.0) -> tuple[np.ndarray, ...]:
    """(t, x, y, θ) of the DB18 dynamic model driving PWM 0.4 from ``step_time``, acting ``delay`` later."""
    dt, n = 1 / 60, 181
    t = np.arange(n) * dt
    x, y, th, v, w = np.zeros(n), np.zeros(n), np.zeros(n), 0.0, 0.0
    for k in range(1, n):
        u = 0.4 if t[k - 1] >= step_time + delay - 1e-9 else 0.0
        v, w = v + dt * (-5 * v + 1.5 * 2 * u), w + dt * (-4 * w + 15 * 2 * trim * u)
        th[k] = th[k - 1] + w * dt
        x[k], y[k] = x[k - 1] + v * np.cos(th[k - 1]) * dt, y[k - 1] + v * np.sin(th[k - 1]) * dt
    return t, x, y, th


def test_the_calibration_method_recovers_trim_and_delay_and_keeps_the_rest_nominal():
    from proxybench.experiments.validate.run import ValidateConfig, calibrated_theta, settings_for
    from proxybench.usefulness.calibration import curvature_per_trim

    per = curvature_per_trim(kinematic=False)
    gym = settings_for(ValidateConfig(family="gym"), True)
    pick = calibrated_theta(gym, [_drive(0.12, 0.0)] * 2, [_drive(0.0, 0.18, 1.0)[:3]] * 2, per_trim=per,
                            step_time=1.0)
    assert pick.theta["trim"] == pytest.approx(0.12, abs=0.01)
    assert pick.theta["command_delay"] == pytest.approx(0.18, abs=0.02)
    far = calibrated_theta(gym, [_drive(-0.3, 0.0)], [_drive(0.0, 0.1, 1.0)[:3]], per_trim=per, step_time=1.0)
    assert far.estimate["trim"] == pytest.approx(-0.3, abs=0.01) and far.theta["trim"] == -0.15  # clipped to the draw
    heldout = settings_for(ValidateConfig(), True)  # trim × camera pitch: a drive cannot see the camera
    pick = calibrated_theta(heldout, [_drive(0.2, 0.0)], [_drive(0.0, 0.1, 1.0)[:3]], per_trim=per, step_time=1.0)
    assert pick.theta["camera_pitch"] == 19.15 and pick.theta["trim"] == pytest.approx(0.2, abs=0.01)
    assert set(pick.theta) == set(heldout.grid)


def test_a_target_without_poses_makes_calibration_not_applicable_with_its_reason():
    from proxybench.experiments.validate.run import (
        ValidateConfig,
        ValidationRun,
        _calibration,
        calibrated_theta,
        score_target,
        settings_for,
        summarize,
    )

    s = settings_for(ValidateConfig(methods=("prpv", "calibration", "nominal")), True)
    none = calibrated_theta(s, [], [], per_trim=12.5, step_time=1.0)
    assert none.theta is None and "carry no pose" in none.reason

    class Recording:  # a recorded target: its agents are fixed, the drives are not among them
        fixed_agents = ("pid", "vision")

    rec_pick, ran = _calibration(Recording(), s, {}, lambda _n: None)
    assert rec_pick.theta is None and ran == 0 and "recording" in rec_pick.reason
    from proxybench.experiments.validate.run import _candidates

    cands = _candidates(s)
    target = _res({"a": 3.0, "b": 2.0, "c": 1.0})
    proxies = [_res({"a": 3.0 - 0.1 * c, "b": 2.0, "c": 1.0 + 0.3 * c}) for c in range(len(cands))]
    record = score_target(s, 0, cands, target, target, proxies, proxies, None, {"calibration": none})
    assert "calibration" not in record.picks and record.not_applicable["calibration"] == none.reason
    criteria = {"written": "2026-01-01 00:00:00 +0000", "commit": "test", "minimum_detectable_effect": {}}
    summary = summarize(ValidationRun(s, None, [record, record], [None, None]), criteria)
    cal = summary.methods["calibration"]
    assert cal.not_applicable == 2 and cal.reasons == [none.reason]
    assert [t.n for t in summary.primary_tests] == [0]  # an interim look (2 of 3): one pooled test, nothing in it
    assert summary.primary_tests[0].stratum == "all" and summary.primary_tests[0].not_applicable == 2


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
    pool = ["--agent", "pid", "--agent", "pid-twitchy", "--agent", "vision", "--agent", "vision-fast"]  # half of
    # --quick's, two families (two agents a side in every split): nothing checked here depends on the pool's size
    args = ["validate", "--quick", "--targets", "3", "--episodes-eval", "3", *pool, "--backend", "inline", "--out",
            str(out)]
    res = CliRunner().invoke(app, args, env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    criteria = json.loads((out / "criteria.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    assert "draw_seed_sha256" in criteria and "draw_seed" not in json.dumps(criteria["settings"])
    assert summary["criteria"]["scoring_unchanged"] and summary["targets"] == 3 and not summary["interim"]
    methods = summary["methods"]
    assert {"prpv", "nominal", "trajectory", "kendall"} <= set(methods)
    assert methods["nominal"]["prpv_norm"]["vs_nominal"]["mean"] == 0.0
    # no grid method beats the grid's oracle (a continuous pick may)
    assert all(m["prpv_norm"]["mean_regret"] >= 0 for k, m in methods.items() if k not in ("calibration",
                                                                                          "trajectory_fit"))
    assert "primary" in summary and "tuning with prpv" in res.output.lower()
    # the primary comparison: PRPV against each calibration, per pre-declared stratum (assigned at the reveal)
    tests = {(t["b"], t["stratum"]): t for t in summary["primary_tests"]}
    assert set(tests) == {(b, st) for b in ("calibration", "trajectory_fit") for st in ("near", "far")}
    assert sorted(summary["strata"]) == sorted(st for st in summary["strata"] if st in ("near", "far"))
    assert len(summary["strata"]) == 3
    for (b, st), t in tests.items():
        assert t["n"] + t["not_applicable"] == summary["strata"].count(st), (b, st)
        # Holm: each test at its own level (at most α), shown only below the margin at that level
        assert t["alpha"] <= 0.05 and (not t["noninferior"] or t["upper"] < t["margin"])
        assert t["superior"] == bool(t["noninferior"] and t["upper"] < 0)
    assert sorted(t["alpha"] for t in tests.values()) == pytest.approx([0.05 / 4, 0.05 / 3, 0.05 / 2, 0.05])
    assert ("stratum" in res.output) and ("PRPV − calibration" in res.output or "PRPV against calibration" in
                                          res.output)
    assert {"calibration", "trajectory_fit"} <= set(methods)
    records = [json.loads(p.read_text()) for p in sorted((out / "targets").glob("*.json"))]
    assert all(r["grid_size"] == 9 and len(r["candidates"]) >= 9 for r in records)
    assert all("calibration" in r["picks"] and set(r["estimates"]["calibration"]) == {"trim", "command_delay"}
               for r in records)
    assert all(r["episodes_run"] > 0 for r in records)
    # split by family: no held-out agent is a variant of a tuning one
    from proxybench.agents.families import family_of

    assert all(not {family_of(a) for a in r["tuning_agents"]} & {family_of(a) for a in r["heldout_agents"]}
               for r in records)
    # agents as a sample: the gain from per-agent shares (their mean is the quality), two ways of resampling
    level = summary["agent_level"]["prpv-nominal"]
    assert level["targets_only"]["value"] == pytest.approx(methods["prpv"]["prpv_norm"]["vs_nominal"]["mean"])
    assert level["targets_and_families"]["resampled"] == "both (families)"
    assert {c["agent"] for c in level["contributions"]} == {a for r in records for a in r["heldout_agents"]}
    # the episodes saved by each pick as the predictor (3 evaluation episodes per agent: enough to compute)
    assert summary["savings"]["nominal"]["targets"] == 3 and "vs_nominal" in summary["savings"]["prpv"]
    assert "agents as a sample" in res.output and "target episodes saved" in res.output
    # a quick study says it cannot answer, in the terminal and in summary.json's verdict (issue 39)
    assert "CANNOT ANSWER THE QUESTION" in res.output and summary["verdict"].startswith("QUICK MODE")
    assert set(summary["planned"]) == {"near", "far"} and summary["planned"]["far"]["targets"] > 0
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
    assert interim["strata"] == [] and {t["stratum"] for t in interim["primary_tests"]} == {"all"}
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
    # half of --quick's pool, two families: what is checked here (the family, the secret's mode, no θ in the
    # reports) does not depend on the pool, and the gym nodes' episodes are the suite's slowest
    pool = ["--agent", "pid", "--agent", "pid-twitchy", "--agent", "vision", "--agent", "vision-fast"]
    res = CliRunner().invoke(app, ["validate", "--family", "gym", "--quick", "--targets", "2", *pool, "--backend",
                                   "inline", "--out", str(out)], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["family"] == "gym" and summary["targets"] == 2 and "prpv" in summary["methods"]
    secret = next((out / "secret" / "gym").glob("gym-*.yaml"))
    assert stat.S_IMODE(secret.stat().st_mode) == 0o600
    drawn = summary["truths"][0]["trim"]
    report = (out / "targets.csv").read_text() + (out / "criteria.json").read_text()
    assert f"{drawn}" not in report  # the hidden θ is only in the secret file and the revealed summary


def test_the_pools_networks_learn_in_different_places(monkeypatch):
    """Issue 35 item 3: behaviour-cloned agents trained elsewhere than the nominal proxy — another θ, the
    domain-randomised family, DAgger rounds — so held-out networks are not all siblings; the first two recipes are
    every earlier study's (nominal proxy, 1,500 and 6,000 frames), so a resumed study trains what it trained."""
    import proxybench.experiments.plv.dagger as dagger_mod
    import proxybench.learning as learning
    import proxybench.learning.collection as collection
    from proxybench.experiments.validate import run as vr

    calls = []

    def fake_collect(domain, cfg, policy=None, beta=0.0, progress=None, pool=None):
        calls.append((domain.name, domain.kind, cfg.samples, policy is not None))
        return object()

    monkeypatch.setattr(collection, "collect", fake_collect)
    monkeypatch.setattr(dagger_mod, "collect", fake_collect)
    monkeypatch.setattr(dagger_mod, "torch_policy", lambda model: (lambda images: None))
    monkeypatch.setattr(dagger_mod.Dataset, "concat", staticmethod(lambda parts: object()))
    monkeypatch.setattr(learning, "train", lambda model, data, cfg: None)
    monkeypatch.setattr(dagger_mod, "train", lambda model, data, cfg: None)
    assert vr.BC_RECIPES[:2] == (vr.BCRecipe("nominal", 1500), vr.BCRecipe("nominal", 6000))
    seen = {}
    for recipe in vr.BC_RECIPES:
        calls.clear()
        vr._train_bc(recipe, 3, lambda what: None)
        seen[recipe.where] = list(calls)
    assert seen["nominal"] == [("proxy", "simulation", 12000, False)]  # the last nominal recipe
    assert seen["other"][0][0].startswith("proxy:camera_pitch=") and seen["other"][0][1] == "simulation"
    assert seen["randomized"][0][:2] == ("randomized", "family")
    assert seen["dagger"][0] == ("proxy", "simulation", 3000, False)
    assert [c[3] for c in seen["dagger"][1:]] == [True, True] and sum(c[2] for c in seen["dagger"][1:]) == 1500
    assert seen["gym"][0][1] == "robot" and seen["gym"][0][0].endswith("-m proxybench gym serve")  # gym's defaults


def test_a_network_that_trains_in_gym_needs_its_environment_before_anything_trains(monkeypatch, tmp_path):
    from types import SimpleNamespace

    import proxybench.gym.environment as environment
    from proxybench.experiments.config import ConfigError
    from proxybench.experiments.validate import run as vr
    from proxybench.experiments.validate.config import ValidateConfig, settings_for

    missing = SimpleNamespace(problems=["no gym-duckietown environment at /nowhere (run: proxybench gym setup)"])
    monkeypatch.setattr(environment, "check_environment", lambda path=None, render=True: missing)
    trained = []
    monkeypatch.setattr(vr, "_train_bc", lambda *a: trained.append(a))
    gym_index = next(i for i, r in enumerate(vr.BC_RECIPES) if r.where == "gym")
    s = settings_for(ValidateConfig(family="gym", bc_agents=gym_index + 1), False)
    with pytest.raises(ConfigError, match=f"bc_agents: network {gym_index} trains in gym-duckietown.*proxybench gym "
                                          f"setup.*bc_agents to {gym_index} or fewer"):
        vr.train_bc_agents(s, tmp_path)
    assert trained == [] and not list(tmp_path.iterdir())
    assert settings_for(ValidateConfig(family="gym"), False).bc_agents == gym_index + 1  # the gym family trains it
