"""Repeatability designs of thesis §5.4 (1×9, 3×3, 2×6) on all three kinds of target, and the command."""

from __future__ import annotations

import json
import shlex
import sys

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.domain.reality import reality_params
from proxybench.experiments.repeatability.run import (
    DESIGNS,
    Design,
    recorded_study,
    repeatability_study,
    robot_params,
    robot_study,
)


def test_designs_parse_by_name_or_as_labs_robots_runs():
    assert DESIGNS["repeatability"] == Design(1, 1, 9) and DESIGNS["inter-robot"] == Design(1, 3, 3)
    assert DESIGNS["inter-lab"] == Design(2, 1, 6) and DESIGNS["inter-lab"].total == 12
    assert Design.parse("inter-robot") == ("inter-robot", Design(1, 3, 3))
    assert Design.parse("2×1×6") == ("2×1×6", Design(2, 1, 6)) and Design.parse("1x4x2")[1].group == "robot"
    assert Design(2, 1, 6).group == "lab" and Design(1, 1, 9).group is None
    for bad, msg in (("3x3", "unknown design"), ("1x1x1", "at least 2 runs"), ("0x2x2", "labs must be >= 1")):
        with pytest.raises(ValueError, match=msg):
            Design.parse(bad)


def test_a_robot_is_the_same_robot_in_every_design_and_a_lab_changes_the_light():
    base = reality_params()
    assert robot_params(base, 0, 0, 1) == robot_params(base, 0, 0, 1)
    assert robot_params(base, 0, 0, 1).trim != robot_params(base, 0, 0, 2).trim
    assert robot_params(base, 0, 0, 0).light_rgb == base.light_rgb  # lab 0 is the reality model's own lab
    assert robot_params(base, 0, 1, 0).light_rgb != base.light_rgb


@pytest.fixture(scope="module")
def study():
    designs = {"one": Design(1, 1, 3), "fleet": Design(1, 2, 2)}
    return repeatability_study("pure-pursuit", designs, seconds=4.0, image_size=(40, 30))


def test_study_runs_each_design_and_splits_robots_from_runs(study):
    one, fleet = study.designs["one"], study.designs["fleet"]
    assert len(one.runs) == 3 and len(fleet.runs) == 4 and study.source.startswith("reality-model")
    assert fleet.labels == ["lab 0/robot 0", "lab 0/robot 0", "lab 0/robot 1", "lab 0/robot 1"]
    assert [t.meta["run"] for t in fleet.runs] == [0, 1, 0, 1] and fleet.runs[2].meta["robot"] == 1
    assert "MPD_within_std_cm" not in one.figures and "MPD_between_std_cm" in fleet.figures
    # two robots with their own trim and gain drive apart more than two runs of one robot do
    assert fleet.figures["MPD_between_std_cm"] > fleet.figures["MPD_within_std_cm"]
    again = repeatability_study("pure-pursuit", {"one": Design(1, 1, 3)}, seconds=4.0, image_size=(40, 30))
    assert again.figures["one"] == one.figures  # seeded: the same runs again


def test_recorded_runs_in_lab_robot_folders_give_the_same_figures(study, tmp_path):
    """A real lab's files (t, x, y, theta) laid out LAB/ROBOT/run.csv: the design is read from the folders."""
    fleet = study.designs["fleet"]
    for tr in fleet.runs:
        folder = tmp_path / "ethz" / f"bot{tr.meta['robot']}"
        folder.mkdir(parents=True, exist_ok=True)
        pd.DataFrame({k: tr[k] for k in ("t", "x", "y", "theta")}).to_csv(folder / f"run{tr.meta['run']}.csv",
                                                                          index=False)
    res = recorded_study([tmp_path], "loop_3x3")
    (name, got), = res.designs.items()
    assert res.source == "recorded" and got.design == Design(1, 2, 2) and name == "recorded 1×2×2"
    assert got.labels[0] == "ethz/bot0" and got.runs[0].meta["source"] == "recorded"
    for key in ("MPD_cm", "MPD_std_cm", "MOD_deg", "MPD_between_std_cm"):
        assert got.figures[key] == pytest.approx(fleet.figures[key], abs=0.05), key
    with pytest.raises(ValueError, match="at least 2 recorded runs"):
        recorded_study([tmp_path / "ethz" / "bot0" / "run0.csv"])
    with pytest.raises(FileNotFoundError, match="no such file"):
        recorded_study([tmp_path / "missing"])


def test_robot_nodes_are_robots_of_a_design(tmp_path):
    serve = shlex.join([sys.executable, "-m", "proxybench.cli", "robot", "serve", "--param", "image_width=40",
                        "--param", "image_height=30"])
    res = robot_study("pure-pursuit", {"sim-a": serve}, runs=2, seconds=2.0)
    (name, got), = res.designs.items()
    assert res.source == "robot node" and got.design == Design(1, 1, 2) and "sim-a" in res.notes[name]
    # each run says what the node said it is (a simulator here), never "robot" on our behalf
    assert all(t.meta["source"] == "simulation" and t.meta["robot"] == "sim-a" for t in got.runs)
    assert np.isfinite(got.figures["MPD_cm"])


def test_repeatability_command_prints_each_design_beside_the_thesis(tmp_path):
    runner = CliRunner()
    res = runner.invoke(app, ["repeatability", "--agent", "pure-pursuit", "--design", "repeatability",
                              "--design", "1x2x2", "--runs", "2", "--seconds", "2", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "repeatability" in res.output and "1×2×2" in res.output and "-6.2 ± 1.3" in res.output
    assert "MPD [cm]" in res.output  # units survive rich markup
    blob = json.loads((tmp_path / "repeatability.json").read_text())
    assert set(blob["figures"]) == {"repeatability", "1×2×2"} and blob["source"].startswith("reality-model")
    assert len(pd.read_csv(tmp_path / "repeatability.csv")) == 2
    for name in ("trajectories.png", "mpd_mod.png", "mpd_mod.svg"):
        assert (tmp_path / name).stat().st_size > 0
    bad = runner.invoke(app, ["repeatability", "--design", "3x3", "--out", str(tmp_path)])
    assert bad.exit_code == 2 and "unknown design '3x3'" in bad.output
    missing = runner.invoke(app, ["repeatability", "--recorded", str(tmp_path / "nope"), "--out", str(tmp_path)])
    assert missing.exit_code == 2 and "no such file or folder" in missing.output
