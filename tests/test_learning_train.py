"""Behaviour cloning: training reduces the loss, checkpoints fine-tune, the agent drives, DAgger aggregates."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from proxybench.agents.simple import StraightAgent
from proxybench.domain.simulator import Simulator
from proxybench.experiments.plv.dagger import DaggerConfig, dagger
from proxybench.learning import is_checkpoint
from proxybench.learning.agent import BCAgent, make_bc_agent, torch_policy
from proxybench.learning.collection import CollectConfig, collect
from proxybench.learning.domains import proxy_domain, reality_domain
from proxybench.learning.evaluation import EvalConfig, evaluate_expert, evaluate_policy
from proxybench.learning.model import ModelConfig
from proxybench.learning.training import TrainConfig, build_model, dataset_loss, load_checkpoint, save_checkpoint, train
from proxybench.runner.episode import run_episode
from proxybench.tasks.metrics import METRICS

W, H = 32, 24
SMALL = ModelConfig(width=W, height=H, channels=(8, 12, 16, 16, 16), hidden=(32, 16))
FAST = TrainConfig(epochs=1.0, min_steps=40, max_steps=40, batch_size=32, lr=2e-3, log_every=10)


@pytest.fixture(scope="module")
def proxy_data():
    return collect(proxy_domain(W, H), CollectConfig(samples=256, robots=8, episode_frames=32, seed=1))


@pytest.fixture(scope="module")
def target_data():
    return collect(reality_domain(W, H), CollectConfig(samples=128, robots=8, episode_frames=32, seed=2))


@pytest.fixture(scope="module")
def trained(proxy_data):
    model = build_model(SMALL, seed=0, device="cpu")
    before = dataset_loss(model, proxy_data)
    res = train(model, proxy_data, FAST)
    return model, before, res


def test_training_reduces_the_loss(trained, proxy_data):
    model, before, res = trained
    after = dataset_loss(model, proxy_data)
    assert res.steps == 40 and len(res.losses) == 4
    assert after < 0.5 * before, (before, after)
    assert res.samples_per_s > 0


def test_training_is_seeded(proxy_data):
    a, b = build_model(SMALL, seed=5, device="cpu"), build_model(SMALL, seed=5, device="cpu")
    cfg = TrainConfig(epochs=1.0, min_steps=5, max_steps=5, batch_size=16, seed=7)
    train(a, proxy_data, cfg)
    train(b, proxy_data, cfg)
    for pa, pb in zip(a.parameters(), b.parameters(), strict=True):
        assert torch.equal(pa, pb)


def test_fine_tuning_from_a_checkpoint_continues_and_reduces_target_loss(trained, target_data, tmp_path):
    model, _, _ = trained
    path = save_checkpoint(tmp_path / "pre", model, {"data": {"samples": 256}})
    assert path.suffix == ".pt" and path.with_suffix(".json").exists() and is_checkpoint(path)
    assert not is_checkpoint(tmp_path / "missing.pt") and not is_checkpoint("pure-pursuit")
    loaded, info = load_checkpoint(path, "cpu")
    assert info["model"]["channels"] == list(SMALL.channels) and info["data"] == {"samples": 256}
    x = torch.rand(3, 3, H, W) - 0.5
    with torch.no_grad():
        assert torch.equal(loaded(x), model(x))  # the weights came back exactly
    before = dataset_loss(loaded, target_data)
    train(loaded, target_data, TrainConfig(epochs=1.0, min_steps=30, max_steps=30, batch_size=32, lr=1e-3))
    after = dataset_loss(loaded, target_data)
    assert after < before, (before, after)
    with torch.no_grad():
        assert not torch.equal(loaded(x), model(x))  # it trained a copy, the original is untouched


def test_vw_output_head_trains_too(proxy_data):
    model = build_model(ModelConfig(width=W, height=H, channels=SMALL.channels, hidden=SMALL.hidden, output="vw"),
                        device="cpu")
    before = dataset_loss(model, proxy_data)
    train(model, proxy_data, FAST)
    assert dataset_loss(model, proxy_data) < before
    pwm = torch_policy(model)(proxy_data.images[:4])
    assert pwm.shape == (4, 2) and np.all(np.abs(pwm) <= 1.0)


def test_bc_agent_drives_a_simulator_episode(trained, tmp_path):
    model, _, _ = trained
    path = save_checkpoint(tmp_path / "agent.pt", model)
    agent = make_bc_agent(path)
    assert isinstance(agent, BCAgent) and not agent.privileged and agent.name == "bc:agent"
    # the robot's camera is larger than the network input: frames are resampled
    sim = Simulator("loop_3x3", reality_domain(64, 48).params)
    traj = run_episode(sim, agent, seed=4, seconds=2.0, allow_privileged=False)
    assert traj.termination in ("timeout", "off_road") and not [e for e in traj.events if e.kind == "agent_failure"]
    assert len(traj) > 10 and np.isfinite(METRICS["lane_score"](traj))
    assert np.abs(traj["pwm_left"][1:]).max() > 0  # it actually commanded the wheels


@pytest.mark.parametrize("map_name", ["loop_3x3", "zigzag"])  # zigzag has objects: collisions end episodes
def test_batched_evaluation_scores_like_run_episode(map_name):
    dom = reality_domain(W, H)
    cfg = EvalConfig(episodes=3, seconds=3.0, seed=11, map=map_name)
    batched = evaluate_policy(lambda im: np.full((len(im), 2), 0.5), dom, cfg)
    sim = Simulator(cfg.map, dom.params)
    singles = [run_episode(sim, StraightAgent(0.5), cfg.seed + e, cfg.seconds) for e in range(cfg.episodes)]
    np.testing.assert_allclose(batched.scores, [METRICS["lane_score"](t) for t in singles])
    assert batched.terminations == [t.termination for t in singles]
    assert evaluate_expert(dom, cfg).mean > 0


def test_dagger_adds_on_policy_samples_labelled_by_the_expert(trained, target_data):
    model, _, _ = trained
    import copy

    learner = copy.deepcopy(model)
    data, rounds = dagger(learner, reality_domain(W, H), target_data, 64,
                          CollectConfig(samples=1, robots=8, episode_frames=16, seed=5),
                          TrainConfig(epochs=1.0, min_steps=5, max_steps=5, batch_size=32), DaggerConfig(rounds=2))
    assert len(data) == 128 + 64 and data.on_policy_count == 64 and len(rounds) == 2
    on = data.arrays["on_policy"]
    assert not np.allclose(data.arrays["executed"][on], data.actions[on])  # the learner drove, the expert labelled


def test_package_exports_are_the_functions_not_same_named_modules():
    import proxybench.learning as pl
    import proxybench.learning.training  # noqa: F401 - a submodule named like a function it exports

    assert pl.train is train
    assert pl.BCAgent is BCAgent


def test_runner_keys_follow_a_checkpoints_content(trained, tmp_path):
    import torch

    from proxybench.runner.jobs import AgentSpec, DomainSpec, Job

    model, _, _ = trained
    model = __import__("copy").deepcopy(model)
    path = save_checkpoint(tmp_path / "agent.pt", model)

    def key() -> str:
        return Job(AgentSpec(str(path)), DomainSpec("d"), "loop_3x3", 0, 1, 1.0).key

    first = key()
    assert key() == first
    with torch.no_grad():
        next(model.parameters()).add_(0.5)
    save_checkpoint(path, model)  # retrained into the same file: cached episodes must not be re-used
    assert key() != first
    assert Job(AgentSpec("pid"), DomainSpec("d"), "loop_3x3", 0, 1, 1.0).key  # zoo names need no files
