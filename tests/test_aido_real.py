"""proxybench against AIDO's own code (zuper-nodes-z6 6.2.17, aido-protocols-daffy 6.1.1), not stand-ins.

The project's own interpreter when it has the AIDO libraries at the pinned versions (the ``test`` extra
brings them with duckietown-world-daffy); otherwise a separate virtual environment with them
(``tests/aido/requirements.txt``, every version pinned) is built once into a cache folder
(``$PROXYBENCH_AIDO_VENV``, else ``~/.cache/proxybench/aido-venv-<hash>``; about two minutes) and reused. In it run:

- ``aido/solution.py``: a lane-following agent written with AIDO's API. On Python >= 3.11 its wrapper
  crashes on ``describe_protocol``: it runs with ``--no-reflection`` and by the automatic fallback, over
  FIFOs (it prints to stdout) and pipes.
- ``aido/decode_messages.py``: decodes every robot-protocol message (caller's and node's) into AIDO's types.
- ``aido/experiment_manager.py``: AIDO's experiment-manager loop with zuper's ``ComponentInterface``,
  which checks the robot node's protocol description against ``protocol_simulator_DB20``.
- ``aido/stock_sim.py``: a simulator node written with AIDO's API as AIDO's gym simulator is, which
  proxybench's runner drives as a robot.

``PROXYBENCH_SKIP_AIDO=1`` skips these tests (e.g. offline); nothing else does.
"""

from __future__ import annotations

import fcntl
import hashlib
import io
import json
import os
import shlex
import shutil
import subprocess
import sys
import venv
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from proxybench.agents import make_agent
from proxybench.cli import app
from proxybench.domain.maps import load_map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import start_pose
from proxybench.protocol import RemoteRobot, jpeg, wire
from proxybench.protocol import robot_wire as rw
from proxybench.protocol.aido_arrays import se2_matrix
from proxybench.protocol.robot_node import RobotNode, serve_robot
from proxybench.protocol.robot_process import map_yaml
from proxybench.runner.robot_episode import RobotLacksGroundTruth, run_episode_on_robot

AIDO = Path(__file__).resolve().parent / "aido"
REQUIREMENTS = AIDO / "requirements.txt"
runner = CliRunner()


def _venv_dir() -> Path:
    if os.environ.get("PROXYBENCH_AIDO_VENV"):
        return Path(os.environ["PROXYBENCH_AIDO_VENV"])
    key = hashlib.sha256(REQUIREMENTS.read_bytes() + sys.version.encode()).hexdigest()[:12]
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "proxybench" / f"aido-venv-{key}"


def _has_aido(python: str) -> bool:
    """Whether ``python`` imports AIDO's libraries at the pinned versions (and Pillow, for the agent)."""
    pins = {line.split("==")[0]: line.split("==")[1] for line in REQUIREMENTS.read_text().splitlines()
            if "==" in line and not line.startswith("#")}
    want = {k: pins[k] for k in ("zuper-nodes-z6", "aido-protocols-daffy", "zuper-ipce-z6", "zuper-typing-z6")}
    code = ("import importlib.metadata as m, sys, PIL, zuper_nodes, aido_schemas; "
            f"sys.exit(any(m.version(k) != v for k, v in {want!r}.items()))")
    try:
        return subprocess.run([python, "-c", code], capture_output=True, timeout=120).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


@pytest.fixture(scope="session")
def aido_python() -> str:
    """The Python of a virtual environment holding the AIDO libraries (built once, then cached)."""
    if os.environ.get("PROXYBENCH_SKIP_AIDO"):
        pytest.skip("PROXYBENCH_SKIP_AIDO is set")
    if not os.environ.get("PROXYBENCH_AIDO_VENV") and _has_aido(sys.executable):
        return sys.executable  # the `test` extra brings them (duckietown-world-daffy): no second venv to build
    target = _venv_dir()
    python, done = target / "bin" / "python", target / ".complete"
    if done.exists():
        return str(python)
    target.parent.mkdir(parents=True, exist_ok=True)
    with open(target.parent / (target.name + ".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one builder at a time (parallel test workers)
        if not done.exists():
            shutil.rmtree(target, ignore_errors=True)
            venv.EnvBuilder(with_pip=True, clear=True).create(target)
            res = subprocess.run([str(python), "-m", "pip", "install", "--disable-pip-version-check", "-q", "-r",
                                  str(REQUIREMENTS)], capture_output=True, text=True, timeout=1200)
            if res.returncode != 0:
                pytest.fail(f"could not build the AIDO test environment {target}:\n{res.stdout[-3000:]}"
                            f"{res.stderr[-3000:]}")
            done.write_text(REQUIREMENTS.read_text())
    return str(python)


@pytest.fixture
def solution(tmp_path: Path) -> Path:
    sub = tmp_path / "my submission"  # a space in the path: quoting must hold
    sub.mkdir()
    shutil.copy(AIDO / "solution.py", sub / "solution.py")
    (sub / "config.yaml").write_text("speed: 0.3\ngain: 0.6\n")
    return sub


# ---------------------------------------------------------------------------------- the real agent node
@pytest.mark.parametrize(("transport", "extra"), [("fifo", ""), ("pipe", " --quiet")])
def test_real_aido_agent_runs_with_no_reflection(tmp_path: Path, solution: Path, aido_python: str,
                                                 transport: str, extra: str) -> None:
    cmd = f"cd {shlex.quote(str(solution))} && exec {shlex.quote(aido_python)} solution.py{extra}"
    res = runner.invoke(app, ["run", "--agent-cmd", cmd, "--transport", transport, "--no-reflection", "--seconds",
                              "6", "--width", "160", "--height", "120", "--no-video", "--start-timeout", "120",
                              "--out", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["termination"] == "timeout" and metrics["survival_time"] == 6.0  # it follows the lane
    assert metrics["driven_lanedir_consec"] > 0.5 and metrics["agent"] == "remote:solution"


def test_real_aido_agent_falls_back_without_reflection(solution: Path, aido_python: str) -> None:
    res = runner.invoke(app, ["agent", "check", f"{shlex.quote(aido_python)} solution.py", "--agent-cwd",
                              str(solution), "--transport", "fifo", "--start-timeout", "120", "--seconds", "1"])
    assert res.exit_code == 0, res.output
    assert "describe_protocol failed (aborted" in res.output and "started again without" in res.output
    assert "15 frames" in res.output


# ---------------------------------------------------------------------------------- AIDO's types
def _conversation(extensions: bool) -> bytes:
    """A whole AIDO-style episode with the proxybench robot node: what the caller wrote, then what it answered."""
    m = load_map("loop_3x3")
    spawn_npc = {"playable": False, "owned_by_player": False, "robot_name": "npc0", "dynamics": "DB18",
                 "dynamics_params": {}, "color": "blue", "simulate_camera": False,
                 "configuration": {"pose": {"x": 0.8775, "y": 1.46, "theta_deg": 0.0},
                                   "velocity": {"x": 0.0, "y": 0.0, "theta_deg": 0.0}}}
    inputs = [wire.encode_seed(3), rw.encode_clear(), rw.encode_set_map(map_yaml(m)),
              rw.encode_spawn_robot("ego", start_pose(m, 3)), wire.encode_topic("spawn_robot", spawn_npc),
              wire.encode_topic("spawn_duckie", {"name": "duckie0", "color": "yellow",
                                                 "pose": {"x": 1.4, "y": 0.9, "theta_deg": 30.0}}),
              rw.encode_get_robot_interface_description("ego"),
              wire.encode_episode_start("e1", json.dumps({"seed": 3, "proxybench": extensions}))]
    for k in range(3):
        t = k / 15
        inputs += [wire.encode_topic("dump_state", {}), rw.encode_get_robot_state("ego", t),
                   rw.encode_get_robot_state("npc0", t),
                   wire.encode_topic("get_duckie_state", {"duckie_name": "duckie0", "t_effective": t}),
                   rw.encode_get_sim_state(), rw.encode_get_robot_performance("ego"),
                   rw.encode_get_robot_observations("ego", t), rw.encode_set_robot_commands("ego", t, 0.3, 0.35),
                   rw.encode_step((k + 1) / 15), wire.encode_topic("get_ui_image", None)]
    out = io.BytesIO()
    node = RobotNode(DomainParams(image_width=64, image_height=48), "loop_3x3")
    assert serve_robot(node, io.BytesIO(b"".join(inputs)), out, exit_on_abort=False) == 0
    return b"".join(inputs) + out.getvalue()


@pytest.mark.parametrize("extensions", [False, True])
def test_robot_protocol_messages_decode_as_aido_types(tmp_path: Path, aido_python: str, extensions: bool) -> None:
    path = tmp_path / "messages.cbor"
    path.write_bytes(_conversation(extensions))
    res = subprocess.run([aido_python, str(AIDO / "decode_messages.py"), str(path)], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    rows = [json.loads(line) for line in res.stdout.splitlines()]
    bad = [r for r in rows if not r["ok"]]
    assert not bad, bad[:3]
    topics = {r["topic"] for r in rows}
    assert topics >= {"spawn_robot", "spawn_duckie", "set_robot_commands", "robot_state", "duckie_state",
                      "state_dump", "sim_state", "robot_observations", "robot_performance", "ui_image",
                      "robot_interface_description"}
    spawn = next(r["value"] for r in rows if r["topic"] == "spawn_robot")
    x, y, th = start_pose(load_map("loop_3x3"), 3)
    assert (spawn["x"], spawn["y"]) == (x, y) and spawn["theta_deg"] == pytest.approx(np.degrees(th))
    ego0 = next(r["value"] for r in rows if r["topic"] == "robot_state" and r["value"]["robot_name"] == "ego")
    np.testing.assert_allclose(ego0["pose"], se2_matrix(x, y, th), atol=1e-12)  # where it was spawned
    npc = [r["value"] for r in rows if r["topic"] == "robot_state" and r["value"]["robot_name"] == "npc0"]
    assert all(np.allclose(v["pose"], se2_matrix(0.8775, 1.46, 0.0)) for v in npc)  # parked, as AIDO parks NPCs
    dump = [r["value"] for r in rows if r["topic"] == "state_dump"][-1]
    assert dump["duckiebots"] == ["ego", "npc0"] and dump["duckies"] == ["duckie0"]


# ---------------------------------------------------------------------------------- AIDO's experiment manager
def test_aido_experiment_manager_accepts_the_robot_node(tmp_path: Path, aido_python: str) -> None:
    serve = [sys.executable, "-m", "proxybench.cli", "robot", "serve", "--param", "image_width=160", "--param",
             "image_height=120"]
    res = subprocess.run([aido_python, str(AIDO / "experiment_manager.py"), str(tmp_path), "12", "--", *serve],
                         capture_output=True, text=True, timeout=300, env={**os.environ, "NUMBA_NUM_THREADS": "1"})
    seen = json.loads(res.stdout.splitlines()[-1]) if res.stdout.strip() else {}
    assert res.returncode == 0 and seen.get("ok"), seen.get("error") or res.stderr[-3000:]
    assert seen["protocol_checked"] and seen["steps"] == 12  # description checked against protocol_simulator_DB20
    assert seen["terminations"] == {"ego": None, "npc0": None} and seen["exit_code"] == 0
    assert seen["jpg_bytes"] > 500 and seen["ui_jpg_bytes"] > 500
    poses = np.array(seen["poses"])
    assert poses[0, 0, 2] == pytest.approx(0.2925) and poses[-1, 1, 2] < poses[0, 1, 2] - 0.05  # it drove south


# ---------------------------------------------------------------------------------- a stock AIDO simulator
@pytest.fixture
def stock_sim(tmp_path: Path, aido_python: str) -> list[str]:
    frame = tmp_path / "frame.jpg"
    frame.write_bytes(jpeg.encode(np.full((120, 160, 3), 90, np.uint8)))
    return [aido_python, str(AIDO / "stock_sim.py"), str(frame)]


@pytest.mark.parametrize("transport", ["fifo", "pipe"])
def test_proxybench_drives_a_stock_aido_simulator(stock_sim: list[str], transport: str) -> None:
    with RemoteRobot(stock_sim, transport=transport, init_timeout=120, step_timeout=10) as robot:
        traj = run_episode_on_robot(robot, make_agent("straight"), seed=3, seconds=4.0, map_="loop_3x3")
        described, note = robot.process.description is not None, robot.process.reflection_note
    assert described or "describe_protocol failed" in note  # on Python >= 3.11: the agent's crash, and fallback
    assert traj.meta["source"] == "unreported" and traj.meta["robot"]["kind"] == "unreported"
    assert traj.termination == "off_road"  # AIDO's out-of-tile
    assert traj.events[-1].message == "Robot 'ego' is out of tile." and 1.0 < traj.duration < 4.0
    x, y, _ = start_pose(load_map("loop_3x3"), 3)
    assert (traj["x"][0], traj["y"][0]) == pytest.approx((x, y))
    assert np.diff(traj["t"]) == pytest.approx(1 / 15)  # one sample per frame: a stock simulator sends no trace


def test_a_privileged_agent_is_refused_on_a_robot_without_ground_truth(stock_sim: list[str]) -> None:
    with RemoteRobot(stock_sim, init_timeout=120) as robot, pytest.raises(RobotLacksGroundTruth,
                                                                          match="reports no true lane pose"):
        run_episode_on_robot(robot, make_agent("pid"), seed=3, seconds=1.0, map_="loop_3x3")

