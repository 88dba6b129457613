"""Node start-up options wherever a node command is accepted: robot nodes (`run --robot-cmd`, `--target
robot:CMD`, the experiment file's `robot_options`, the runner's robot domain) and agent nodes given as
benchmark-style entries in an experiment file. Bad options are errors naming the option or field."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.domain.params import DomainParams
from proxybench.experiments.agent_args import parse_agents
from proxybench.experiments.config import ConfigError, load_config, resolve
from proxybench.protocol.options import RobotNodeOptions
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
from proxybench.runner.sweep import run_jobs
from proxybench.targets import TargetError, open_target
from support.jobs import worker_job

runner = CliRunner()
HERE = Path(__file__).resolve().parent
NODE = HERE / "protocol_agents" / "zuper311_like.py"
MAPS = HERE.parent / "src" / "proxybench" / "maps"
PY = shlex.quote(sys.executable)
#: a robot node as users start theirs: it prints on stdout as it boots (so only the FIFO transport works)
#: and needs a file of its working directory (so only the right --robot-cwd works)
ROBOT = (f"echo 'bridge: booting' && exec {PY} -m proxybench robot serve --map local.yaml "
         "--param image_width=80 --param image_height=60")


@pytest.fixture
def bridge(tmp_path: Path) -> Path:
    """The robot node's folder: the map file it is started with."""
    folder = tmp_path / "bridge"
    folder.mkdir()
    (folder / "local.yaml").write_text((MAPS / "loop_3x3.yaml").read_text())
    return folder


# ------------------------------------------------------------------------------------- robot nodes
def test_run_robot_cmd_takes_cwd_fifo_and_timeouts(tmp_path: Path, bridge: Path) -> None:
    base = ["run", "--robot-cmd", ROBOT, "--seconds", "1", "--out", str(tmp_path / "out")]
    res = runner.invoke(app, [*base, "--robot-cwd", str(bridge), "--robot-transport", "fifo",
                              "--robot-start-timeout", "60", "--robot-no-reflection"])
    assert res.exit_code == 0, res.output
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["termination"] == "timeout" and metrics["survival_time"] == 1.0
    assert metrics["robot_options"] == {"cwd": str(bridge), "transport": "fifo", "start_timeout": 60.0,
                                        "reflection": False}
    over_pipes = runner.invoke(app, [*base, "--robot-cwd", str(bridge)])  # its boot message breaks the pipe
    assert over_pipes.exit_code == 1 and "garbage" in over_pipes.output and "fifo" in over_pipes.output


@pytest.mark.parametrize(("args", "option", "says"), [
    (["--robot-transport", "fifo"], "--robot-transport", "only with --robot-cmd"),
    (["--robot-cmd", "x", "--robot-transport", "tcp"], "--robot-transport", "'pipe' or 'fifo'"),
    (["--robot-cmd", "x", "--robot-step-timeout", "0"], "--robot-step-timeout", "greater than 0"),
    (["--robot-cmd", "x", "--robot-cwd", "/no/such/dir"], "--robot-cwd", "is not a directory"),
])
def test_bad_robot_options_are_usage_errors_naming_the_option(tmp_path: Path, args, option, says) -> None:
    res = runner.invoke(app, ["run", *args, "--out", str(tmp_path / "out")], env={"COLUMNS": "200"})
    assert res.exit_code == 2 and option in res.output and says in res.output, res.output
    assert not (tmp_path / "out" / "metrics.json").exists()


def test_robot_domain_carries_its_options_and_only_cwd_is_in_the_key() -> None:
    plain = DomainSpec.robot("bridge", frame_rate=15)
    slow = DomainSpec.robot("bridge", frame_rate=15, options=RobotNodeOptions(step_timeout=30, transport="fifo"))
    moved = DomainSpec.robot("bridge", frame_rate=15, options=RobotNodeOptions(cwd="/opt/bridge"))
    faster = DomainSpec.robot("bridge", frame_rate=30)
    assert slow.link.node_options().step_timeout == 30.0 and plain.link.node_options().start_timeout == 120.0
    assert plain.canonical() == slow.canonical() != moved.canonical()  # cached episodes survive a new timeout
    assert plain.canonical() == json.dumps({"command": "bridge", "kind": "robot", "params": {}})  # as before links
    assert faster.canonical() != plain.canonical() and faster.frame_rate == 30.0  # asked to step at another rate
    with pytest.raises(TypeError, match="a simulated domain, not options"):
        DomainSpec("s", options=(("transport", "fifo"),))


def test_robot_domain_jobs_start_the_node_with_its_options(tmp_path: Path, bridge: Path) -> None:
    job = lambda dom: Job(AgentSpec("straight"), dom, "loop_3x3", 0, 1, 0.5)  # noqa: E731
    good = DomainSpec.robot(ROBOT, frame_rate=15, options=RobotNodeOptions(cwd=str(bridge), transport="fifo"))
    (res,) = run_jobs([job(good)], tmp_path / "good").results
    assert res.termination == "timeout", res.message
    (bad,) = run_jobs([job(DomainSpec.robot(ROBOT, frame_rate=15, options=RobotNodeOptions(transport="fifo")))],
                      tmp_path / "bad").results  # no local.yaml where it starts
    assert bad.termination == "robot_failure" and "local.yaml" in bad.message


def test_experiment_file_robot_options(tmp_path: Path, bridge: Path) -> None:
    exp = tmp_path / "exp.yaml"
    exp.write_text(f"target: {json.dumps('robot:' + ROBOT)}\n"
                   "robot_options: {cwd: bridge, transport: fifo, start_timeout: 60}\n")
    cfg = load_config(exp, {"robot_options": {"step_timeout": 3.0}})  # the command line changes one field
    assert cfg.robot_options == RobotNodeOptions(cwd=str(bridge), transport="fifo", start_timeout=60, step_timeout=3)
    _, target = resolve(cfg, "predictivity", quick=True, work_dir=tmp_path / "agents")
    assert target.domain().link.node_options() == cfg.robot_options
    assert target.info().details["options"]["cwd"] == str(bridge)  # in every report's details
    exp.write_text("robot_options: {transprot: fifo, step_timeout: -1}\n")
    with pytest.raises(ConfigError) as info:
        load_config(exp)
    assert "robot_options.transprot: unknown key (did you mean 'transport'?)" in str(info.value)
    assert "robot_options.step_timeout" in str(info.value)
    with pytest.raises(TargetError, match=r"robot_options .*only a robot node"):
        open_target("reality", robot_options=RobotNodeOptions(transport="fifo"))


def test_predictivity_cli_passes_robot_options_to_the_target(tmp_path: Path, bridge: Path) -> None:
    res = runner.invoke(app, ["predictivity", "--target", f"robot:{ROBOT}", "--robot-cwd", str(bridge),
                              "--robot-transport", "fifo", "--agent", "straight", "--episodes", "1", "--seconds", "1",
                              "--image-size", "80x60", "--sweep", "trim=0", "--n-boot", "10", "--pod-seconds", "0",
                              "--backend", "inline", "--out", str(tmp_path / "out")], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    assert "robot node" in res.output
    wrong = runner.invoke(app, ["predictivity", "--robot-transport", "fifo", "--out", str(tmp_path / "x")],
                          env={"COLUMNS": "200"})
    assert wrong.exit_code == 2 and "only a robot node" in wrong.output


@pytest.mark.slow
def test_evaluator_target_jobs_start_the_robot_node_with_its_options(tmp_path: Path, bridge: Path) -> None:
    """`proxybench evaluator --robot-cmd CMD --robot-cwd DIR --robot-transport fifo`: the compliance check and
    the episodes start the node that way (the job's config carries the options to the worker)."""
    from proxybench.evaluator.compliance import check_robot
    from proxybench.evaluator.report import summarize
    from proxybench.evaluator.run import _Job
    from proxybench.runner.evaluate import evaluate_benchmark
    from proxybench.tasks.benchmark import Benchmark

    bench = Benchmark.from_dict({
        "name": "tiny_robot", "map": "loop_3x3", "episodes": {"count": 1, "seed": 1}, "duration": 1.0,
        "domain": {"params": {"image_width": 80, "image_height": 60}}, "metrics": ["survival_time"],
        "scoring": [{"metric": "survival_time_median"}]})
    options = _Job(tmp_path, worker_job(robot_options={"cwd": str(bridge), "transport": "fifo"})).robot_options()
    assert options == RobotNodeOptions(cwd=str(bridge), transport="fifo")
    report = check_robot(bench, ROBOT, options=options)
    assert report.ok, report.failures()
    plain = check_robot(bench, ROBOT)  # over a pipe, from here: no local.yaml, and its boot message
    assert not plain.ok and "the robot node failed" in plain.failures()
    ev = evaluate_benchmark(bench, [AgentSpec("pid")], tmp_path / "run",
                            domain=DomainSpec.robot(ROBOT, frame_rate=bench.frame_rate, options=options))
    summary = summarize(ev, "validation", domain_kind=report.domain_kind)
    assert summary.problems == [] and summary.failures == []
    res = runner.invoke(app, ["repeatability", "--agent", "pid", "--robot-cmd", f"r1={ROBOT}", "--robot-cwd",
                              str(bridge), "--robot-transport", "fifo", "--runs", "2", "--seconds", "1", "--out",
                              str(tmp_path / "rep")], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output


# ------------------------------------------------------------------------ agents in the experiment file
def _solution(tmp_path: Path) -> Path:
    sub = tmp_path / "submissions" / "lf"
    sub.mkdir(parents=True)
    (sub / "solution.py").write_text(NODE.read_text())
    (sub / "model.bin").write_bytes(b"weights")
    return sub


def test_experiment_agents_take_benchmark_entries_with_node_options(tmp_path: Path) -> None:
    sub = _solution(tmp_path)
    exp = tmp_path / "exp.yaml"  # the submission lies inside the file's folder (a cwd may not leave it)
    exp.write_text(f"""
agents:
  - pid
  - {{name: vision}}
  - quick=python3 agent.py
  - name: lf
    command: {PY} solution.py --print --need model.bin
    cwd: submissions/lf
    transport: fifo
    step_timeout: 2
    reflection: false
""")
    cfg = load_config(exp)
    specs = parse_agents(cfg.agents)
    assert [s.label for s in specs] == ["pid", "vision", "quick", "lf"]
    assert specs[1] == AgentSpec("vision") and specs[2] == AgentSpec.node("quick", "python3 agent.py")
    options = specs[3].node_options()
    assert (options.cwd, options.transport, options.step_timeout, options.reflection) == (str(sub), "fifo", 2.0,
                                                                                          False)
    # the node runs with them: it prints to stdout (fine over FIFOs) and needs a file of its folder
    (res,) = run_jobs([Job(specs[3], DomainSpec("small", DomainParams(image_width=80, image_height=60)), "loop_3x3", 0,
                           1, 0.5)], tmp_path / "runs").results
    assert res.termination == "timeout", res.message


@pytest.mark.parametrize(("entry", "says"), [
    ("{name: lf, command: x, transprot: fifo}", "agents.1.transprot: unknown key (did you mean 'transport'?)"),
    ("{name: lf, command: x, step_timeout: 0}", "agents.1.step_timeout: Input should be greater than 0"),
    ("{name: vision, cwd: sub}", "agents.1: cwd: start-up options need a command"),
    ("{command: x}", "agents.1.name: required, missing"),
])
def test_bad_agent_entries_name_the_field(tmp_path: Path, entry: str, says: str) -> None:
    exp = tmp_path / "exp.yaml"
    exp.write_text(f"agents:\n  - pid\n  - {entry}\n")
    with pytest.raises(ConfigError) as info:
        load_config(exp)
    assert f"{exp}: {says}" in str(info.value)


def test_a_node_entry_without_cwd_runs_in_the_files_folder(tmp_path: Path) -> None:
    exp = tmp_path / "exp.yaml"
    exp.write_text("agents: [{name: lf, command: python3 solution.py}]\n")
    (spec,) = parse_agents(load_config(exp).agents)
    assert spec.node_options().cwd == str(tmp_path)
    over = load_config(exp, {"agents": ["lf=python3 solution.py"]})  # the command line's agents replace the file's
    assert parse_agents(over.agents)[0].node_options().cwd is None


def test_serve_passes_robot_options_to_its_local_evaluators(tmp_path: Path, bridge: Path, monkeypatch) -> None:
    """`proxybench serve --evaluators 2 --robot-cmd CMD --robot-*`: each evaluator it starts gets the robot node
    and every option, and parses them back to the same RobotNodeOptions (nothing is started here)."""
    import subprocess

    import uvicorn

    started: list[list[str]] = []

    class FakeProcess:
        def __init__(self, cmd: list[str], **_kw) -> None:
            started.append(cmd)

        def terminate(self) -> None: ...

        def wait(self, _timeout: float | None = None) -> int:
            return 0

    monkeypatch.setattr(subprocess, "Popen", FakeProcess)
    monkeypatch.setattr(uvicorn, "run", lambda *a, **kw: None)
    data = tmp_path / "server"
    options = ["--robot-cwd", str(bridge), "--robot-transport", "fifo", "--robot-start-timeout", "200",
               "--robot-step-timeout", "12.5", "--robot-no-reflection"]
    res = runner.invoke(app, ["serve", "--data-dir", str(data), "--workers", "1", "--evaluators", "2",
                              "--robot-cmd", ROBOT, *options])
    assert res.exit_code == 0, res.output
    assert len(started) == 2 and "target jobs on the robot node" in res.output
    want = RobotNodeOptions(cwd=str(bridge.resolve()), transport="fifo", start_timeout=200, step_timeout=12.5,
                            reflection=False)
    import proxybench.evaluator as evaluator_pkg

    seen = []

    class FakeEvaluator:
        stop_reason = None

        def __init__(self, server, secret, config, reporter) -> None:
            seen.append(config)

        def install_signal_handlers(self) -> None: ...

        def run(self, once: bool = False) -> int:
            return 0

    monkeypatch.setattr(evaluator_pkg, "Evaluator", FakeEvaluator)
    for k, cmd in enumerate(started):
        assert cmd[1:4] == ["-m", "proxybench.cli", "evaluator"] and cmd[cmd.index("--robot-cmd") + 1] == ROBOT
        res = runner.invoke(app, cmd[3:], env={"PROXYBENCH_TOKEN": None, "PROXYBENCH_TOKEN_FILE": None})
        assert res.exit_code == 0, res.output
        assert seen[k].name == f"local-{k + 1}" and seen[k].robot_cmd == ROBOT
        assert RobotNodeOptions(**seen[k].robot_options) == want  # every option arrived, the same
    # options need the command, and the command needs local evaluators to use it
    res = runner.invoke(app, ["serve", "--data-dir", str(data), "--workers", "1", "--evaluators", "1", *options[:2]])
    assert res.exit_code == 2 and "--robot-cwd" in res.output and "only with --robot-cmd" in res.output
    res = runner.invoke(app, ["serve", "--data-dir", str(data), "--workers", "1", "--robot-cmd", ROBOT])
    assert res.exit_code == 2 and "--robot-cmd" in res.output and "only with --evaluators" in res.output
    assert len(started) == 2  # nothing more was started
