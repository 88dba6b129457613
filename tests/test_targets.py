"""Targets as data: manifests, recorded trajectories and score tables, and what goes wrong with them."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import yaml

from proxybench.targets import TargetError, check_recording, load_manifest, load_recording
from proxybench.targets.recorded import RecordedEpisode

# a lane point of loop_3x3's bottom road, heading east, and a run along it
Y_LANE = 0.585 * 0.5 - 0.22 * 0.585


def manifest(**changes):
    m = {"source": "real", "map": "loop_3x3", "seconds": 2.0, "agents": ["a", "b"], "episodes": [0, 1],
         "trajectories": "runs/{agent}/{episode}.csv", "who": "test lab"}
    m.update(changes)
    return {k: v for k, v in m.items() if v is not None}


def run_csv(speed: float, n: int = 41) -> pd.DataFrame:
    t = np.linspace(0.0, 2.0, n)
    return pd.DataFrame({"t": t, "x": 0.3 + speed * t, "y": np.full(n, 0.585 + Y_LANE - 0.585), "theta": 0.0 * t})


def write_lab(root, man=None, speeds=None):
    root.mkdir(parents=True, exist_ok=True)
    (root / "target.yaml").write_text(yaml.safe_dump(man or manifest()))
    speeds = speeds or {"a": 0.3, "b": 0.1}
    for agent, v in speeds.items():
        for ep in (0, 1):
            f = root / "runs" / agent / f"{ep}.csv"
            f.parent.mkdir(parents=True, exist_ok=True)
            run_csv(v + 0.01 * ep).to_csv(f, index=False)
    return root


def problems(root) -> str:
    report = check_recording(root)
    assert not report.ok
    return "\n".join(report.problems)


def test_a_lab_recording_loads_with_scores_starts_and_seeds(tmp_path):
    root = write_lab(tmp_path / "lab")
    rec = load_recording(root, ("driven_lanedir_consec", "survival_time"))
    assert rec.agents == ["a", "b"] and len(rec.episodes) == 4
    ep: RecordedEpisode = rec.episodes[("a", 1)]
    assert ep.pose == pytest.approx((0.3, Y_LANE, 0.0)) and ep.seed == 1  # seed·10000 + episode, seed 0
    assert ep.scores["survival_time"] == pytest.approx(2.0)
    assert ep.scores["driven_lanedir_consec"] == pytest.approx(0.62, abs=0.03)  # ~0.31 m/s for 2 s
    assert rec.episodes[("b", 0)].scores["driven_lanedir_consec"] < ep.scores["driven_lanedir_consec"]
    assert [e.agent for e in rec.select(["b"], 1)] == ["b"]
    with pytest.raises(TargetError, match="agent\\(s\\) 'c' not in the recording"):
        rec.select(["c"], None)
    with pytest.raises(TargetError, match=r"episodes: 3 asked, the recording .* has 2"):
        rec.select(["a"], 3)


def test_manifest_is_strict_and_names_the_field(tmp_path):
    cases = [
        (manifest(seconds=None), "seconds: required, missing"),
        (manifest(source="lab"),
         "source: Input should be 'real', 'reality-model', 'robot-node', 'dtps-robot' or 'simulation'"),
        ({**manifest(), "agnets": ["a"]}, "agnets: unknown key (did you mean 'agents'?)"),
        (manifest(agents=["a", "a"]), "agents: agent 'a' is listed twice"),
        (manifest(trajectories="runs/{agent}.csv"), "lacks {episode}"),
        (manifest(metrics_table="s.csv"), "give trajectories or metrics_table, not both"),
        (manifest(source="robot-node"), "source robot-node needs robot"),
    ]
    for k, (data, message) in enumerate(cases):
        root = tmp_path / f"m{k}"
        root.mkdir()
        (root / "target.yaml").write_text(yaml.safe_dump(data))
        with pytest.raises(TargetError) as err:
            load_manifest(root)
        assert str(root / "target.yaml") in str(err.value) and message in str(err.value), str(err.value)
    with pytest.raises(TargetError, match=r"has no target\.yaml"):
        load_manifest(tmp_path)


def test_bad_trajectory_files_are_named_with_row_and_column(tmp_path):
    root = write_lab(tmp_path / "lab")
    f = root / "runs" / "a" / "0.csv"
    df = run_csv(0.3)
    df.loc[5, "t"] = df.loc[4, "t"]  # time stands still at data row 6, line 7
    df.to_csv(f, index=False)
    assert f"{f}: row 6 (line 7), column 't': time is not increasing" in problems(root)

    df = run_csv(0.3)
    df.loc[3, "y"] = np.nan
    df.to_csv(f, index=False)
    assert f"{f}: row 4 (line 5), column 'y': empty (or NaN)" in problems(root)

    df = run_csv(0.3).drop(columns=["theta"])
    df.to_csv(f, index=False)
    assert f"{f}: missing column(s) theta" in problems(root)

    df = run_csv(0.3)
    df["x"] += 30.0  # centimetres? another frame?
    df["theta"] = df["theta"].astype(object)
    df.loc[2, "theta"] = "north"  # and a word where a number belongs
    df.to_csv(f, index=False)
    assert f"{f}: row 3 (line 4), column 'theta': 'north' is not a finite number" in problems(root)
    df.loc[2, "theta"] = 0.0
    df.to_csv(f, index=False)
    text = problems(root)
    assert f"{f}: row 1 (line 2), columns 'x', 'y': the first pose (30.300" in text
    assert "is off the map 'loop_3x3' (1.75 × 1.75 m): wrong map, units or frame?" in text

    f.unlink()
    assert f"{f}: missing (agent 'a', episode 0" in problems(root)


def test_a_run_leaving_the_map_ends_there_with_a_note(tmp_path):
    root = write_lab(tmp_path / "lab")
    df = run_csv(0.3)
    df.loc[30:, "y"] = -1.0
    df.to_csv(root / "runs" / "a" / "0.csv", index=False)
    report = check_recording(root)
    assert report.ok and any("left the map at row 31" in n for n in report.notes)
    ep = next(e for e in report.episodes if (e.agent, e.episode) == ("a", 0))
    assert ep.termination == "left_map" and ep.scores["survival_time"] < 1.6


def test_a_proxybench_file_from_another_map_is_a_map_mismatch(tmp_path):
    from proxybench.agents import make_agent
    from proxybench.domain.simulator import Simulator
    from proxybench.runner.episode import run_episode

    root = write_lab(tmp_path / "lab", manifest(trajectories="runs/{agent}/{episode}.parquet", agents=["pid"],
                                                episodes=[0]), speeds={})
    sim = Simulator("zigzag", render=False)
    traj = run_episode(sim, make_agent("pid"), 0, 1.0, camera=False, meta={"map": "zigzag"})
    (root / "runs" / "pid").mkdir(parents=True)
    traj.save(root / "runs" / "pid" / "0.parquet")
    assert "map mismatch: recorded on 'zigzag', the manifest says 'loop_3x3'" in problems(root)


def test_metrics_tables_for_labs_that_kept_only_scores(tmp_path):
    root = tmp_path / "scores"
    root.mkdir()
    man = manifest(trajectories=None, metrics_table="scores.csv")
    (root / "target.yaml").write_text(yaml.safe_dump(man))
    rows = [{"agent": a, "episode": e, "survival_time": 2.0, "driven_lanedir_consec": 0.5 * (a == "a") + 0.1 * e}
            for a in ("a", "b") for e in (0, 1)]
    pd.DataFrame(rows).to_csv(root / "scores.csv", index=False)
    rec = load_recording(root, ("driven_lanedir_consec", "survival_time"))
    assert rec.episodes[("a", 1)].scores["driven_lanedir_consec"] == pytest.approx(0.6)
    assert rec.episodes[("a", 1)].pose is None  # no start poses: proxies draw them from the seed

    bad = pd.DataFrame(rows).rename(columns={"survival_time": "survival"})
    bad.to_csv(root / "scores.csv", index=False)
    assert "column 'survival': 'survival' is not a known metric (did you mean 'survival_time'?)" in problems(root)

    bad = pd.DataFrame(rows)
    bad.loc[2, "agent"] = "c"
    bad.to_csv(root / "scores.csv", index=False)
    text = problems(root)
    assert "row 3 (line 4), column 'agent': 'c' is not in the manifest's agents" in text
    assert "missing agent 'b', episode(s) 0" in text

    bad = pd.DataFrame(rows)
    bad.loc[1, "survival_time"] = np.nan
    bad.to_csv(root / "scores.csv", index=False)
    assert "row 2 (line 3), column 'survival_time': empty (or NaN)" in problems(root)

    pd.DataFrame(rows + rows[:1]).to_csv(root / "scores.csv", index=False)
    assert "row 5 (line 6): agent 'a' episode 0 again (first at row 1 (line 2))" in problems(root)

    pd.DataFrame(rows).to_csv(root / "scores.csv", index=False)
    with pytest.raises(TargetError, match="no column for the metric 'lane_score'"):
        load_recording(root, ("lane_score",))


def test_open_target_tells_the_kinds_apart(tmp_path):
    from proxybench.targets import RealityTarget, RecordedTarget, open_target

    assert isinstance(open_target("reality"), RealityTarget)
    assert open_target("reality").info().simulated is True
    lab = open_target(str(write_lab(tmp_path / "lab")))
    assert isinstance(lab, RecordedTarget) and lab.info().simulated is False
    assert "REAL robots (as its manifest declares)" in lab.info().statement and "by test lab" in lab.info().statement
    with pytest.raises(TargetError, match=r"not 'reality', 'robot:COMMAND', 'dtps:HOST\[:PORT\]/PATH' or an "
                                          "existing directory"):
        open_target(str(tmp_path / "nowhere"))
    with pytest.raises(TargetError, match="robot: needs the command"):
        open_target("robot:")
    with pytest.raises(TargetError, match=r"target_params: unknown domain parameter 'trimm' \(did you mean 'trim'"):
        open_target("reality", params={"trimm": 0.1})
    with pytest.raises(TargetError, match="only the reality model's parameters"):
        open_target(str(tmp_path / "lab"), params={"trim": 0.1})


def test_imported_runs_that_stop_early_are_counted_as_ended_early(tmp_path):
    """A run whose samples stop before the episode's length ended early: off the road when its last pose is off
    the drivable tiles, else 'ended_early'; `target check`'s table counts both (it said 0 for every agent)."""
    from typer.testing import CliRunner

    from proxybench.cli import app

    root = write_lab(tmp_path / "lab")
    short = run_csv(0.3).iloc[:21]  # 1 s of a 2 s episode, still on the road
    short.to_csv(root / "runs" / "a" / "0.csv", index=False)
    gone = run_csv(0.3).iloc[:21].copy()
    gone.loc[20, "y"] = 0.585 * 1.5  # its last pose on the grass tile in the middle of loop_3x3
    gone.to_csv(root / "runs" / "b" / "1.csv", index=False)
    rec = load_recording(root, ("survival_time",))
    assert rec.episodes[("a", 0)].termination == "ended_early"
    assert rec.episodes[("b", 1)].termination == "off_road"
    assert rec.episodes[("a", 1)].termination == rec.episodes[("b", 0)].termination == "timeout"
    res = CliRunner().invoke(app, ["target", "check", str(root)], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    rows = {line.split("│")[1].strip(): line for line in res.output.splitlines() if line.count("│") > 3}
    assert rows["a"].rstrip("│ ").endswith("1") and rows["b"].rstrip("│ ").endswith("1"), res.output
