"""A robot node as the target: episodes through the runner's robot domain, cached, recorded, and θ recovered."""

from __future__ import annotations

import shlex
import sys

import pytest

from proxybench.runner.jobs import AgentSpec
from proxybench.targets import TargetError, open_target
from proxybench.targets.record import record_target
from proxybench.usefulness.experiment import ExperimentConfig, SearchConfig
from proxybench.usefulness.optimize import optimize_proxy
from proxybench.usefulness.predictivity import run_predictivity

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
    assert [t["value"] for t in replay.trials] == [t["value"] for t in live.trials]  # same figures, no robot


def test_a_failing_robot_node_is_reported_and_nothing_recorded_is_lost(tmp_path):
    broken = shlex.join([sys.executable, "-c", "import sys; sys.exit(3)"])
    cfg = ExperimentConfig(target=f"robot:{broken}", agents=["pid"], episodes=1, seconds=1.0, sweep={"trim": (0.0,)},
                           n_boot=10, pod_seconds=0.0)
    with pytest.raises(TargetError, match=r"the robot node .* failed on 1 of 1 episode\(s\)"):
        run_predictivity(cfg, tmp_path / "runs")
    with pytest.raises(TargetError, match="the robot node failed on 1 episode"):
        record_target(tmp_path / "rec", open_target(f"robot:{broken}"), [AgentSpec("pid")], episodes=1, seconds=1.0)
    assert (tmp_path / "rec" / "target.yaml").exists()
