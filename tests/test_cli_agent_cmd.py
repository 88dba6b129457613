"""Agent nodes from the command line as users start them: `run`, `evaluate` (and benchmark `agents:`),
`agent check`; bad start-up options are usage errors naming the option."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from proxybench.cli import app

runner = CliRunner()
NODE = Path(__file__).resolve().parent / "protocol_agents" / "zuper311_like.py"
PY = shlex.quote(sys.executable)

BENCH = """
name: tiny-nodes
map: loop_3x3
episodes: {count: 1, seed: 1}
duration: 1.0
domain: {params: {image_width: 80, image_height: 60}}
metrics: [survival_time, driven_lanedir_consec]
scoring:
  - {metric: survival_time_median, tolerance: 0.5}
"""


@pytest.fixture
def solution(tmp_path: Path) -> Path:
    sub = tmp_path / "solution"
    sub.mkdir()
    (sub / "solution.py").write_text(NODE.read_text())
    (sub / "model.bin").write_bytes(b"weights")
    return sub


def test_run_takes_a_shell_command_over_fifos(tmp_path: Path, solution: Path) -> None:
    cmd = f"cd {shlex.quote(str(solution))} && exec {PY} solution.py --print --need model.bin"
    res = runner.invoke(app, ["run", "--agent-cmd", cmd, "--transport", "fifo", "--seconds", "1", "--width", "80",
                              "--height", "60", "--no-video", "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["termination"] == "timeout" and metrics["survival_time"] == 1.0


def test_run_with_agent_cwd_and_no_reflection(tmp_path: Path, solution: Path) -> None:
    res = runner.invoke(app, ["run", "--agent-cmd", f"{PY} solution.py --need model.bin", "--agent-cwd",
                              str(solution), "--no-reflection", "--seconds", "1", "--width", "80", "--height", "60",
                              "--no-video", "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert (solution / "starts.log").read_text().count("\n") == 1  # started once: no describe_protocol


@pytest.mark.parametrize(("args", "option"), [
    (["--transport", "tcp"], "--transport"),
    (["--step-timeout", "0"], "--step-timeout"),
    (["--start-timeout", "-3"], "--start-timeout"),
    (["--agent-cwd", "/no/such/folder"], "--agent-cwd"),
])
def test_bad_start_up_options_name_the_option(tmp_path: Path, args: list[str], option: str) -> None:
    res = runner.invoke(app, ["run", "--agent-cmd", "true", *args, "--out", str(tmp_path)])
    assert res.exit_code == 2 and option in res.output, res.output


def test_agent_check_reports_the_fallback_and_the_exchanges(solution: Path) -> None:
    res = runner.invoke(app, ["agent", "check", f"{PY} solution.py --print", "--agent-cwd", str(solution),
                              "--transport", "fifo", "--seconds", "0.5"])
    assert res.exit_code == 0, res.output
    assert "describe_protocol failed" in res.output and "camera only" in res.output
    assert "8 frames" in res.output and "exchange median" in res.output


def test_agent_check_fails_with_the_nodes_words(solution: Path) -> None:
    res = runner.invoke(app, ["agent", "check", f"{PY} solution.py --need missing.bin", "--agent-cwd", str(solution)])
    assert res.exit_code == 1 and "failed to start" in res.output and "missing.bin" in res.output


def test_evaluate_runs_the_benchmark_files_agents(tmp_path: Path, solution: Path) -> None:
    bench = tmp_path / "bench.yaml"
    bench.write_text(BENCH + f"""agents:
  - straight
  - name: my-node
    command: {PY} solution.py --print --need model.bin
    cwd: solution
    transport: fifo
    reflection: false
    step_timeout: 2
""")
    res = runner.invoke(app, ["evaluate", str(bench), "--backend", "inline", "--run-dir", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    board = json.loads((tmp_path / "run" / "leaderboard.json").read_text())
    assert sorted(r["agent"] for r in board) == ["my-node", "straight"]
    assert (solution / "starts.log").read_text().count("\n") == 1


def test_evaluate_agent_cmd_takes_the_options(tmp_path: Path, solution: Path) -> None:
    bench = tmp_path / "bench.yaml"
    bench.write_text(BENCH)
    cmd = f"node=cd {shlex.quote(str(solution))} && exec {PY} solution.py --print"
    res = runner.invoke(app, ["evaluate", str(bench), "--agent-cmd", cmd, "--transport", "fifo", "--backend", "inline",
                              "--run-dir", str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    board = json.loads((tmp_path / "run" / "leaderboard.json").read_text())
    assert [r["agent"] for r in board] == ["node"]


def test_benchmark_agents_errors_name_the_entry(tmp_path: Path) -> None:
    bench = tmp_path / "bench.yaml"
    bench.write_text(BENCH + "agents:\n  - name: x\n    command: y\n    transprot: fifo\n")
    res = runner.invoke(app, ["evaluate", str(bench)])
    assert res.exit_code == 1 and "agents.0.transprot: unknown key (did you mean transport?)" in res.output
