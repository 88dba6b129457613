"""The simulator as a robot node, in-process over byte buffers: message shapes, language, bad input."""

from __future__ import annotations

import io
import json
import math

import cbor2
import numpy as np
import pytest

from proxybench.domain.maps import load_map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import start_pose
from proxybench.protocol import jpeg, wire
from proxybench.protocol import robot_wire as rw
from proxybench.protocol.language import ROBOT_INPUTS, RobotLanguage
from proxybench.protocol.robot_node import RobotNode, serve_robot
from proxybench.protocol.robot_process import map_yaml

PARAMS = DomainParams(image_width=64, image_height=48, texture_size=32)
LOOP = map_yaml(load_map("loop_3x3"))
START = start_pose(load_map("loop_3x3"), 3)  # where the node would put the robot for seed 3


def node() -> RobotNode:
    return RobotNode(PARAMS, "loop_3x3")


def run(*inputs: bytes, robot: RobotNode | None = None) -> tuple[list[dict], int]:
    """Serve the inputs; (decoded output messages, exit status)."""
    out = io.BytesIO()
    code = serve_robot(robot or node(), io.BytesIO(b"".join(inputs)), out, exit_on_abort=False)
    data, msgs, pos = out.getvalue(), [], 0
    while pos < len(data):
        end = wire.item_end(data, pos)
        msgs.append(cbor2.loads(data[pos:end]))
        pos = end
    return msgs, code


def answers(msgs: list[dict]) -> list[list[dict]]:
    """Split a node's output into answers (understood … over), checking that framing."""
    out, cur = [], None
    for m in msgs:
        if m.get("control") == "understood":
            assert cur is None
            cur = []
        elif m.get("control") == "over":
            out.append(cur)
            cur = None
        else:
            cur.append(m)
    assert cur is None
    return out


def setup(payload: dict | None = None, pose=START, camera: bool = True) -> list[bytes]:
    payload = {"seed": 3, "proxybench": True} if payload is None else payload
    return [wire.encode_seed(3), rw.encode_clear(), rw.encode_set_map(LOOP),
            rw.encode_spawn_robot("ego", pose, simulate_camera=camera),
            rw.encode_get_robot_interface_description("ego"), wire.encode_episode_start("e1", json.dumps(payload))]


def test_describe_protocol_and_node():
    msgs, code = run(wire.encode_control(wire.CTRL_CAPABILITIES, wire.CAPABILITIES),
                     wire.encode_topic("wrapper.describe_protocol", None),
                     wire.encode_topic("wrapper.describe_node", None))
    assert code == 0
    caps, desc, node_desc = answers(msgs)
    assert caps == [{"control": "capabilities", "data": {"z2": {"protocol-reflection": True}}}]
    data = desc[0]["data"]["data"]
    assert sorted(data["inputs"]) == sorted(ROBOT_INPUTS)
    assert {"robot_observations", "robot_state", "sim_state", "robot_performance", "robot_interface_description",
            "duckie_state", "state_dump", "ui_image"} == set(data["outputs"])  # all of AIDO's
    assert data["inputs"]["set_robot_commands"]["properties"]["commands"]["title"] == "DB20Commands"
    obs = data["outputs"]["robot_observations"]["properties"]["observations"]
    assert obs["order"] == ["camera", "odometry"] and "proxybench" not in obs["properties"]  # AIDO's type, as is
    assert "SIMULATED" in node_desc[0]["data"]["description"]


def test_an_episode_message_by_message():
    frame_dt = 1 / PARAMS.frame_rate
    msgs, code = run(*setup(), rw.encode_get_robot_state("ego", 0.0), rw.encode_get_robot_observations("ego", 0.0),
                     rw.encode_set_robot_commands("ego", 0.0, 0.4, 0.5), rw.encode_step(2 * frame_dt),
                     rw.encode_get_sim_state(), rw.encode_get_robot_state("ego", 2 * frame_dt),
                     rw.encode_get_robot_observations("ego", 2 * frame_dt), rw.encode_get_robot_performance("ego"))
    assert code == 0
    (seed, clear, set_map, spawn, (describe,), start, (s0,), (o0,), cmd, step, (sim,), (s1,), (o1,),
     (perf,)) = answers(msgs)
    assert seed == clear == set_map == spawn == start == cmd == step == []
    info = rw.parse_robot_info(describe["data"])
    assert (info.kind, info.frame_rate, info.physics_rate) == ("simulation", 15.0, 60.0)
    assert info.params["image_width"] == 64 and describe["data"]["robot_name"] == "ego"
    for m in (describe, s0, o0, sim, s1, o1, perf):  # node outputs carry processing times, like commands do
        assert m["compat"] == ["z2"] and set(m["timing"]["processed"]["robot"]) == {"time", "clock", "frame", "time2"}

    state0, state1 = rw.parse_robot_state(s0["data"]), rw.parse_robot_state(s1["data"])
    assert state0.t_effective == 0.0 and state0.trace["t"].tolist() == [0.0]
    assert state1.t_effective == pytest.approx(2 * frame_dt) and state1.pwm == (0.4, 0.5)
    assert state1.trace["t"].size == 2 * 4 and state1.trace["t"][-1] == pytest.approx(2 * frame_dt)
    st = s1["data"]["state"]
    assert list(st) == ["pwm", "leds", "pose", "velocity", "proxybench"]  # canonical key order, as zuper writes
    assert list(st["pose"]) == ["data", "dtype", "shape"] and st["pose"]["shape"] == [3, 3]  # AIDO's SE(2) array
    pose = np.frombuffer(st["pose"]["data"], "<f8").reshape(3, 3)
    assert pose[:2, 2].tolist() == list(state1.pose[:2]) and math.atan2(pose[1, 0], pose[0, 0]) == pytest.approx(
        state1.pose[2])
    twist = np.frombuffer(st["velocity"]["data"], "<f8").reshape(3, 3)
    assert twist[0, 2] == state1.v > 0 and twist[1, 2] == 0.0 and twist[1, 0] == pytest.approx(state1.omega)

    obs0, obs1 = rw.parse_robot_observations(o0["data"]), rw.parse_robot_observations(o1["data"])
    assert obs1.t_effective == obs1.observations.timestamp == pytest.approx(2 * frame_dt)
    assert jpeg.decode(obs0.observations.jpg).shape == (48, 64, 3)
    assert obs1.observations.odometry[0] > 0 and obs1.observations.resolution == PARAMS.encoder_resolution
    assert obs1.observations.extras["lane_pose"]["valid"] is True  # asked for with proxybench: true
    camera = o1["data"]["observations"]["camera"]
    assert isinstance(camera["jpg_data"], bytes) and type(camera["timestamp"]) is float

    assert rw.parse_sim_state(sim["data"]) == rw.SimState(False, {"ego": None})
    metrics = perf["data"]["performance"]["metrics"]
    assert metrics["survival_time"]["cumulative_value"] == pytest.approx(2 * frame_dt)
    assert 0 < metrics["distance_driven"]["cumulative_value"] < 0.1


def test_extensions_only_when_asked_and_camera_off():
    msgs, code = run(*setup({"seed": 3}, camera=False), rw.encode_get_robot_state("ego", 0.0),
                     rw.encode_get_robot_observations("ego", 0.0))
    (state,), (obs,) = answers(msgs)[-2:]
    assert code == 0 and "proxybench" not in state["data"]["state"]
    assert "proxybench" not in obs["data"]["observations"]
    assert obs["data"]["observations"]["camera"]["jpg_data"] == b""  # simulate_camera: false


def test_spawn_pose_and_exact_payload_pose():
    pose = (0.9, 0.29, 0.1)
    msgs, _ = run(*setup({"seed": 3, "proxybench": True}, pose=pose), rw.encode_get_robot_state("ego", 0.0))
    exact = rw.parse_robot_state(answers(msgs)[-1][0]["data"])
    assert exact.pose[:2] == pose[:2] and exact.pose[2] == pytest.approx(0.1)  # via degrees
    msgs, _ = run(*setup({"seed": 3, "proxybench": True, "pose": list(pose)}, pose=(0.0, 0.0, 0.0)),
                  rw.encode_get_robot_state("ego", 0.0))
    assert rw.parse_robot_state(answers(msgs)[-1][0]["data"]).pose == pose  # the payload's pose wins, exactly


def test_episode_time_limit_is_reported():
    msgs, _ = run(*setup({"seed": 3, "episode_seconds": 0.2}), rw.encode_step(0.2), rw.encode_get_sim_state())
    sim = rw.parse_sim_state(answers(msgs)[-1][0]["data"])
    end = sim.terminations["ego"]
    assert sim.done and end.termination == "timeout" and end.when == pytest.approx(0.2) and end.hit is None


def test_steps_are_whole_frames():
    msgs, _ = run(*setup(), rw.encode_step(0.05), rw.encode_get_robot_state("ego", 0.05), rw.encode_step(0.1),
                  rw.encode_get_robot_state("ego", 0.1))
    first, second = (rw.parse_robot_state(a[0]["data"]) for a in answers(msgs)[-3::2])
    assert first.t_effective == 0.0 and first.trace["t"].size == 1  # 0.05 s < one frame (1/15 s): no step
    assert second.t_effective == pytest.approx(1 / 15) and second.trace["t"].size == 4


def aborted(msgs: list[dict]) -> str:
    assert msgs[-3:-2] == [{"control": "understood", "data": None}] or msgs[-4]["control"] == "not-understood"
    assert msgs[-2]["control"] == "aborted" and msgs[-1] == {"control": "over", "data": None}
    return msgs[-2]["data"]


@pytest.mark.parametrize(("inputs", "words"), [
    ([wire.encode_topic("step", {"until": 1})], "step: field 'until' must be a float"),
    ([rw.encode_set_robot_commands("ego", 0.0, 0.1, 0.1)], 'Unexpected input "set_robot_commands"'),
    ([wire.encode_seed(1), rw.encode_clear(), rw.encode_set_map(LOOP), wire.encode_episode_start("e")],
     "episode_start: no robot spawned"),
    ([rw.encode_clear(), rw.encode_set_map("tiles: [[banana]]\n")], "set_map: map_data is not a valid map"),
    ([rw.encode_clear(), rw.encode_set_map(LOOP), rw.encode_spawn_robot("a", START), rw.encode_spawn_robot("b", START)],
     "already spawned"),
    ([*setup(), rw.encode_step(0.2), rw.encode_step(0.1)], "time cannot go back"),
    ([*setup(), rw.encode_set_robot_commands("other", 0.0, 0.1, 0.1)], "set_robot_commands: unknown robot 'other'"),
    ([*setup(), rw.encode_set_robot_commands("ego", 0.0, 1.5, 0.1)], "motor_left = 1.5 is not a finite number"),
    ([*setup(), wire.encode_topic("get_robot_state", {"robot_name": "ego"})], "missing field 't_effective'"),
    ([*setup()[:-1], wire.encode_episode_start("e", '{"seed": "three"}')], "yaml_payload.seed must be an integer"),
    ([rw.encode_clear(), rw.encode_set_map(LOOP),
      wire.encode_topic("spawn_robot", {"playable": True, "robot_name": "a", "configuration": {"pose": {}}})],
     "spawn_robot.configuration.pose: missing field 'x'"),
])
def test_bad_input_aborts_naming_the_fault(inputs, words):
    msgs, code = run(*inputs)
    assert code == 1
    assert words in aborted(msgs)


def test_unknown_topic_is_not_understood_and_non_z2_is_ignored():
    msgs, code = run(wire.encode_seed(1), cbor2.dumps({"compat": ["z9"], "topic": "clear", "data": None,
                                                       "timing": None}),
                     wire.encode_topic("spawn_pedestrian", {"name": "d"}))
    assert code == 1
    assert msgs[2]["control"] == "not-understood" and 'Input channel "spawn_pedestrian" not found' in msgs[2]["data"]
    assert "'set_robot_commands'" in msgs[2]["data"] and msgs[4]["control"] == "aborted"
    assert len(msgs) == 6  # seed: understood, over; the z9 message: nothing; spawn_pedestrian: 4 messages


def test_language_follows_aido_order():
    lang = RobotLanguage()
    for topic in ("seed", "clear", "set_map", "spawn_robot", "get_robot_interface_description", "episode_start",
                  "set_robot_commands", "step", "get_robot_state", "clear", "set_map", "episode_start"):
        assert lang.check(topic) is None, topic
        lang.push(topic)
    assert lang.check("spawn_robot") is not None and lang.check("seed") is not None
    lang = RobotLanguage()
    assert lang.check("step") is not None and lang.check("episode_start") is not None


def test_caller_messages_are_aido_shaped():
    spawn = cbor2.loads(rw.encode_spawn_robot("ego", (0.5, 0.25, math.pi / 2)))
    assert list(spawn) == ["compat", "topic", "data", "timing"]
    assert spawn["data"]["configuration"] == {"pose": {"x": 0.5, "y": 0.25, "theta_deg": 90.0},
                                              "velocity": {"x": 0.0, "y": 0.0, "theta_deg": 0.0}}
    assert rw.parse_spawn_robot(spawn["data"]).pose == pytest.approx((0.5, 0.25, math.pi / 2))
    cmds = cbor2.loads(rw.encode_set_robot_commands("ego", 0.5, 1, 0))["data"]
    assert cmds["t_effective"] == 0.5 and cmds["commands"]["wheels"] == {"motor_left": 1.0, "motor_right": 0.0}
    assert type(cmds["commands"]["wheels"]["motor_left"]) is float and set(cmds["commands"]["LEDS"]) == {
        "center", "front_left", "front_right", "back_left", "back_right"}
    assert rw.parse_set_robot_commands(cmds)[2].tolist() == [1.0, 0.0]
    assert cbor2.loads(rw.encode_step(2))["data"] == {"until": 2.0}
    assert cbor2.loads(rw.encode_get_robot_observations("ego", 0))["data"] == {"robot_name": "ego", "t_effective": 0.0}
    with pytest.raises(wire.MessageTypeError, match="unknown-code"):
        rw.parse_sim_state({"done": True, "terminations": {"ego": {"when": 1.0, "desc": "", "code": "unknown-code"}}})
    assert rw.parse_sim_state({"done": True, "terminations": {"ego": {"when": 1, "desc": "d", "code": "out-of-tile"}}}
                              ).terminations["ego"] == rw.Ending("off_road", "d", 1.0)


def test_same_map_text_reuses_the_prepared_simulator():
    robot = node()
    sim = robot._sims[(LOOP, ())]
    run(*setup(), robot=robot)
    assert robot.sim is sim and np.isfinite(robot.sim.state).all()
