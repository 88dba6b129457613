"""A robot node as the target: episodes through the runner's robot domain, cached, recorded, and θ recovered."""

from __future__ import annotations

import shlex
import sys

import pytest

from proxybench.experiments.config import ExperimentConfig, SearchConfig
from proxybench.experiments.optimize.run import optimize_proxy
from proxybench.experiments.predictivity.run import run_predictivity
from proxybench.runner.jobs import AgentSpec
from proxybench.targets import TargetError, open_target
from proxybench.targets.record import record_target

#: a simulated robot whose trim is hidden from the optimiser and off-centre in its search range; the rest
#: at the proxies' nominal calibration
HIDDEN = {"trim": 0.12, "camera_pitch": 23, "image_width": 80, "image_height": 60, "fisheye": "true",
          "command_delay": 0.1}
ROBOT = shlex.join([sys.executable, "-m", "proxybench", "robot", "serve",
                    *[x for k, v in HIDDEN.items() for x in ("--param", f"{k}={v}")]])


def test_predictivity_against_a_robot_node_caches_its_episodes(tmp_path):
    cfg = ExperimentConfig(target=f"robot:{ROBOT}", agents=["straight", "pid"], episodes=1, seconds=2.0,
                           image_size=(80, 60), sweep={"trim": (-0.2, 0.2)}, n_boot=10, pod_seconds=0.0)
    res = run_predictivity(cfg, tmp_path / "runs")
    info = res.target.info
    assert info.kind == "robot" and res.target.ran == 2 and ROBOT in info.statement
    assert info.simulated is True and "described itself as a simulation" in info.statement
    assert res.target.truth == {} and "truth" not in str(res.claims)  # nothing known about a robot's θ
    again = run_predictivity(cfg, tmp_path / "runs")  # the robot's episodes are re-used, not driven again
    assert again.target.ran == 0 and again.frame().prpv.tolist() == res.frame().prpv.tolist()


def test_hidden_off_centre_trim_is_recovered_from_the_robot_and_from_its_recording(tmp_path):
    search = SearchConfig(space={"trim": (-0.3, 0.2)}, objective="ppv", trials=16, sampler="tpe")
    cfg = ExperimentConfig(target=f"robot:{ROBOT}", agents=["straight", "pid", "pure-pursuit"], episodes=1,
                           seconds=3.0, image_size=(80, 60), n_boot=10, search=search, truth={"trim": 0.12})
    live = optimize_proxy(cfg, tmp_path / "live")
    assert live.target_episodes_run == 3  # once, for all trials
    # privileged agents: PPV is a smooth function of trim here (0.03 at 0.122, 0.6 at 0.146, 2.5 at 0.084)
    assert abs(live.best_params["trim"] - 0.12) < 0.02 and abs(live.recovered["trim"] - 0.12) < 0.03, live.trials
    rec = tmp_path / "rec"
    record_target(rec, open_target(f"robot:{ROBOT}"), [AgentSpec(a) for a in cfg.agents], episodes=1, seconds=3.0)
    replay = optimize_proxy(cfg.model_copy(update={"target": str(rec)}), tmp_path / "replay")
    assert replay.target_episodes_run == 0 and "robot-node" in replay.target.statement
    assert [t.value for t in replay.trials] == [t.value for t in live.trials]  # same figures, no robot


def test_a_failing_robot_node_is_reported_and_nothing_recorded_is_lost(tmp_path):
    broken = shlex.join([sys.executable, "-c", "import sys; sys.exit(3)"])
    cfg = ExperimentConfig(target=f"robot:{broken}", agents=["pid"], episodes=1, seconds=1.0, sweep={"trim": (0.0,)},
                           n_boot=10, pod_seconds=0.0)
    with pytest.raises(TargetError, match=r"the robot node .* failed on 1 of 1 episode\(s\)"):
        run_predictivity(cfg, tmp_path / "runs")
    with pytest.raises(TargetError, match="the robot node failed on 1 episode"):
        record_target(tmp_path / "rec", open_target(f"robot:{broken}"), [AgentSpec("pid")], episodes=1, seconds=1.0)
    assert (tmp_path / "rec" / "target.yaml").exists()


def test_a_recording_keeps_how_its_robot_node_was_started(tmp_path):
    """Provenance: `target record --target robot:CMD` stores the node's start-up options in target.yaml, `target
    check` shows them, a resume from another working directory is refused, and a typo in them is named."""
    import yaml
    from typer.testing import CliRunner

    from proxybench.cli import app
    from proxybench.targets.manifest import load_manifest

    runner = CliRunner()
    node_dir = tmp_path / "bridge"
    node_dir.mkdir()
    rec = tmp_path / "rec"
    args = ["target", "record", "--out", str(rec), "--target", f"robot:{ROBOT}", "--agent", "straight", "--episodes",
            "1", "--seconds", "1", "--image-size", "80x60", "--backend", "inline", "--robot-transport", "fifo",
            "--robot-step-timeout", "15", "--robot-no-reflection"]
    res = runner.invoke(app, [*args, "--robot-cwd", str(node_dir)])
    assert res.exit_code == 0, res.output
    robot = load_manifest(rec).robot
    assert robot.command == ROBOT and robot.kind == "simulation"
    assert robot.options.cwd == str(node_dir.resolve()) and robot.options.transport == "fifo"
    assert robot.options.step_timeout == 15.0 and robot.options.start_timeout == 120.0  # defaults kept too
    assert robot.options.reflection is False
    stored = yaml.safe_load((rec / "target.yaml").read_text())["robot"]["options"]
    assert stored == {"cwd": str(node_dir.resolve()), "transport": "fifo", "start_timeout": 120.0,
                      "step_timeout": 15.0, "reflection": False}
    check = runner.invoke(app, ["target", "check", str(rec)])
    assert check.exit_code == 0, check.output
    line = next(x for x in check.output.splitlines() if x.startswith("robot node:"))
    assert f"cwd {node_dir.resolve()}" in line and "transport fifo" in line and "step timeout 15 s" in line
    assert "start timeout 120 s" in line and "no describe_protocol" in line and "a simulation" in line
    # resuming the recording from another working directory: another robot, perhaps; refused, nothing run
    other = tmp_path / "other"
    other.mkdir()
    res = runner.invoke(app, [*args, "--robot-cwd", str(other), "--episodes", "2"])
    assert res.exit_code == 2 and "robot.options.cwd" in res.output
    assert not (rec / "episodes" / "straight" / "1.parquet").exists()
    # a misspelt option in a hand-edited manifest names the field
    data = yaml.safe_load((rec / "target.yaml").read_text())
    data["robot"]["options"]["transprt"] = "pipe"
    (rec / "target.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(TargetError, match=r"robot\.options\.transprt: unknown key \(did you mean 'transport'\?\)"):
        load_manifest(rec)
