"""Behaviour-cloning data collection through the episode engine: the same arrays, to the byte, as the collector
that stepped the simulator itself (digests recorded from it, on main at ad37d72, before the auto-resetting plant)."""

from __future__ import annotations

import hashlib
import json
import sys

import numpy as np
import pytest

from proxybench.learning.collection import CollectConfig, collect
from proxybench.learning.dataset import Dataset
from proxybench.learning.domains import parse_domain, proxy_domain, randomized_domain
from proxybench.runner.plants import PlantPool

W, H = 32, 24
NODE = f"{sys.executable} -m proxybench robot serve --param image_width=32 --param image_height=24"


def digest(d: Dataset) -> str:
    """Every array (name, dtype, shape, bytes) and the metadata that says what was collected (a node's command
    aside: it names the interpreter)."""
    h = hashlib.sha256()
    for k in sorted(d.arrays):
        a = np.ascontiguousarray(d.arrays[k])
        h.update(f"{k}{a.dtype}{a.shape}".encode())
        h.update(a.tobytes())
    meta = {k: d.meta[k] for k in ("episodes", "thetas", "beta", "collect")}
    meta["domain"] = {k: v for k, v in d.meta["domain"].items() if k not in ("name", "command")}  # name the python
    h.update(json.dumps(meta, sort_keys=True).encode())
    return h.hexdigest()[:16]


def learner(images: np.ndarray) -> np.ndarray:
    """A deterministic stand-in for a network: brightness steers."""
    return np.stack([images.mean(axis=(1, 2, 3)) / 255.0, np.full(len(images), 0.3)], axis=1)


def test_off_policy_family_collection_is_byte_identical_to_the_old_collector():
    data = collect(randomized_domain(W, H), CollectConfig(samples=200, robots=4, episode_frames=15, seed=3))
    assert len(data) == 200 and len(data.meta["episodes"]) > 4  # robots were reset mid-stream
    assert digest(data) == "fbbca4486e455216"


def test_on_policy_collection_is_byte_identical_to_the_old_collector():
    data = collect(proxy_domain(W, H), CollectConfig(samples=120, robots=3, episode_frames=12, seed=4),
                   policy=learner, beta=0.5)
    assert data.arrays["on_policy"].all()
    assert digest(data) == "8db8ed52f7a827fd"


@pytest.mark.slow
def test_collection_on_a_robot_node_is_byte_identical_to_the_old_collector():
    robot = parse_domain(f"robot:{NODE}", W, H)
    with PlantPool() as pool:
        off = collect(robot, CollectConfig(samples=50, episode_frames=20, seed=3), pool=pool)
        on = collect(robot, CollectConfig(samples=80, episode_frames=60, seed=5), pool=pool,
                     policy=lambda im: np.tile([1.0, 0.3], (len(im), 1)))  # leaves the road: episodes end early
    assert digest(off) == "98f765149e12aa77"
    assert np.bincount(on.arrays["episode"]).tolist() == [13, 16, 13, 20, 18]
    assert digest(on) == "60733700239a96ed"
