"""Served agents in child processes driven by AgentProcess / RemoteAgent: same commands as in-process."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from proxybench.agents.base import Observation
from proxybench.agents.pid import LanePIDAgent
from proxybench.domain.lane_pose import LanePose
from proxybench.protocol import AgentFailure, AgentProcess, ProtocolUsageError, RemoteAgent, jpeg
from test_protocol_node import AGENTS

PIXEL = [sys.executable, str(Path(__file__).resolve().parent / "protocol_agents" / "pixel_agent.py")]


def frames(n: int, seed: int = 0, shape: tuple[int, int] = (120, 160)) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    h, w = shape
    base = np.linspace(0, 200, w)[None, :, None] + np.linspace(0, 40, h)[:, None, None]
    return [np.clip(base + 20 * np.sin(k + np.arange(3)) + rng.normal(0, 6, (h, w, 3)), 0, 255).astype(np.uint8)
            for k in range(n)]


def lane_pose(k: int) -> LanePose:
    return LanePose(True, k % 3, 0.1 * k, 0.01 * np.sin(k), -0.02 * k, True, True, True, True, True, (k, 1), 0.5)


def episode_obs(k: int, image: np.ndarray | None, privileged: bool = False) -> Observation:
    return Observation(image, k / 15, (0.04 * k, 0.05 * k), 0.0465, lane_pose(k) if privileged else None)


def drive(agent, seeds: list[int], steps: int, roundtrip: bool, privileged: bool = False) -> list[np.ndarray]:
    """Runner-style episodes; ``roundtrip``: frames pass through jpeg.roundtrip first (the runner's filter)."""
    out = []
    for e, seed in enumerate(seeds):
        agent.reset(seed)
        for k, img in enumerate(frames(steps, seed=e)):
            out.append(agent.act(episode_obs(k, jpeg.roundtrip(img) if roundtrip else img, privileged)))
    return out


@pytest.mark.parametrize("transport", ["pipes", "fifos"])
def test_remote_agent_gives_the_same_commands_as_in_process(transport):
    expected = drive(AGENTS.PixelAgent(), [5, 6], 8, roundtrip=True)
    with RemoteAgent([*PIXEL, "pixel"], transport=transport, init_timeout=20) as remote:
        assert not remote.privileged and remote.name == "remote:pixel"
        got_filtered = drive(remote, [5, 6], 8, roundtrip=True)  # the node gets the bytes roundtrip decoded
        got_raw = drive(remote, [5, 6], 8, roundtrip=False)  # the node gets one encoding of the raw frame
        assert remote.process.seed  # seed went only once: a second seed would have failed the process
    assert remote.process.returncode == 0
    for got in (got_filtered, got_raw):
        assert len(got) == len(expected)
        for a, b in zip(got, expected, strict=True):
            assert a.tolist() == b.tolist()


def test_agent_process_api_step_by_step():
    imgs = frames(3)
    ref = AGENTS.PixelAgent()
    ref.reset(1, "e")
    with AgentProcess([*PIXEL, "pixel"], init_timeout=20) as proc:
        assert proc.capabilities == {"z2": {"protocol-reflection": True}} and proc.description is not None
        proc.seed(1)
        proc.episode_start("e", '{"seed": 1}')
        for k, img in enumerate(imgs):
            data = jpeg.encode(img)
            proc.observe(episode_obs(k, img), jpeg=data)
            got = proc.get_commands(k / 15)
            assert got.tolist() == ref.act(episode_obs(k, jpeg.decode(data))).tolist()
        topic, data = proc.meta("describe_node")
        assert topic == "node_description" and "PixelAgent" in data["description"]
    assert proc.returncode == 0 and not proc.alive


def test_privileged_node_is_detected_and_gets_lane_poses():
    expected = drive(LanePIDAgent(), [3], 10, roundtrip=False, privileged=True)
    with RemoteAgent([sys.executable, "-m", "proxybench.protocol", "pid"], init_timeout=20) as remote:
        assert remote.privileged
        got = drive(remote, [3], 10, roundtrip=False, privileged=True)
    assert [g.tolist() for g in got] == [e.tolist() for e in expected]


def test_privileged_extension_is_opt_in():
    remote = RemoteAgent([*PIXEL, "privileged"], privileged=False, init_timeout=20)
    assert not remote.privileged
    with pytest.raises(AgentFailure) as exc:
        drive(remote, [1], 2, roundtrip=False, privileged=True)
    assert exc.value.reason == "aborted" and "privileged agent got no lane pose" in exc.value.detail
    assert exc.value.exit_code == 1


def test_caller_order_errors_send_nothing():
    with AgentProcess([*PIXEL, "pixel"], init_timeout=20) as proc:
        with pytest.raises(ProtocolUsageError):
            proc.get_commands(0.0)
        with pytest.raises(ProtocolUsageError):
            proc.step(episode_obs(0, None))
        proc.seed(2)
        with pytest.raises(ProtocolUsageError):
            proc.seed(3)
        with pytest.raises(ProtocolUsageError):
            proc.meta("reboot")
        proc.episode_start("e")
        assert proc.get_commands(0.0).shape == (2,)
    with pytest.raises(ProtocolUsageError):
        proc.get_commands(0.1)
    assert proc.close() == 0


def test_prints_of_a_served_agent_go_to_stderr():
    lines: list[str] = []
    with RemoteAgent([*PIXEL, "chatty"], init_timeout=20, on_stderr=lines.append) as remote:
        remote.reset(0)
        for k, img in enumerate(frames(3)):
            assert remote.act(episode_obs(k, img)).shape == (2,)
    assert lines.count("chatty agent says hello on stdout") == 3


def test_failed_process_stays_failed_and_remote_agent_restarts():
    remote = RemoteAgent([*PIXEL, "failing"], init_timeout=20)
    first = remote.process
    with pytest.raises(AgentFailure) as exc:
        drive(remote, [1], 4, roundtrip=False)
    assert exc.value.reason == "aborted" and "failing agent gives up" in exc.value.detail
    assert first.returncode == 1 and not first.alive
    with pytest.raises(AgentFailure) as again:
        first.get_commands(1.0)
    assert again.value.reason == "aborted"
    assert len(drive(remote, [2], 2, roundtrip=False)) == 2  # a fresh process, seeded again
    assert remote.restarts == 1 and remote.process is not first
    assert remote.close() == 0
