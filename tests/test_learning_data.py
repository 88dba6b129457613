"""Learning data: the batched expert, recovery-data collection, and the NPZ-shard dataset format."""

from __future__ import annotations

import json

import numpy as np
import pytest

from proxybench.agents import make_agent
from proxybench.agents.base import Observation
from proxybench.domain.lane_pose import LanePose
from proxybench.domain.simulator import Simulator
from proxybench.learning.collection import CollectConfig, collect
from proxybench.learning.dataset import Dataset, DatasetError
from proxybench.learning.domains import parse_domain, proxy_domain, randomized_domain, reality_domain
from proxybench.learning.expert import expert_actions, vw_to_wheels, wheels_to_vw

W, H = 32, 24


def test_batched_expert_equals_the_zoo_pure_pursuit_agent():
    sim = Simulator("loop_3x3", reality_domain(W, H).params, n=16, render=False)
    rng = np.random.default_rng(0)
    agent = make_agent("pure-pursuit")
    for _ in range(10):
        sim.step(rng.uniform(0.1, 0.6, (16, 2)))
        batched = expert_actions(sim.lane)
        for i in range(16):
            one = agent.act(Observation(None, 0.0, lane_pose=LanePose.from_row(sim.lane[i])))
            np.testing.assert_allclose(batched[i], one, atol=1e-12)
    vw = np.array([[0.35, 1.2], [0.2, -0.5]])
    np.testing.assert_allclose(wheels_to_vw(vw_to_wheels(vw)), vw)


def test_domain_specs():
    assert parse_domain("proxy:camera_pitch=35", W, H).params.camera_pitch == 35.0
    assert parse_domain("reality", W, H).kind == "reality-model"
    fam = parse_domain("randomized", W, H)
    a, b = fam.sample(np.random.default_rng(1)), fam.sample(np.random.default_rng(2))
    assert a != b and a.image_width == W
    with pytest.raises(ValueError, match="unknown domain"):
        parse_domain("mars", W, H)


@pytest.fixture(scope="module")
def family_data() -> Dataset:
    return collect(randomized_domain(W, H), CollectConfig(samples=300, robots=8, episode_frames=20, seed=3))


def test_collection_labels_with_the_expert_while_noise_drives(family_data):
    d = family_data
    assert len(d) == 300 and d.images.shape == (300, H, W, 3) and d.images.dtype == np.uint8
    assert np.abs(d.arrays["executed"] - d.actions).mean() > 0.02  # noise injection: executed ≠ label
    assert not d.arrays["on_policy"].any()
    assert len(d.meta["thetas"]) > 1  # a family: a fresh θ per episode
    eps = d.arrays["episode"]
    assert np.all(np.diff(eps) >= 0)  # stored episode by episode
    clean = collect(proxy_domain(W, H), CollectConfig(samples=50, robots=4, noise_std=0.0))
    np.testing.assert_array_equal(clean.arrays["executed"], clean.actions)


def test_family_collection_never_regrows_histories_mid_episode(monkeypatch):
    # a regrow would restart every robot's command and blur history, corrupting the other robots' episodes
    monkeypatch.setattr(Simulator, "_grow", lambda *a: pytest.fail("simulator histories regrown mid-collection"))
    data = collect(randomized_domain(W, H), CollectConfig(samples=80, robots=4, episode_frames=10))
    assert len(data.meta["thetas"]) >= 8


def test_collection_is_reproducible():
    cfg = CollectConfig(samples=60, robots=4, seed=9)
    a, b = collect(reality_domain(W, H), cfg), collect(reality_domain(W, H), cfg)
    for k in a.arrays:
        np.testing.assert_array_equal(a.arrays[k], b.arrays[k])


def test_dataset_round_trip_keeps_arrays_and_metadata(family_data, tmp_path):
    folder = family_data.save(tmp_path / "ds", shard_size=64)
    assert len(list(folder.glob("shard-*.npz"))) == 5
    back = Dataset.load(folder, verify=True)
    for k, v in family_data.arrays.items():
        assert back.arrays[k].dtype == v.dtype
        np.testing.assert_array_equal(back.arrays[k], v)
    assert back.meta["episodes"] == json.loads(json.dumps(family_data.meta["episodes"]))
    assert back.meta["thetas"] == family_data.meta["thetas"]
    assert back.meta["domain"]["name"] == "randomized" and back.meta["collect"]["seed"] == 3
    side = json.loads((folder / "dataset.json").read_text())  # readable without proxybench
    assert side["samples"] == 300 and side["image_shape"] == [H, W, 3]
    with np.load(folder / side["shards"][0]["file"]) as z:
        assert z["images"].shape == (64, H, W, 3)
    (folder / "dataset.json").unlink()
    with pytest.raises(DatasetError, match=r"no dataset\.json"):
        Dataset.load(folder)


def test_take_gives_whole_episodes_nested_by_seed(family_data):
    small, big = family_data.take(50, seed=1), family_data.take(150, seed=1)
    assert len(small) == 50 and len(big) == 150
    first = small.arrays["episode"][0]
    assert small.arrays["frame"][small.arrays["episode"] == first][0] == 0  # an episode from its start
    assert set(np.unique(small.arrays["episode"])) <= set(np.unique(big.arrays["episode"]))
    other = family_data.take(50, seed=2)
    assert not np.array_equal(other.arrays["episode"], small.arrays["episode"])
    both = Dataset.concat([small, other])
    assert len(both) == 100 and len(both.meta["episodes"]) == len(np.unique(both.arrays["episode"]))
    with pytest.raises(DatasetError):
        family_data.take(10_000)
