"""Drive a simulator node the way AIDO's experiment manager does, with AIDO's own code.

``python experiment_manager.py WORKDIR STEPS -- SIMULATOR-COMMAND...``: starts the command as AIDO starts
nodes (``AIDONODE_DATA_IN`` = a FIFO this process creates, ``AIDONODE_DATA_OUT=fifo:`` a FIFO the node
creates), connects zuper-nodes' ``ComponentInterface`` with ``expect_protocol=protocol_simulator_DB20``
(which checks the node's protocol description against AIDO's), and runs the per-step exchange of
duckietown-experiment-manager's ``run_episode`` (daffy): clear, set_map, spawn_robot (a playable robot,
a parked one), spawn_duckie, episode_start with the scenario's payload; then per step dump_state,
get_robot_state of each robot, get_duckie_state, get_sim_state, get_robot_performance,
get_robot_observations, set_robot_commands, step(t + physics_dt), get_ui_image. Every answer is decoded
into AIDO's types by ComponentInterface. Prints one JSON line with what it saw; exits 1 on any error.
"""

import json
import logging
import os
import subprocess
import sys
import traceback

logging.disable(logging.CRITICAL)

import numpy as np  # noqa: E402
from aido_schemas import (  # noqa: E402
    RGB,
    DB20Commands,
    DumpState,
    EpisodeStart,
    FriendlyPose,
    FriendlyVelocity,
    GetDuckieState,
    GetRobotObservations,
    GetRobotState,
    LEDSCommands,
    PWMCommands,
    RobotConfiguration,
    SetMap,
    SetRobotCommands,
    SpawnDuckie,
    SpawnRobot,
    Step,
    protocol_simulator_DB20,
)
from zuper_nodes_wrapper import wrapper_outside  # noqa: E402
from zuper_nodes_wrapper.wrapper_outside import ComponentInterface  # noqa: E402

# zuper-ipce 6.1.2 cannot write the JSON schema of an ``Any`` field on Python >= 3.11 (the crash the real nodes
# show on describe_protocol). ComponentInterface writes each message's data twice: without schema to the node,
# then with schema for its log copy (``cc``, unused here). Only that second write falls back to no schema when
# it fails; what goes to the node is untouched, and on Python <= 3.10 nothing changes.
_ipce_from_object = wrapper_outside.ipce_from_object


def _ipce_for_log(ob, *args, **kwargs):
    try:
        return _ipce_from_object(ob, *args, **kwargs)
    except Exception:
        return _ipce_from_object(ob, *args, **{**kwargs, "ieso": wrapper_outside.IESO(with_schema=False)})


wrapper_outside.ipce_from_object = _ipce_for_log

MAP = """tiles:
- [curve_left/W, straight/W, curve_left/N]
- [straight/S  , grass     , straight/N]
- [curve_left/S, straight/E, curve_left/E]
tile_size: 0.585
"""
PHYSICS_DT = 0.05  # AIDO LF's experiment-manager setting


def main(workdir: str, steps: int, command: list[str]) -> dict:
    fin, fout = os.path.join(workdir, "sim-in"), os.path.join(workdir, "sim-out")
    env = {**os.environ, "AIDONODE_DATA_IN": fin, "AIDONODE_DATA_OUT": "fifo:" + fout}
    proc = subprocess.Popen(command, env=env, stdout=sys.stderr)
    seen: dict = {"steps": 0}
    try:
        sim = ComponentInterface(fin, fout, expect_protocol=protocol_simulator_DB20, nickname="simulator",
                                 timeout=60)
        sim._get_node_protocol(timeout=120)  # checks compatibility with protocol_simulator_DB20
        seen["protocol_checked"] = sim.node_protocol is not None
        sim.write_topic_and_expect_zero("seed", 4)
        sim.write_topic_and_expect_zero("clear")
        sim.write_topic_and_expect_zero("set_map", SetMap(map_data=MAP))
        still = FriendlyVelocity(0.0, 0.0, 0.0)
        for name, pose, playable in (("ego", FriendlyPose(0.2925, 0.88, -90.0), True),
                                     ("npc0", FriendlyPose(0.8775, 1.46, 0.0), False)):
            sim.write_topic_and_expect_zero("spawn_robot", SpawnRobot(
                playable=playable, owned_by_player=playable, robot_name=name,
                configuration=RobotConfiguration(pose, still), dynamics="DB18", dynamics_params={}, color="red",
                simulate_camera=playable))
        sim.write_topic_and_expect_zero("spawn_duckie", SpawnDuckie("duckie0", "yellow", FriendlyPose(1.4, 0.9, 0.0)))
        sim.write_topic_and_expect_zero("episode_start", EpisodeStart("ep0", yaml_payload="{}"))
        t = 0.0
        c = RGB(0.0, 0.0, 1.0)
        poses, terminations = [], None
        for _ in range(steps):
            dump = sim.write_topic_and_expect("dump_state", DumpState(), expect="state_dump")
            for name in ("ego", "npc0"):
                state = sim.write_topic_and_expect("get_robot_state", GetRobotState(name, t), expect="robot_state")
                if name == "ego":
                    poses.append(np.asarray(state.data.state.pose).tolist())
            sim.write_topic_and_expect("get_duckie_state", GetDuckieState("duckie0", t), expect="duckie_state")
            sim_state = sim.write_topic_and_expect("get_sim_state", expect="sim_state")
            terminations = {k: None if v is None else v.code for k, v in sim_state.data.terminations.items()}
            sim.write_topic_and_expect("get_robot_performance", "ego", expect="robot_performance")
            obs = sim.write_topic_and_expect("get_robot_observations", GetRobotObservations("ego", t),
                                             expect="robot_observations")
            seen["jpg_bytes"] = len(obs.data.observations.camera.jpg_data)
            commands = DB20Commands(PWMCommands(0.3, 0.3), LEDSCommands(c, c, c, c, c))
            sim.write_topic_and_expect_zero("set_robot_commands", SetRobotCommands("ego", t, commands))
            t += PHYSICS_DT
            sim.write_topic_and_expect_zero("step", Step(t))
            ui = sim.write_topic_and_expect("get_ui_image", None, expect="ui_image")
            seen["ui_jpg_bytes"] = len(ui.data.jpg_data)
            seen["steps"] += 1
        seen.update(poses=poses, terminations=terminations, dump_robots=sorted(dump.data.state.duckiebots),
                    dump_duckies=sorted(dump.data.state.duckies), ok=True)
        sim.close()
        seen["exit_code"] = proc.wait(timeout=30)
    except Exception:
        seen.update(ok=False, error=traceback.format_exc()[-4000:])
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return seen


if __name__ == "__main__":
    sep = sys.argv.index("--")
    result = main(sys.argv[1], int(sys.argv[2]), sys.argv[sep + 1:])
    print(json.dumps(result))
    sys.exit(0 if result["ok"] else 1)
