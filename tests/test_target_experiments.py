"""Recording targets, and predictivity / optimisation against recorded targets (tiny configs)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.runner.jobs import AgentSpec
from proxybench.targets import RealityTarget, TargetError, check_recording
from proxybench.targets.record import record_target
from support.sandbox import AGENT_USER_GROUP

runner = CliRunner()
TINY = {"episodes": 2, "seconds": 3.0, "n_boot": 30, "pod_seconds": 0.0,
        "agents": ["straight", "pid", "pid-fast", "vision"], "sweep": {"trim": [-0.3, 0.0, 0.3]}}


def test_recording_resumes_after_an_interruption_and_extends(tmp_path):
    out = tmp_path / "rec"
    agents = [AgentSpec("straight"), AgentSpec("pid")]
    calls = []

    def interrupt(done, total):
        calls.append(done)
        if done >= 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        record_target(out, RealityTarget(), agents, episodes=2, seconds=2.0, progress=interrupt)
    first = sorted(p.relative_to(out).as_posix() for p in (out / "episodes").rglob("*.parquet"))
    assert first and (out / "target.yaml").exists()  # what finished is kept, and the directory says what it is
    report = check_recording(out)
    assert not report.ok and any("missing (agent" in p for p in report.problems)

    again = record_target(out, RealityTarget(), agents, episodes=2, seconds=2.0)
    assert again.kept == len(first) and again.kept + again.recorded == 4
    assert check_recording(out).ok and not (out / ".record").exists()

    more = record_target(out, RealityTarget(), [AgentSpec("vision")], episodes=2, seconds=2.0)
    assert more.kept == 4 and more.recorded == 2 and more.manifest.agents == ["straight", "pid", "vision"]
    with pytest.raises(TargetError, match=r"seconds: this recording has 2\.0, the command asks for 3\.0"):
        record_target(out, RealityTarget(), agents, episodes=2, seconds=3.0)
    with pytest.raises(TargetError, match="which need the new episodes too: give them again"):
        record_target(out, RealityTarget(), agents, episodes=3, seconds=2.0)


def test_round_trip_recorded_reality_model_gives_the_live_figures(tmp_path):
    cfg = tmp_path / "exp.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    rec = tmp_path / "rec"
    res = runner.invoke(app, ["target", "record", "--out", str(rec), "--target", "reality", "--episodes", "2",
                              "--seconds", "3",
                              "--backend", "inline", *[x for a in TINY["agents"] for x in ("--agent", a)]])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["target", "check", str(rec)])
    assert res.exit_code == 0 and "SIMULATED runs of proxybench's reality model" in res.output, res.output
    live = runner.invoke(app, ["predictivity", "--config", str(cfg), "--out", str(tmp_path / "live"),
                               "--backend", "inline"])
    assert live.exit_code == 0, live.output
    replay = runner.invoke(app, ["predictivity", "--config", str(cfg), "--target", str(rec),
                                 "--out", str(tmp_path / "replay"), "--backend", "inline"])
    assert replay.exit_code == 0, replay.output
    a = pd.read_csv(tmp_path / "live" / "usefulness.csv")
    b = pd.read_csv(tmp_path / "replay" / "usefulness.csv")
    assert a.ppv.nunique() > 1  # the figures vary with θ: the comparison is not between constants
    for col in ("prpv", "prpv_low", "prpv_high", "ppv", "ppv_low", "ppv_high", "pearson", "pearson_low", "pearson_high",
                "kendall", "delta_best"):
        np.testing.assert_array_equal(a[col].to_numpy(), b[col].to_numpy(), err_msg=col)
    html = (tmp_path / "replay" / "report.html").read_text()
    assert f"The target is a recording at {rec.resolve()} (source: reality-model)" in html
    assert "SIMULATED TARGET" in html and "noise floor" in html


def test_predictivity_against_a_lab_csv_recording_replays_its_starts(tmp_path):
    from proxybench.experiments.config import ExperimentConfig
    from proxybench.experiments.predictivity.run import run_predictivity

    root = tmp_path / "lab"
    y = 0.585 * 0.5 - 0.22 * 0.585
    man = {"source": "real", "map": "loop_3x3", "seconds": 2.0, "agents": ["pid", "straight"], "episodes": [0, 1],
           "trajectories": "{agent}_{episode}.csv", "who": "lab", "where": "room 1", "when": "2024-05-14"}
    root.mkdir()
    (root / "target.yaml").write_text(yaml.safe_dump(man))
    for agent, v in (("pid", 0.3), ("straight", 0.2)):
        for ep in (0, 1):
            t = np.linspace(0, 2.0, 41)
            x0 = 0.5 + 0.1 * ep
            pd.DataFrame({"time": t, "x": x0 + v * t, "y": np.full(41, y), "yaw": 0 * t}).to_csv(
                root / f"{agent}_{ep}.csv", index=False)
    cfg = ExperimentConfig(target=str(root), sweep={"trim": (-0.2, 0.0)}, n_boot=20, pod_seconds=0.0)
    res = run_predictivity(cfg, tmp_path / "runs")
    assert res.target.ran == 0 and res.target.info.simulated is False  # no simulation for the target
    assert [(e.agent, e.episode, e.pose[0]) for e in res.target.episodes] == [
        ("pid", 0, 0.5), ("pid", 1, 0.6), ("straight", 0, 0.5), ("straight", 1, 0.6)]
    traj = pd.read_parquet(next((tmp_path / "runs" / "episodes").glob("*.parquet")))
    assert traj.x.iloc[0] in (0.5, 0.6) and traj.y.iloc[0] == pytest.approx(y)  # the proxy started there
    assert res.experiment.seconds == 2.0 and np.isnan(res.frame().pod).all()
    with pytest.raises(TargetError, match="seconds: the target's episodes last 2 s, the experiment asks for 5 s"):
        run_predictivity(cfg.model_copy(update={"seconds": 5.0}), tmp_path / "runs")
    with pytest.raises(TargetError, match="map: the target was recorded on 'loop_3x3', the experiment asks for"):
        run_predictivity(cfg.model_copy(update={"map": "zigzag"}), tmp_path / "runs")
    with pytest.raises(TargetError, match="agents: 'vision' not in the recorded target"):
        run_predictivity(cfg.model_copy(update={"agents": ["vision"]}), tmp_path / "runs")
    with pytest.raises(TargetError, match="episodes: 5 asked, the target has 2 per agent"):
        run_predictivity(cfg.model_copy(update={"episodes": 5}), tmp_path / "runs")


def test_a_recorded_target_with_agents_proxybench_cannot_run_says_how_to_name_them(tmp_path):
    from proxybench.experiments.config import ExperimentConfig, resolve

    root = tmp_path / "lab"
    root.mkdir()
    (root / "target.yaml").write_text(yaml.safe_dump(
        {"source": "real", "map": "loop_3x3", "seconds": 2.0, "agents": ["my-agent"], "episodes": [0],
         "metrics_table": "s.csv"}))
    with pytest.raises(TargetError, match=r"agents: the target's agent 'my-agent' is not a zoo agent.*--agent"):
        resolve(ExperimentConfig(target=str(root)), "predictivity")
    exp, _ = resolve(ExperimentConfig(target=str(root), agents=["my-agent=python3 agent.py"]), "predictivity")
    assert exp.agents == [AgentSpec.node("my-agent", "python3 agent.py")]


def test_optimize_against_a_recorded_target_reads_it_once(tmp_path):
    from proxybench.experiments.config import ExperimentConfig, SearchConfig
    from proxybench.experiments.optimize.run import optimize_proxy

    rec = tmp_path / "rec"
    record_target(rec, RealityTarget(), [AgentSpec("straight"), AgentSpec("pid")], episodes=1, seconds=2.0)
    cfg = ExperimentConfig(target=str(rec), n_boot=10,
                           search=SearchConfig(space={"trim": (-0.3, 0.2)}, trials=3, sampler="random"))
    res = optimize_proxy(cfg, tmp_path / "runs")
    assert len(res.trials) == 3 and res.target_episodes_run == 0
    assert res.truth == {"trim": 0.0}  # the recording's declared truth, for annotation
    assert "recording" in res.target.statement


def test_cli_reports_bad_targets_and_configs_by_name(tmp_path):
    res = runner.invoke(app, ["target", "check", str(tmp_path)])
    assert res.exit_code == 1 and "has no target.yaml" in res.output
    bad = tmp_path / "exp.yaml"
    bad.write_text("episodes: 2\nsweep: {trim: [0.0]}\nn_bot: 5\n")
    res = runner.invoke(app, ["predictivity", "--config", str(bad), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and f"{bad}: n_bot: unknown key (did you mean 'n_boot'?)" in res.output
    res = runner.invoke(app, ["optimize", "--target", str(tmp_path / "none"), "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "is not 'reality', 'robot:COMMAND', 'dtps:HOST[:PORT]/PATH' or an" in res.output
    res = runner.invoke(app, ["predictivity", "--agent", "nobody", "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "agents: agent 'nobody' is not a zoo agent" in res.output
    res = runner.invoke(app, ["predictivity", "--sweep", "trim=a,b", "--out", str(tmp_path / "o")])
    assert res.exit_code == 2 and "expected NAME=V1,V2" in res.output
    record = ["target", "record", "--out", str(tmp_path / "r"), "--agent", "pid"]
    res = runner.invoke(app, [*record, "--target", "reality", "--robot-cmd", "x"])  # the old flag beside the new
    assert res.exit_code == 2 and "give one target: --target reality | robot:CMD" in res.output
    res = runner.invoke(app, [*record, "--target", "robot:", "--robot-cwd", str(tmp_path)])
    assert res.exit_code == 2 and "robot: needs the command that starts the robot node" in res.output
    res = runner.invoke(app, [*record, "--robot-cwd", str(tmp_path)])  # no robot node to start with them
    assert res.exit_code == 2 and "only with --target robot:CMD" in res.output
    res = runner.invoke(app, [*record, "--target", str(tmp_path / "none")])
    assert res.exit_code == 2 and "is not 'reality', 'robot:COMMAND'" in res.output
    res = runner.invoke(app, [*record, "--dtps-reset", "teleport"])
    assert res.exit_code == 2 and "only with --target dtps:" in res.output
    res = runner.invoke(app, [*record, "--dtps", "bot.local/bot", "--dtps-option", "watchdg=1"])  # the old flag
    assert res.exit_code == 2 and "--dtps is deprecated: say --target dtps:bot.local/bot" in res.output
    assert "unknown option 'watchdg'" in res.output


def test_score_saves_its_table_and_the_table_is_a_metrics_target(tmp_path):
    rec = tmp_path / "rec"
    record_target(rec, RealityTarget(), [AgentSpec("pid")], episodes=1, seconds=1.0)
    table = tmp_path / "scores.csv"
    res = runner.invoke(app, ["score", str(rec / "episodes" / "pid" / "0.parquet"), "--out", str(table)])
    assert res.exit_code == 0, res.output
    df = pd.read_csv(table)
    assert list(df.agent) == ["pid"] and df.survival_time.iloc[0] == pytest.approx(1.0)
    res = runner.invoke(app, ["score", str(rec / "episodes" / "pid" / "0.parquet"), "--out", str(tmp_path / "x.txt")])
    assert res.exit_code == 2 and ".csv or .parquet" in res.output
    lab = tmp_path / "lab"
    lab.mkdir()
    df.assign(episode=0).to_csv(lab / "scores.csv", index=False)
    man = {"source": "real", "map": "loop_3x3", "seconds": 1.0, "agents": ["pid"], "episodes": [0],
           "metrics_table": "scores.csv"}
    (lab / "target.yaml").write_text(yaml.safe_dump(man))
    assert check_recording(lab).ok


FORWARD_NODE = """\
import sys
import numpy as np
from proxybench.agents.base import Agent
from proxybench.protocol import serve

class Forward(Agent):
    name = "forward"
    def reset(self, seed, episode=None):
        pass
    def act(self, obs):
        return np.array([0.3, 0.3])

sys.exit(serve(Forward()))
"""


@AGENT_USER_GROUP
def test_an_agent_package_runs_sandboxed_in_predictivity(tmp_path):
    import io
    import zipfile

    from proxybench.experiments.config import ExperimentConfig
    from proxybench.experiments.predictivity.run import run_predictivity
    from support.sandbox import require_safe_sandbox

    require_safe_sandbox()
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("proxybench-agent.yaml", "name: forward\nprotocol: aido-z2\ncommand: [python3, agent.py]\n")
        zf.writestr("agent.py", FORWARD_NODE)
    pkg = tmp_path / "forward.zip"
    pkg.write_bytes(buf.getvalue())
    cfg = ExperimentConfig(agents=["pid", str(pkg)], episodes=1, seconds=1.0, sweep={"trim": (0.0,)}, n_boot=10,
                           pod_seconds=0.0)
    res = run_predictivity(cfg, tmp_path / "out" / "runs")
    assert res.experiment.agent_labels == ["pid", "forward"]
    assert "_confine.py" in res.experiment.agents[1].command  # started through the sandbox's shim
    assert res.target_scores["forward"]["survival_time"] == pytest.approx(1.0)  # it drove, no agent failure
    bad = tmp_path / "bad.zip"
    bad.write_bytes(b"not a zip")
    with pytest.raises(TargetError, match=r"agent package .*bad\.zip"):
        run_predictivity(cfg.model_copy(update={"agents": [str(bad)]}), tmp_path / "out" / "runs")
