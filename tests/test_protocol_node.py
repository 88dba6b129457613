"""The served node, in-process over byte buffers: answers must match the recorded AIDO node's."""

from __future__ import annotations

import importlib.util
import io
from dataclasses import dataclass
from pathlib import Path

import cbor2
import numpy as np
import pytest

from proxybench.agents.base import Agent, Observation
from proxybench.agents.simple import StraightAgent
from proxybench.domain.lane_pose import LanePose
from proxybench.protocol import jpeg, serve, wire
from proxybench.protocol.description import declares_extension, encode_extras
from test_protocol_wire import (
    CAPABILITIES,
    COMMANDS,
    DESCRIBE,
    DESCRIPTION_HEAD,
    EPISODE_000,
    OVER,
    SEED_42,
    UNDERSTOOD,
)

HERE = Path(__file__).resolve().parent
# shared/aido/wire-errors.txt
SEED_1 = "a466636f6d70617481627a3265746f70696364736565646464617461016674696d696e67f6"
EPISODE_E = ("a466636f6d70617481627a3265746f7069636d657069736f64655f73746172746464617461a16c657069736f64655f6e616d65"
             "61656674696d696e67f6")
GET_COMMANDS_0 = ("a466636f6d70617481627a3265746f7069636c6765745f636f6d6d616e64736464617461a16761745f74696d65fb000000"
                  "00000000006674696d696e67f6")
RESET = "a466636f6d70617481627a3265746f7069636572657365746464617461f66674696d696e67f6"
NOT_UNDERSTOOD_RESET = (
    "a267636f6e74726f6c6e6e6f742d756e64657273746f6f6464646174617878496e707574206368616e6e656c2022726573657422206e6f"
    "7420666f756e6420696e2070726f746f636f6c2e200a0a4b6e6f776e206368616e6e656c733a205b27657069736f64655f7374617274"
    "272c20276765745f636f6d6d616e6473272c20276f62736572766174696f6e73272c202773656564275d")
AT_TIME_INT = ("a466636f6d70617481627a3265746f7069636c6765745f636f6d6d616e64736464617461a16761745f74696d6501667469"
               "6d696e67f6")
NO_ODOMETRY = ("a466636f6d70617481627a3265746f7069636c6f62736572766174696f6e736464617461a16663616d657261a2686a70675f"
               "64617461406974696d657374616d70fb00000000000000006674696d696e67f6")
SEED_3_NO_COMPAT = "a365746f70696364736565646464617461036674696d696e67f6"
SEED_4 = "a466636f6d70617481627a3265746f70696364736565646464617461046674696d696e67f6"
SEED_5 = "a466636f6d70617481627a3265746f70696364736565646464617461056674696d696e67f6"


def _load_agents():
    spec = importlib.util.spec_from_file_location("protocol_test_agents", HERE / "protocol_agents" / "pixel_agent.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


AGENTS = _load_agents()


def split(data: bytes) -> list[bytes]:
    out, pos = [], 0
    while pos < len(data):
        end = wire.item_end(data, pos)
        out.append(data[pos:end])
        pos = end
    return out


def run(*inputs: str | bytes | dict, agent: Agent | None = None) -> tuple[list[bytes], int]:
    """Serve ``agent`` on the given messages (hex, bytes or maps); (raw output messages, exit status)."""
    raw = b"".join(bytes.fromhex(m) if isinstance(m, str) else m if isinstance(m, bytes) else cbor2.dumps(m)
                   for m in inputs)
    out = io.BytesIO()
    code = serve(agent or StraightAgent(0.5), io.BytesIO(raw), out, exit_on_abort=False)
    return split(out.getvalue()), code


def control(raw: bytes) -> tuple[str, object]:
    m = cbor2.loads(raw)
    return m["control"], m["data"]


def assert_aborted_on(raw: bytes, topic: str) -> str:
    code, text = control(raw)
    assert code == "aborted"
    assert text.startswith(f'Exception while handling a message on topic "{topic}".\n\n| Traceback (most recent call '
                           'last):\n|   File ')
    return text


def test_happy_path_matches_capture():
    obs = wire.encode_observations(jpeg.encode(np.full((120, 160, 3), 90, np.uint8)), 0.0, (0.0, 0.0), 0.0465)
    out, code = run(CAPABILITIES, DESCRIBE, SEED_42, EPISODE_000, obs, GET_COMMANDS_0)
    assert code == 0
    hexes = [m.hex() for m in out]
    assert hexes[:3] == [UNDERSTOOD, CAPABILITIES, OVER]
    assert hexes[3] == UNDERSTOOD and len(out[4]) == 11814 and hexes[4].startswith(DESCRIPTION_HEAD)
    assert hexes[5:12] == [OVER, UNDERSTOOD, OVER, UNDERSTOOD, OVER, UNDERSTOOD, OVER]
    assert hexes[12] == UNDERSTOOD and hexes[14] == OVER and len(hexes) == 15
    upto_motors = COMMANDS.index("66776865656c73")  # everything before "wheels" is the same bytes
    assert hexes[13][:upto_motors] == COMMANDS[:upto_motors]
    commands = cbor2.loads(out[13])
    assert commands["data"]["wheels"] == {"motor_left": 0.5, "motor_right": 0.5}
    spec = commands["timing"]["processed"]["agent"]
    assert list(spec) == ["time", "clock", "frame", "time2"] and spec["time"]["us"] < 10**9


def test_get_commands_before_episode_start_aborts():
    out, code = run(SEED_1, GET_COMMANDS_0)
    assert code == 1 and [m.hex() for m in out[:3]] == [UNDERSTOOD, OVER, UNDERSTOOD] and out[4].hex() == OVER
    assert "ExternalProtocolViolation: Unexpected input \"get_commands\"" in assert_aborted_on(out[3], "get_commands")
    assert len(out) == 5


def test_unknown_topic_answers_like_the_recorded_node():
    out, code = run(EPISODE_E, RESET)
    assert code == 1
    assert [m.hex() for m in out[:4]] == [UNDERSTOOD, OVER, NOT_UNDERSTOOD_RESET, OVER]
    kind, text = control(out[4])
    assert kind == "aborted" and text.startswith("Unexpected error:\n\n| Traceback (most recent call last):\n|")
    assert 'ExternalProtocolViolation: Input channel "reset" not found in protocol. \n| \n| Known channels:' in text
    assert text.endswith("\n| ") and out[5].hex() == OVER and len(out) == 6


def test_int_where_float_declared_aborts():
    out, code = run(EPISODE_E, AT_TIME_INT)
    assert code == 1 and [m.hex() for m in (out[0], out[1], out[2], out[4])] == [UNDERSTOOD, OVER, UNDERSTOOD, OVER]
    assert "must be a float, got int" in assert_aborted_on(out[3], "get_commands")


def test_observations_without_odometry_abort():
    out, code = run(EPISODE_E, NO_ODOMETRY)
    assert code == 1 and "missing field 'odometry'" in assert_aborted_on(out[3], "observations")


def test_message_without_compat_is_skipped():
    out, code = run(SEED_3_NO_COMPAT, SEED_4)
    assert code == 0 and b"".join(out).hex() == UNDERSTOOD + OVER


def test_seed_after_episode_start_aborts():
    out, code = run(EPISODE_E, SEED_5)
    assert code == 1 and len(out) == 5
    assert_aborted_on(out[3], "seed")


def test_unknown_control_is_not_understood_and_node_goes_on():
    out, code = run({"control": "hello", "data": None}, SEED_4)
    assert code == 0
    assert control(out[0]) == ("not-understood", "I expect any of ['capabilities'], not \"hello\".")
    assert [m.hex() for m in out[1:]] == [OVER, UNDERSTOOD, OVER]


@pytest.mark.parametrize("data", [b"\x1c\x00", cbor2.dumps([1, 2]), bytes.fromhex(SEED_4)[:10], cbor2.dumps({"x": 1})])
def test_unusable_input_aborts_with_unexpected_error(data):
    out, code = run(data)
    assert code == 1 and control(out[0])[0] == "aborted" and out[0] and out[1].hex() == OVER
    assert control(out[0])[1].startswith("Unexpected error:\n\n| Traceback")


def test_agent_exception_aborts_with_its_traceback():
    obs = wire.encode_observations(b"", 0.0, (0.0, 0.0), 0.01)
    steps = [obs, wire.encode_get_commands(0.0)] * 3
    out, code = run(EPISODE_E, *steps, agent=AGENTS.FailingAgent())
    assert code == 1
    text = assert_aborted_on(out[-2], "get_commands")
    assert "RuntimeError: failing agent gives up" in text
    with pytest.raises(SystemExit) as exc:
        serve(AGENTS.FailingAgent(), io.BytesIO(bytes.fromhex(EPISODE_E) + b"".join(steps)), io.BytesIO())
    assert exc.value.code == 1


@dataclass
class _Config:
    gain: float = 1.0


class _ConfiguredAgent(StraightAgent):
    """An agent with a config, as zuper nodes have."""

    def __init__(self):
        super().__init__(0.2)
        self.config = _Config()


def test_meta_topics_are_answered():
    metas = {"describe_config": "config_description", "describe_node": "node_description",
             "describe_build": "build_description", "get_state": "node_state", "set_state": "set_state_ack",
             "get_logs": "logs", "describe_protocol": "protocol_description"}
    requests = [wire.encode_topic("wrapper." + k, None) for k in metas]
    requests += [wire.encode_topic("wrapper.set_config", {"key": "gain", "value": 2.0}),
                 wire.encode_topic("wrapper.set_config", {"key": "nope", "value": 2.0})]
    agent = _ConfiguredAgent()
    out, code = run(*requests, agent=agent)
    assert code == 0 and len(out) == 3 * len(requests)
    answers = [cbor2.loads(m) for m in out[1::3]]
    assert [a["topic"] for a in answers] == [*metas.values(), "set_config_ack", "set_config_error"]
    assert all(list(a["timing"]["processed"]) == ["agent.wrapper"] for a in answers)
    assert agent.config.gain == 2.0 and "nope" in answers[-1]["data"]
    assert "An agent with a config" in answers[1]["data"]["description"]


def test_unknown_meta_topic_is_not_understood():
    out, code = run(wire.encode_topic("wrapper.reboot", None))
    assert code == 1 and control(out[0])[0] == "not-understood" and "describe_protocol" in control(out[0])[1]


def _lane_pose() -> LanePose:
    return LanePose(True, 2, 0.3, 0.02, -0.1, True, True, True, True, True, (1, 0), 0.0)


def test_privileged_agent_gets_the_lane_pose_from_the_extension():
    agent = AGENTS.PrivilegedPixelAgent()
    obs = wire.encode_observations(b"", 0.1, (0.2, 0.3), 0.01, encode_extras(_lane_pose()))
    out, code = run(DESCRIBE, EPISODE_E, obs, wire.encode_get_commands(0.1), agent=agent)
    assert code == 0 and declares_extension(cbor2.loads(out[1])["data"])
    got = cbor2.loads(out[-2])["data"]["wheels"]
    ref = AGENTS.PrivilegedPixelAgent()
    ref.reset(0, "e")
    expected = ref.act(Observation(None, 0.1, (0.2, 0.3), 0.01, _lane_pose()))
    assert [got["motor_left"], got["motor_right"]] == expected.tolist()


def test_non_privileged_agent_never_sees_a_lane_pose():
    seen = []

    class Spy(StraightAgent):
        def act(self, obs):
            seen.append(obs)
            return super().act(obs)

    obs = wire.encode_observations(jpeg.encode(np.zeros((8, 8, 3), np.uint8)), 0.1, None, None,
                                   encode_extras(_lane_pose()))
    _, code = run(EPISODE_E, obs, wire.encode_get_commands(0.1), agent=Spy(0.1))
    assert code == 0 and seen[0].lane_pose is None and seen[0].odometry is None and seen[0].time == 0.1
    assert seen[0].camera.shape == (8, 8, 3) and not seen[0].camera.flags.writeable


def test_episode_seed_comes_from_the_payload():
    seeds = []

    class Spy(StraightAgent):
        def reset(self, seed, episode=None):
            seeds.append((seed, episode))

    _, code = run(SEED_4, wire.encode_episode_start("a", '{"seed": 9}'), wire.encode_episode_start("b", "{}"),
                    wire.encode_episode_start("c", "seed: 11\n"), agent=Spy(0.1))
    assert code == 0 and seeds == [(9, "a"), (4, "b"), (11, "c")]
