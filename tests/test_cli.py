"""The command line as a user meets it: the main job, map checking and drawing, the agent list."""

from __future__ import annotations

import json
import sys

import pandas as pd
import pytest
from typer.testing import CliRunner

from proxybench.cli import app

runner = CliRunner()


def test_run_drives_the_loop_and_writes_video_strip_trajectory_and_metrics(tmp_path):
    out = tmp_path / "run"
    res = runner.invoke(app, ["run", "--seconds", "3", "--width", "80", "--height", "60", "--out", str(out)])
    assert res.exit_code == 0, res.output
    for name in ("drive.mp4", "drive_strip.png", "trajectory.parquet", "metrics.json"):
        assert (out / name).stat().st_size > 0, name
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["source"] == "simulation" and metrics["agent"] == "pid"
    assert metrics["survival_time"] == 3.0 and metrics["termination"] == "timeout"
    assert metrics["driven_lanedir_consec"] > 0.5  # ~0.3 m/s for 3 s, minus the start
    traj = pd.read_parquet(out / "trajectory.parquet")  # readable without proxybench
    assert len(traj) == 3 * 60 + 1 and {"t", "x", "y", "theta", "lateral"} <= set(traj.columns)
    assert "metrics:" in res.output


def test_run_rejects_unknown_agent_and_map(tmp_path):
    res = runner.invoke(app, ["run", "--agent", "nobody", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "unknown agent 'nobody'" in res.output
    res = runner.invoke(app, ["run", "--map", "no_such_map", "--out", str(tmp_path)])
    assert res.exit_code == 1 and "no_such_map" in res.output


def test_map_check_reports_every_problem_and_exits_1(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("tile_size: 0.585\ntiles:\n- [straight/N, grass]\n- [curve_lft/W, straight/Q]\n")
    res = runner.invoke(app, ["map", "check", "loop_3x3", str(bad)])
    assert res.exit_code == 1
    assert "✓ loop_3x3: 3×3 tiles" in res.output
    assert f"{bad}:4:4: row 1, column 0: unknown tile kind 'curve_lft'" in res.output
    assert "bad orientation 'Q'" in res.output


def test_map_check_all_builtins_pass():
    res = runner.invoke(app, ["map", "check", "loop_3x3", "small_loop", "small_loop_cw", "zigzag", "intersections",
                              "straight_road"])
    assert res.exit_code == 0, res.output


def test_map_show_writes_png(tmp_path):
    png = tmp_path / "m.png"
    res = runner.invoke(app, ["map", "show", "intersections", "-o", str(png)])
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_agent_list_shows_the_zoo():
    res = runner.invoke(app, ["agent", "list"])
    assert res.exit_code == 0
    for name in ("random", "pid", "pure-pursuit", "vision", "vision-pitch15"):
        assert name in res.output


def test_score_reads_simulated_and_recorded_runs_and_reports_bad_files(tmp_path):
    out = tmp_path / "run"
    runner.invoke(app, ["run", "--seconds", "2", "--width", "80", "--height", "60", "--no-video", "--out", str(out)])
    traj = pd.read_parquet(out / "trajectory.parquet")
    csv = tmp_path / "recorded.csv"
    traj[["t", "x", "y", "theta"]].to_csv(csv, index=False)
    res = runner.invoke(app, ["score", str(out / "trajectory.parquet"), str(csv)])
    assert res.exit_code == 0, res.output
    assert "simulation" in res.output and "recorded" in res.output
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x\n0,1\n")
    res = runner.invoke(app, ["score", str(bad)])
    assert res.exit_code == 1 and "missing column(s) y, theta" in res.output


def test_repeatability_prints_the_three_designs(tmp_path):
    res = runner.invoke(app, ["repeatability", "--runs", "2", "--seconds", "2", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    for design in ("repeatability", "inter-robot", "inter-lab"):
        assert design in res.output
    figures = json.loads((tmp_path / "repeatability.json").read_text())["figures"]
    assert figures["repeatability"]["MPD_std_cm"] <= figures["inter-robot"]["MPD_std_cm"]
    assert (tmp_path / "trajectories.png").exists() and (tmp_path / "trajectories.svg").exists()


BENCH = """
name: tiny
map: loop_3x3
episodes: {count: 2, seed: 1}
duration: 3.0
domain: {params: {image_width: 80, image_height: 60}}
camera_only: CAMERA_ONLY
metrics: [survival_time, driven_lanedir_consec]
scoring:
  - {metric: driven_lanedir_consec_median, tolerance: 0.1}
  - {metric: survival_time_median, tolerance: 0.5}
"""


def test_evaluate_prints_a_leaderboard_and_resumes(tmp_path):
    bench = tmp_path / "tiny.yaml"
    bench.write_text(BENCH.replace("CAMERA_ONLY", "false"))
    args = ["evaluate", str(bench), "--agent", "straight", "--agent", "pid", "--backend", "inline",
            "--run-dir", str(tmp_path / "run")]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    board = json.loads((tmp_path / "run" / "leaderboard.json").read_text())
    assert [r["agent"] for r in board] == ["pid", "straight"]
    assert "4 run, 0 cached" in res.output
    # beside the semiorder: Bradley–Terry scores with intervals over the 2 paired episodes, and their summary
    bt = json.loads((tmp_path / "run" / "bradley_terry.json").read_text())
    assert "BT score [95%]" in res.output and "Bradley–Terry from the 2 paired episodes" in res.output
    assert bt["episodes"] == 2 and bt["leader"] == "pid" and bt["fragility"]["text"]
    assert board[0]["bt"]["lo"] <= board[0]["bt"]["score"] <= board[0]["bt"]["hi"]
    again = runner.invoke(app, args)
    assert "0 run, 4 cached" in again.output


def test_evaluate_camera_only_refuses_privileged_agents(tmp_path):
    bench = tmp_path / "tiny.yaml"
    bench.write_text(BENCH.replace("CAMERA_ONLY", "true"))
    res = runner.invoke(app, ["evaluate", str(bench), "--agent", "straight", "--agent", "pid", "--backend",
                              "inline", "--run-dir", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    assert "not admitted: pid: privileged" in res.output
    res = runner.invoke(app, ["evaluate", str(bench), "--agent", "pid", "--backend", "inline",
                              "--run-dir", str(tmp_path / "run2")])
    assert res.exit_code == 2 and "no admitted agent" in res.output


def test_evaluate_reports_bad_benchmark_files(tmp_path):
    bench = tmp_path / "bad.yaml"
    bench.write_text(BENCH.replace("CAMERA_ONLY", "false").replace("duration: 3.0", "duration: -1"))
    res = runner.invoke(app, ["evaluate", str(bench)])
    assert res.exit_code == 1 and "bad.yaml" in res.output and "duration" in res.output


@pytest.mark.parametrize("agent", ["vision", "pid"])
def test_in_process_and_node_agents_give_identical_trajectories(tmp_path, agent):
    common = ["run", "--seconds", "3", "--width", "80", "--height", "60", "--no-video", "--seed", "4"]
    local = runner.invoke(app, [*common, "--agent", agent, "--out", str(tmp_path / "local")])
    cmd = f"{sys.executable} -m proxybench.cli agent serve {agent}"
    remote = runner.invoke(app, [*common, "--agent-cmd", cmd, "--out", str(tmp_path / "remote")])
    assert local.exit_code == 0 and remote.exit_code == 0, local.output + remote.output
    a = pd.read_parquet(tmp_path / "local" / "trajectory.parquet")
    b = pd.read_parquet(tmp_path / "remote" / "trajectory.parquet")
    cols = ["t", "x", "y", "theta", "pwm_left", "pwm_right"]
    pd.testing.assert_frame_equal(a[cols], b[cols])
    assert "agent=remote:" in remote.output


def test_agent_node_that_cannot_start_is_a_clear_error(tmp_path):
    res = runner.invoke(app, ["run", "--agent-cmd", "no-such-program-xyz", "--out", str(tmp_path)])
    assert res.exit_code == 1 and "failed to start" in res.output


def test_agent_serve_rejects_unknown_agents():
    res = runner.invoke(app, ["agent", "serve", "nobody"])
    assert res.exit_code == 2 and "cannot load agent 'nobody'" in res.output


def test_camera_only_benchmark_records_a_privileged_node_as_refused(tmp_path):
    bench = tmp_path / "tiny.yaml"
    bench.write_text(BENCH.replace("CAMERA_ONLY", "true"))
    node = f"pidnode={sys.executable} -m proxybench.cli agent serve pid"
    res = runner.invoke(app, ["evaluate", str(bench), "--agent", "straight", "--agent-cmd", node,
                              "--backend", "inline", "--run-dir", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    assert "agent failure pidnode" in res.output and "privileged" in res.output
    board = json.loads((tmp_path / "run" / "leaderboard.json").read_text())
    assert board[0]["agent"] == "straight"


def test_missing_extra_is_an_install_hint_not_a_traceback(capsys):
    import pytest
    import typer

    from proxybench.cli.app import require_extra

    with pytest.raises(typer.Exit) as exc:
        require_extra("server", ("no_such_module_xyz",))
    assert exc.value.exit_code == 2
    assert "pip install -e '.[server]'" in capsys.readouterr().err
    require_extra("server", ("json",))  # present: no exit
