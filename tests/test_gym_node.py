"""gym-duckietown behind the robot protocol: conformance, every agent kind, the frame conversion, and equality
with gym-duckietown run directly. Needs gym's environment (`proxybench gym setup`): skipped without it, except
under PROXYBENCH_REQUIRE_GYM=1 (CI), where a missing environment fails."""

from __future__ import annotations

import io
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import cbor2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from proxybench.agents import make_agent
from proxybench.cli import app
from proxybench.domain.maps import MapObject, load_map
from proxybench.gym.backend import GymRobot, resolve_map
from proxybench.gym.environment import check_environment, default_path
from proxybench.gym.params import gym_params
from proxybench.protocol import RemoteAgent, RemoteRobot, jpeg, wire
from proxybench.protocol import robot_wire as rw
from proxybench.protocol.robot_node import RobotNode, serve_robot
from proxybench.protocol.robot_process import map_yaml
from proxybench.runner.robot_episode import run_episode_on_robot
from proxybench.runner.starts import start_poses

DATA = Path(__file__).resolve().parent / "data" / "aido"
SERVE = [sys.executable, "-m", "proxybench.cli", "gym", "serve", "--param", "camera_width=80",
         "--param", "camera_height=60"]
LOOP = load_map("loop_3x3")


@pytest.fixture(scope="module")
def venv() -> Path:
    env = check_environment(render=False)
    if not env.ok:
        why = "gym-duckietown's environment is not ready (run `proxybench gym setup`): " + "; ".join(env.problems)
        if os.environ.get("PROXYBENCH_REQUIRE_GYM") == "1":
            pytest.fail(why)
        pytest.skip(why)
    return default_path()


@pytest.fixture(scope="module")
def backend(venv: Path):
    robot = GymRobot(gym_params(["camera_width=64", "camera_height=48"]), "loop_3x3", venv)
    yield robot
    robot.close()


def run(backend: GymRobot, *inputs: bytes) -> tuple[list[list[dict]], int]:
    """Serve the inputs on a fresh node over ``backend``: (answers, each its outputs; exit status)."""
    out = io.BytesIO()
    code = serve_robot(RobotNode(backend), io.BytesIO(b"".join(inputs)), out, exit_on_abort=False)
    data, pos, answers, cur = out.getvalue(), 0, [], None
    while pos < len(data):
        end = wire.item_end(data, pos)
        m = cbor2.loads(data[pos:end])
        pos = end
        if m.get("control") == "understood":
            cur = []
        elif m.get("control") == "over":
            answers.append(cur)
        else:
            cur.append(m)
    return answers, code


def setup(pose: tuple[float, float, float], payload: dict | None = None, m=LOOP) -> list[bytes]:
    return [wire.encode_seed(3), rw.encode_clear(), rw.encode_set_map(map_yaml(m)), rw.encode_spawn_robot("ego", pose),
            rw.encode_get_robot_interface_description("ego"),
            wire.encode_episode_start("e1", json.dumps(payload or {"seed": 3, "proxybench": True}))]


# ------------------------------------------------------------------------------------------ conformance
def test_the_gym_node_describes_aidos_protocol_and_says_what_it_is(backend: GymRobot) -> None:
    answers, code = run(backend, wire.encode_topic("wrapper.describe_protocol", None),
                        wire.encode_topic("wrapper.describe_node", None))
    aido = json.loads((DATA / "simulator-protocol-description.json").read_text())
    assert code == 0 and json.loads(json.dumps(answers[0][0]["data"])) == aido
    assert "gym-duckietown 6.1.34" in answers[1][0]["data"]["description"]


def test_an_episode_message_by_message(backend: GymRobot) -> None:
    pose = start_poses("loop_3x3", [3])[0]
    dt = 1 / 30
    answers, code = run(backend, *setup(pose), rw.encode_get_robot_observations("ego", 0.0),
                        rw.encode_set_robot_commands("ego", 0.0, 0.4, 0.5), rw.encode_step(3 * dt),
                        rw.encode_get_sim_state(), rw.encode_get_robot_state("ego", 3 * dt),
                        rw.encode_get_robot_observations("ego", 3 * dt), rw.encode_get_robot_performance("ego"))
    assert code == 0
    info = rw.parse_robot_info(answers[4][0]["data"])
    sim = info.raw["simulator"]
    assert (info.kind, info.frame_rate, info.physics_rate) == ("simulation", 30.0, 30.0)
    assert (sim["name"], sim["version"], sim["hidden"], info.params["trim"]) == ("gym-duckietown", "6.1.34", False, 0)
    o0 = rw.parse_robot_observations(answers[6][0]["data"])
    assert jpeg.decode(o0.observations.jpg).shape == (48, 64, 3) and o0.lane_pose.valid
    assert rw.parse_sim_state(answers[9][0]["data"]) == rw.SimState(False, {"ego": None})
    s1 = rw.parse_robot_state(answers[10][0]["data"])
    assert s1.trace["t"].tolist() == pytest.approx([0.0, dt, 2 * dt, 3 * dt]) and s1.pwm == (0.4, 0.5)
    assert s1.trace["pwm_left"].tolist() == [0.0, 0.4, 0.4, 0.4] and s1.v == 0.0  # gym's 0.15 s command delay
    assert rw.parse_robot_observations(answers[11][0]["data"]).observations.odometry[1] >= 0


def test_a_delay_under_one_physics_step_acts_at_once(venv: Path) -> None:
    """gym's rule (the command stamped nearest to t − delay) gives the command just given; gym-duckietown itself
    raised IndexError there (the validation study's gym draw reaches 0.02 s; a step is 1/30 s)."""
    robot = GymRobot(gym_params(["camera_width=64", "camera_height=48", "delay=0.02"]), "loop_3x3", venv)
    try:
        dt = 1 / 30
        answers, code = run(robot, *setup(start_poses("loop_3x3", [3])[0]),
                            rw.encode_set_robot_commands("ego", 0.0, 0.4, 0.5), rw.encode_step(3 * dt),
                            rw.encode_get_robot_state("ego", 3 * dt))
    finally:
        robot.close()
    assert code == 0, answers[-1]
    assert rw.parse_robot_state(answers[-1][0]["data"]).v > 0  # moving after 3 steps (0.15 s of delay: still)


@pytest.mark.parametrize(("step", "words"), [
    (rw.encode_step(-1.0), "time cannot go back"),
    (rw.encode_get_robot_state("nobody", 0.0), "unknown robot 'nobody'"),
    (rw.encode_set_map("tiles: [[nonsense/N]]\ntile_size: 0.585\n"), "set_map"),
])
def test_bad_input_is_answered_aborted_naming_it(backend: GymRobot, step: bytes, words: str) -> None:
    pose = start_poses("loop_3x3", [3])[0]
    inputs = [*setup(pose)[:2], step] if b"set_map" in step else [*setup(pose), step]
    out = io.BytesIO()
    code = serve_robot(RobotNode(backend), io.BytesIO(b"".join(inputs)), out, exit_on_abort=False)
    assert code == 1 and words in out.getvalue().decode("utf-8", "replace")


def test_a_spawned_duckie_is_gyms_obstacle_and_parked_robots_stand_still(backend: GymRobot) -> None:
    x, y, th = start_poses("loop_3x3", [3])[0]
    ahead = (x + 0.25 * math.cos(th), y + 0.25 * math.sin(th))
    inputs = [wire.encode_seed(3), rw.encode_clear(), rw.encode_set_map(map_yaml(LOOP)),
              rw.encode_spawn_robot("ego", (x, y, th)),
              wire.encode_topic("spawn_duckie", {"name": "d", "color": "yellow", "pose": {
                  "x": ahead[0], "y": ahead[1], "theta_deg": 0.0}}),
              wire.encode_topic("spawn_robot", {
                  "playable": False, "owned_by_player": False, "robot_name": "npc", "dynamics": "DB18",
                  "dynamics_params": {}, "configuration": {"pose": {"x": 0.8775, "y": 1.46, "theta_deg": 0.0},
                                                           "velocity": {"x": 0.0, "y": 0.0, "theta_deg": 0.0}}}),
              wire.encode_episode_start("e", "{}"), rw.encode_set_robot_commands("ego", 0.0, 0.6, 0.6),
              rw.encode_step(2.0), rw.encode_get_sim_state(), rw.encode_get_robot_state("npc", 2.0),
              wire.encode_topic("dump_state", {}), wire.encode_topic("get_ui_image", None)]
    answers, code = run(backend, *inputs)
    end = rw.parse_sim_state(answers[9][0]["data"])
    assert code == 0 and end.terminations["ego"].termination == "collision"
    assert "collision" in end.terminations["ego"].desc and end.terminations["npc"] is None
    assert rw.parse_robot_state(answers[10][0]["data"]).pose == pytest.approx((0.8775, 1.46, 0.0))
    assert sorted(answers[11][0]["data"]["state"]["duckiebots"]) == ["ego", "npc"]
    assert jpeg.decode(answers[12][0]["data"]["jpg_data"]).ndim == 3


def test_the_same_seed_gives_the_same_frames_whatever_came_before(backend: GymRobot) -> None:
    """gym sets an episode's light under the matrices the previous frame left; the node resets them, so a seed's
    frames (domain randomisation on) do not depend on the episodes before."""
    backend.set_map(map_yaml(LOOP))
    first, other = start_poses("loop_3x3", [4, 5])

    def episode(seed: int, pose) -> list[np.ndarray]:
        backend.reset(seed, pose, None, ())
        frames = [backend.camera().copy()]
        for _ in range(3):
            backend.step_frame(np.array([0.4, 0.3]))
            frames.append(backend.camera().copy())
        return frames

    a = episode(4, first)
    episode(5, other)
    b = episode(4, first)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))


def test_frames_through_the_shared_file_are_the_pipes_and_stay_put(backend: GymRobot, venv: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """gym's process writes a stream's frames into a shared file whose slots the look-ahead keeps rewriting; each
    frame the node hands out must be the very pixels the pipe carries, and stay so while later frames come."""
    assert backend._slots is not None, "Linux has memfd: the shared file should be in use"
    send = backend._send

    def slow_send(msg: dict) -> None:  # the node late to read a period: gym's process writes the next ones meanwhile
        send(msg)
        if msg["op"] == "commit":
            time.sleep(0.03)

    monkeypatch.setattr(backend, "_send", slow_send)
    piped = GymRobot(gym_params(["camera_width=64", "camera_height=48"]), "loop_3x3", venv, shared_frames=False)
    pose = start_poses("loop_3x3", [7])[0]

    def episode(robot: GymRobot) -> list[np.ndarray]:
        robot.set_map(map_yaml(LOOP))
        robot.reset(7, pose, None, ())
        frames = []
        for k in range(12):
            robot.step_frame(np.array([0.5 + 0.03 * k, 0.35]))
            frames.append(robot.camera())  # no copy: a frame must not change after it was handed out
            if k == 5:
                robot.probe()  # the pushes computed ahead are dropped, their slots written again
        return frames

    try:
        shared, pipe = episode(backend), episode(piped)
    finally:
        piped.close()
    assert piped._slots is None
    assert all(np.array_equal(a, b) for a, b in zip(shared, pipe, strict=True))
    assert not np.array_equal(shared[0], shared[-1])  # the view moved


def test_a_request_between_steps_puts_back_the_periods_computed_ahead(backend: GymRobot) -> None:
    """The bridge computes periods before their commands come; a probe or a camera request between two steps
    must see the state the caller knows, and the episode must go on as if it had not been asked."""
    backend.set_map(map_yaml(LOOP))
    pose = start_poses("loop_3x3", [6])[0]
    pwm = [np.array([0.2 + 0.05 * k, 0.5 - 0.04 * k]) for k in range(8)]

    def episode(interrupt: bool) -> list[tuple[float, ...]]:
        backend.reset(6, pose, None, ())
        poses = []
        for k, cmd in enumerate(pwm):
            backend.step_frame(cmd)
            poses.append(backend.state().pose)
            if interrupt and k in (2, 5):
                seen = backend.probe()  # gym's own pose: the committed period's, not one computed ahead
                x, y = seen["cur_pos"][0], seen["grid"][1] * seen["tile_size"] - seen["cur_pos"][2]
                assert (x, y) == pytest.approx(poses[-1][:2], abs=1e-9)
                backend.camera()
        return poses

    interrupted, plain = np.array(episode(True)), np.array(episode(False))
    assert np.abs(interrupted - plain).max() < 1e-12 and np.ptp(plain[:, 0]) > 1e-4  # it moved, identically


def test_the_end_and_its_reason_do_not_depend_on_requests_between_steps(backend: GymRobot) -> None:
    """The bridge finds why gym ended an episode once, where the end begins (its collision test is costly), and
    keeps it while gym goes on saying done; periods put back around the end must leave no stale reason."""
    backend.set_map(map_yaml(LOOP))
    pose = start_poses("loop_3x3", [6])[0]

    def episode(asked_after: tuple[int, ...]) -> tuple[float, str, str]:
        backend.reset(6, pose, None, ())
        for k in range(75):
            backend.step_frame(np.array([0.9, 0.1]))  # a hard right turn: off the road within the 2.5 s
            if k in asked_after:
                backend.probe()
        end = backend.ending()
        assert end is not None, "the robot should have left the road"
        return end.t, end.kind, end.message

    plain = episode(())
    assert plain[1] == "off_road"
    x, y, th = pose  # an episode between them that ends otherwise: into a duckie
    backend.reset(6, pose, None, (MapObject("duckie", x + 0.25 * math.cos(th), y + 0.25 * math.sin(th)),))
    for _ in range(60):
        backend.step_frame(np.array([0.6, 0.6]))
    assert backend.ending() is not None and backend.ending().kind == "collision"
    k_end = round(plain[0] / backend.frame_dt) - 1  # the step whose period ended it
    for asked in ((k_end - 2,), (k_end - 1,), (k_end,), (k_end + 1, k_end + 3)):
        assert episode(asked) == plain, asked


# ------------------------------------------------------------------------------------- frame conversion
@pytest.mark.parametrize("name", ["loop_3x3", "zigzag", "udem1", "ETHZ_autolab_technical_track", "4way"])
def test_the_start_pose_lands_where_gym_sees_it_on_several_maps(backend: GymRobot, venv: Path, name: str) -> None:
    """Map frame → gym's frame (x, H·tile − z, angle): gym finds the robot on the tile proxybench placed it on
    (rows count down in gym), reports the pose back unchanged, and driving straight moves it along θ."""
    m = resolve_map(name, venv)
    backend.set_map(map_yaml(m))
    rows = len(m.tiles)
    for seed in (1, 2):
        x, y, th = start_poses(m, [seed])[0]
        backend.reset(seed, (x, y, th), None, ())
        seen = backend.probe()
        i, j_up = int(x // m.tile_size), int(y // m.tile_size)
        assert seen["tile"] == [i, rows - 1 - j_up] and seen["grid"][1] == rows
        assert seen["kind"] == m.tiles[rows - 1 - j_up][i].kind  # row 0 of the file is north in both
        assert seen["cur_pos"][0] == pytest.approx(x) and seen["cur_pos"][2] == pytest.approx(rows * m.tile_size - y)
        assert backend.state().pose == pytest.approx((x, y, th), abs=1e-9)
        for _ in range(10):
            backend.step_frame(np.array([0.5, 0.5]))
        x1, y1, _ = backend.state().pose
        assert math.hypot(x1 - x, y1 - y) > 0.01
        assert math.cos(math.atan2(y1 - y, x1 - x) - th) > 0.99


# -------------------------------------------------------------------------------- agents through the node
@pytest.fixture(scope="module")
def robot(venv: Path):
    with RemoteRobot(SERVE, init_timeout=120, step_timeout=30) as r:
        yield r


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="--cpus needs a CPU for gym and one for the node")
def test_cpus_put_gyms_process_on_them_and_the_node_on_the_others(venv: Path) -> None:
    import psutil

    last = max(os.sched_getaffinity(0))
    with RemoteRobot([*SERVE, "--cpus", str(last)], init_timeout=120, step_timeout=30) as r:
        traj = run_episode_on_robot(r, make_agent("pid"), seed=5, seconds=1.0, map_="loop_3x3", camera=False)
        node = psutil.Process(r.process.pid)
        (gym,) = node.children()
        assert gym.cpu_affinity() == [last] and last not in node.cpu_affinity() and node.cpu_affinity()
    assert traj.termination == "timeout"


def test_cpus_auto_gives_each_node_a_cpu_of_its_own(venv: Path, tmp_path: Path) -> None:
    import psutil

    mine = sorted(os.sched_getaffinity(0))
    if len(mine) < 2:
        pytest.skip("one CPU: --cpus auto leaves gym unpinned")
    env = {"TMPDIR": str(tmp_path)}  # its own lock folder: nodes of someone else's on this machine do not count
    with (RemoteRobot([*SERVE, "--cpus", "auto"], init_timeout=120, step_timeout=30, env=env) as a,
          RemoteRobot([*SERVE, "--cpus", "auto"], init_timeout=120, step_timeout=30, env=env) as b):
        gyms = []
        for r in (a, b):
            run_episode_on_robot(r, make_agent("pid"), seed=5, seconds=0.5, map_="loop_3x3", camera=False)
            node = psutil.Process(r.process.pid)
            (gym,) = node.children()
            (cpu,) = gym.cpu_affinity()
            assert cpu not in node.cpu_affinity() and node.cpu_affinity()
            gyms.append(cpu)
    assert gyms == [mine[-1], mine[-2]]  # the last free CPU first, each held by one node


@pytest.mark.parametrize("agent", ["pid", "vision", "node"])
def test_one_short_episode_per_agent_kind(robot: RemoteRobot, agent: str) -> None:
    a = RemoteAgent([sys.executable, "-m", "proxybench.protocol", "vision"]) if agent == "node" else make_agent(agent)
    try:
        traj = run_episode_on_robot(robot, a, seed=5, seconds=2.0, map_="loop_3x3", camera=not a.privileged)
    finally:
        getattr(a, "close", lambda: None)()
    assert traj.meta["robot"]["simulator"]["name"] == "gym-duckietown" and traj.meta["source"] == "simulation"
    assert traj.termination == "timeout" and traj["t"][-1] == pytest.approx(2.0)
    assert math.hypot(traj["x"][-1] - traj["x"][0], traj["y"][-1] - traj["y"][0]) > 0.05


_DIRECT = """
import json, sys
import numpy as np, pyglet
pyglet.options["headless"] = True
import logging; logging.disable(logging.CRITICAL)
from gym_duckietown.simulator import Simulator, geometry
from duckietown_world.world_duckietown.pwm_dynamics import get_DB18_uncalibrated
job = json.load(sys.stdin)
env = Simulator(map_name="small_loop", camera_width=80, camera_height=60, dynamics_rand=True, max_steps=10**9)
env.seed(job["seed"])
env.reset()
x, y, th = job["pose"]
env.cur_pos, env.cur_angle = env.weird_from_cartesian(geometry.SE2_from_translation_angle([x, y], th))
env.cur_pos = np.asarray(env.cur_pos, dtype=float)
trim = env.randomization_settings["trim"][0]  # as gym's own reset with dynamics_rand
q = env.cartesian_from_weird(env.cur_pos, env.cur_angle)
env.state = get_DB18_uncalibrated(delay=0.15, trim=trim).initialize(
    c0=(q, geometry.se2_from_linear_angular(np.array([0, 0]), 0)), t0=0)
poses = []
for pwm in job["pwm"]:
    env.step(np.array(pwm))
    (px, py), pth = geometry.translation_angle_from_SE2(env.cartesian_from_weird(env.cur_pos, env.cur_angle))
    poses.append([float(px), float(py), float(pth)])
print(json.dumps(poses))
"""


@pytest.mark.slow
def test_a_20_s_episode_through_the_node_is_gym_run_directly(venv: Path) -> None:
    """Same start, commands and seed (with dynamics_rand, the seed draws the trim): poses equal to 1e-6 m."""
    seed, pose = 11, start_poses("loop_3x3", [11])[0]
    with RemoteRobot([*SERVE, "--param", "dynamics_rand=true"], init_timeout=120, step_timeout=30) as r:
        traj = run_episode_on_robot(r, make_agent("pid"), seed=seed, seconds=20.0, map_="loop_3x3", pose=pose,
                                    camera=False)
    assert traj.termination == "timeout"
    pwm = np.column_stack([traj["pwm_left"], traj["pwm_right"]])[1:]  # the row at t=0 is the start
    out = subprocess.run([str(venv / "bin" / "python"), "-c", _DIRECT], input=json.dumps(
        {"seed": seed, "pose": list(pose), "pwm": pwm.tolist()}), capture_output=True, text=True, check=True)
    direct = np.array(json.loads(out.stdout.strip().splitlines()[-1]))
    node = np.column_stack([traj["x"], traj["y"], traj["theta"]])[1:]
    assert node.shape == direct.shape == (600, 3)
    assert np.abs(node[:, :2] - direct[:, :2]).max() < 1e-6
    assert np.abs(np.angle(np.exp(1j * (node[:, 2] - direct[:, 2])))).max() < 1e-6


# ------------------------------------------------------------------------------ recorded, hidden θ, reveal
def test_a_recording_says_gym_and_keeps_only_the_hash_of_hidden_parameters(venv: Path, tmp_path: Path) -> None:
    theta = tmp_path / "theta.yaml"
    theta.write_text("trim: 0.1\ncamera_width: 80\ncamera_height: 60\nnonce: xyzzy-0123456789abcdef\n")
    cmd = f"{sys.executable} -m proxybench.cli gym serve --param-file {theta} --secret"
    res = CliRunner().invoke(app, ["target", "record", "--target", f"robot:{cmd}", "--agent", "pid", "--episodes", "1",
                                   "--seconds", "1", "--out", str(tmp_path / "rec")])
    assert res.exit_code == 0, res.output
    manifest = (tmp_path / "rec" / "target.yaml").read_text()
    sim = yaml.safe_load(manifest)["robot"]["simulator"]
    assert sim["name"] == "gym-duckietown" and sim["hidden"] and "trim" not in manifest
    check = CliRunner().invoke(app, ["target", "check", str(tmp_path / "rec")])
    assert check.exit_code == 0 and "gym-duckietown 6.1.34, parameters hidden" in check.output
    reveal = CliRunner().invoke(app, ["gym", "params", "--param-file", str(theta)])
    assert json.loads(reveal.output)["sha256"] == sim["sha256"] and json.loads(reveal.output)["changed"]["trim"] == 0.1


_DEFAULTS = """
import inspect, json, logging
logging.disable(logging.CRITICAL)
from gym_duckietown import simulator as gs
from duckietown_world.world_duckietown import pwm_dynamics as pd
ctor = {k: p.default for k, p in inspect.signature(gs.Simulator.__init__).parameters.items() if k != "self"}
ctor["color_sky"] = list(ctor["color_sky"])
db18 = pd.get_DB18_uncalibrated(delay=0.15).factory
coef = {k: getattr(db18, a) for k, a in (("u1", "u1"), ("u2", "u2"), ("u3", "u3"), ("w1", "w1"), ("w2", "w2"),
        ("w3", "w3"), ("uar", "u_alpha_r"), ("ual", "u_alpha_l"), ("war", "w_alpha_r"), ("wal", "w_alpha_l"))}
cam = {"cam_height": gs.CAMERA_FLOOR_DIST, "cam_angle": gs.CAMERA_ANGLE, "cam_fov_y": gs.CAMERA_FOV_Y}
print(json.dumps({"ctor": ctor, "coef": coef, "cam": cam}, default=str))
"""


def test_every_parameter_is_gyms_own_name_with_gyms_default(venv: Path) -> None:
    """Checked against gym-duckietown itself: its Simulator's signature, its DB18 model, its camera constants."""
    from proxybench.gym.params import DEFAULTS, NOT_TAKEN

    out = subprocess.run([str(venv / "bin" / "python"), "-c", _DEFAULTS], capture_output=True, text=True, check=True)
    gym = json.loads(out.stdout.strip().splitlines()[-1])
    mine = {k: list(v) if isinstance(v, tuple) else v for k, v in DEFAULTS.items()}
    differ = {"camera_width": 640, "camera_height": 480, "max_steps": 1500, "seed": None}  # ours, documented
    for name, value in gym["ctor"].items():
        assert name in mine or name in NOT_TAKEN, f"gym's {name} is neither a parameter nor explained"
        if name in mine and name not in differ:
            assert mine[name] == value, name
    assert {k: gym["ctor"][k] for k in differ} == differ
    assert {k: mine[k] for k in gym["coef"]} == gym["coef"] and {k: mine[k] for k in gym["cam"]} == gym["cam"]
    assert mine["delay"] == 0.15 and mine["trim"] == 0.0


@pytest.mark.slow
def test_the_gym_node_keeps_the_plant_contract(venv: Path) -> None:
    """proxybench.testing's PlantContract, as on every plant: starts, start pose, stepping at its 30 Hz,
    observations, determinism (a seed again after another one and on a fresh node), clean failure."""
    from proxybench.testing import PlantContract

    report = PlantContract.for_robot_command(SERVE, frame_rate=30.0, image_size=(80, 60)).check_all()  # raises
    assert "80×60 RGB uint8 frames every 1/30 s" in next(r for r in report.results if r.name == "observations").reason
