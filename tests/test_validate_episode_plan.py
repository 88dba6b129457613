"""`proxybench results plan-episodes` (issue 35 item 2, "E1/E2 sizes chosen with plan"): the planner run on a shipped
validation study's own episodes says what more episodes per agent would buy; no episode runs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.experiments.config import ConfigError
from proxybench.experiments.validate.episode_plan import EpisodePlan, plan_study

ROOT = Path(__file__).resolve().parents[1]
STUDY = ROOT / "results" / "validate_heldout_8"
runner = CliRunner()


def test_a_shipped_study_is_planned_per_target_from_its_own_episodes():
    res = plan_study(STUDY, targets=2, reps=30)
    assert [t.target for t in res.targets] == [0, 1] and res.episodes_tune == res.episodes_eval == 3
    for t in res.targets:
        assert t.agents == 34 and t.candidates == 9 and t.pilot_episodes == 3  # 36 runs less the two drives
        ns = [r[0] for r in t.rows]
        assert ns == sorted(ns) and ns[0] == 3
        assert 0.0 <= t.p_correct_at_pilot <= 1.0
        assert t.rows[-1][2] < t.rows[0][2]  # more episodes, a narrower order range
        if t.n_for_p_correct is not None:  # a planned n whose chance reaches the goal
            assert next(r[1] for r in t.rows if r[0] == t.n_for_p_correct) >= 0.8
    assert res.median_p_correct_at_pilot == pytest.approx(float(np.median([t.p_correct_at_pilot
                                                                           for t in res.targets])))
    # seeded: the same answer (each target is planned on its own, seed + its index, so target 0 alone is planned
    # again; the summary is computed from the targets' plans)
    again = plan_study(STUDY, targets=1, reps=30)
    assert again.targets == res.targets[:1]


def test_the_command_writes_the_plan_where_asked_and_bad_folders_are_one_line_errors(tmp_path):
    res = runner.invoke(app, ["results", "plan-episodes", str(STUDY), "--targets", "1", "--reps", "20", "--out",
                              str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "validate_heldout_8: 1 targets" in res.output and "episodes per agent" in res.output
    plan = EpisodePlan.model_validate_json((tmp_path / "episode_plan.json").read_text())
    assert plan.study == "validate_heldout_8" and len(plan.targets) == 1
    assert (tmp_path / "episode_plan.csv").read_text().startswith("target,agents,candidates")
    with pytest.raises(ConfigError, match=r"criteria\.json"):
        plan_study(tmp_path)
    (tmp_path / "criteria.json").write_text(json.dumps({"settings": json.loads(
        (STUDY / "criteria.json").read_text())["settings"]}))
    bad = runner.invoke(app, ["results", "plan-episodes", str(tmp_path)])
    assert bad.exit_code != 0 and "episodes.csv.gz" in bad.output and "Traceback" not in bad.output
