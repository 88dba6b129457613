"""PLV against a robot node: target samples collected on the node (the expert reads the lane pose it serves), every
network scored on it, through the runner's episode engine. The node is `proxybench robot serve` (a simulated
robot), so its episodes can be checked against the in-process simulator."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from proxybench.domain.params import DomainParams
from proxybench.learning.collection import CollectConfig, collect
from proxybench.learning.domains import Domain, parse_domain
from proxybench.learning.evaluation import EvalConfig, evaluate_expert, evaluate_policy
from proxybench.runner.plants import PlantPool

NODE = f"{sys.executable} -m proxybench robot serve --param image_width=32 --param image_height=24"


def test_collection_and_evaluation_on_a_robot_node_go_through_the_engine():
    robot = parse_domain(f"robot:{NODE}", 32, 24)
    assert robot.kind == "robot" and Domain.from_description(robot.describe()) == robot
    same = Domain("node's θ in-process", "simulation", params=DomainParams(image_width=32, image_height=24))
    turning = lambda images: np.tile([0.25, 0.45], (len(images), 1))  # noqa: E731 - drives off the lane in time
    ecfg = EvalConfig(episodes=2, seconds=4.0)
    with PlantPool() as pool:
        data = collect(robot, CollectConfig(samples=50, episode_frames=20, seed=3), pool=pool)
        on_node = evaluate_policy(turning, robot, ecfg, pool=pool)
        expert = evaluate_expert(robot, ecfg, pool=pool)
    assert len(data) == 50 and data.arrays["images"].shape == (50, 24, 32, 3)
    assert data.meta["domain"]["kind"] == "robot" and len(data.meta["episodes"]) >= 3  # 20-frame episodes
    assert np.all(np.abs(data.arrays["actions"]) <= 1.0) and not data.arrays["on_policy"].any()
    assert not np.allclose(data.arrays["executed"], data.arrays["actions"])  # the expert's command plus noise
    in_process = evaluate_policy(turning, same, ecfg)
    np.testing.assert_allclose(on_node.scores, in_process.scores, atol=1e-6)  # the node is this simulator
    np.testing.assert_allclose(expert.scores, evaluate_expert(same, ecfg).scores, atol=1e-6)  # the lane pose it serves
    assert on_node.mean < expert.mean


def _tiny(node: str, proxies: dict[str, str]):
    """A PLV run of networks with a few hundred weights against ``node``: minutes, not hours."""
    from proxybench.experiments.plv.run import PLVConfig

    return PLVConfig.from_dict({"width": 32, "height": 24, "ladder": [30, 60], "seeds": [0, 1], "proxy_samples": 60,
                                "proxies": proxies, "target": f"robot:{node}",
                                "model": {"channels": [8, 8, 8, 8, 8], "hidden": [16]},
                                "train": {"min_steps": 2, "max_steps": 2}, "pretrain": {"min_steps": 2, "max_steps": 2},
                                "finetune": {"min_steps": 2, "max_steps": 2},
                                "collect": {"robots": 8, "episode_frames": 20},
                                "eval": {"episodes": 1, "seconds": 1.0}, "replicates": 100})


def test_plv_with_a_robot_node_as_the_target(tmp_path):
    pytest.importorskip("torch")
    from proxybench.experiments.plv.report import summarize
    from proxybench.experiments.plv.run import run_plv

    cfg = _tiny(NODE, {"pitch 30°": "proxy:camera_pitch=30"})
    res = run_plv(cfg, tmp_path)
    assert {r["arm"] for r in res.runs} == {"target-only", "pitch 30°"}
    s = summarize(res)
    assert s.target_label.startswith("robot node") and s.rows[0].status in ("ok", "not reached")
    data = (tmp_path / "cache" / cfg.work_key() / "data" / "target" / "dataset.json").read_text()
    assert '"kind": "robot"' in data  # the target samples came from the node


@pytest.mark.slow
def test_plv_against_a_gym_duckietown_node(tmp_path):
    """The gym node serves its robot's lane pose: the expert reads it; skipped without gym's environment."""
    pytest.importorskip("torch")
    from proxybench.gym.environment import check_environment

    env = check_environment(render=False)
    if not env.ok:
        pytest.skip("gym-duckietown's environment is not ready (`proxybench gym setup`): " + "; ".join(env.problems))
    from proxybench.experiments.plv.run import run_plv

    gym = f"{sys.executable} -m proxybench.cli gym serve --param camera_width=64 --param camera_height=48"
    cfg = _tiny(gym, {"nominal": "proxy"})
    res = run_plv(cfg, tmp_path)
    assert {r["arm"] for r in res.runs} == {"target-only", "nominal"} and res.expert_score > 0
    meta = (tmp_path / "cache" / cfg.work_key() / "data" / "target" / "dataset.json").read_text()
    assert "gym serve" in meta  # the target samples came from gym-duckietown
