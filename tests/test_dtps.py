"""duckietown-sdk agents in proxybench (docs/dtps.md): parsing without the SDK, episodes with it.

Tests marked ``sdk`` need the SDK environment (``proxybench dtps setup``; see tests/support/dtps.py).
The SDK agents here (tests/dtps_agents, and the lane follower: the Autolab demo's built-in agent,
``cli.autolab_demo.LANE_AGENT``) use only the SDK's public API, except the misbehaving ones.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from proxybench.cli.autolab_demo import LANE_AGENT
from proxybench.dtps import pipe
from proxybench.dtps.env import sdk_python
from proxybench.dtps.maplayer import map_layers
from proxybench.dtps.options import SdkOptions, parse_sdk
from proxybench.experiments.agent_args import AgentArgError, parse_agent
from proxybench.runner.jobs import AgentSpec, NodeAgent, SdkProgram, is_privileged
from proxybench.tasks.agent_entries import AgentEntry
from support.dtps import sdk

AGENTS = Path(__file__).parent / "dtps_agents"


@pytest.fixture(scope="module")
def lane(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding ``lane.py``: the Autolab demo's built-in lane follower."""
    folder = tmp_path_factory.mktemp("lane")
    (folder / "lane.py").write_text(LANE_AGENT)
    return folder


# -------------------------------------------------------------------------------- without the SDK
def test_agent_arguments_name_sdk_programs_and_their_modifiers():
    spec = parse_agent("mine=sdk[lockstep]:python3 agent.py --fast")
    assert spec == SdkProgram("mine", "python3 agent.py --fast", (("timing", "lockstep"),))
    assert spec.node_options() == SdkOptions(timing="lockstep")
    assert parse_agent("node=python3 node.py") == NodeAgent("node", "python3 node.py")
    assert is_privileged(parse_agent("p=sdk[privileged]:python3 a.py"))
    with pytest.raises(AgentArgError, match="unknown sdk modifier 'fast'"):
        parse_agent("mine=sdk[fast]:python3 a.py")
    with pytest.raises(AgentArgError, match="no command"):
        parse_agent("mine=sdk:")
    # the protocol is part of a job's key: the same command as an AIDO node is another agent
    assert AgentSpec.sdk("a", "python3 a.py").key_data() != AgentSpec.node("a", "python3 a.py").key_data()
    assert parse_sdk("python3 sdk.py") is None


def test_benchmark_entries_take_sdk_programs_and_refuse_mixed_options():
    entry = AgentEntry(name="mine", sdk="python3 a.py", timing="lockstep", step_timeout=2)
    spec = parse_agent(entry)
    assert isinstance(spec, SdkProgram) and spec.node_options() == SdkOptions(timing="lockstep", step_timeout=2)
    for bad, match in (({"sdk": "a", "command": "b"}, "not both"), ({"sdk": "a", "transport": "fifo"}, "transport"),
                       ({"command": "a", "timing": "lockstep"}, "timing")):
        with pytest.raises(ValueError, match=match):
            AgentEntry(name="x", **bad)


def test_the_map_layer_places_every_tile_and_object():
    from proxybench.domain.maps import load_map

    m = load_map("loop_3x3")
    layers = map_layers(m)
    assert len(layers["tiles"]) == m.width * m.height
    t = layers["frames"]["map_0/tile_2_1"]["pose"]
    assert (t["x"], t["y"]) == pytest.approx((2.5 * m.tile_size, 1.5 * m.tile_size))
    assert layers["tiles"]["map_0/tile_2_1"]["i"] == 2 and "orientation" in layers["tiles"]["map_0/tile_1_0"]


def test_the_pipe_format_splits_messages_and_refuses_garbage():
    r = pipe.Reader()
    data = pipe.pack({"op": "frame", "jpeg": b"\xff\xd8"}) + pipe.pack({"op": "quit"})
    r.feed(data[:7])
    assert r.next() is None
    r.feed(data[7:])
    assert r.next() == {"op": "frame", "jpeg": b"\xff\xd8"} and r.next() == {"op": "quit"}
    r.feed(b"\x00\x00\x00\x01\x05")  # the CBOR integer 5
    with pytest.raises(pipe.PipeError, match="not a map"):
        r.next()
    r.feed(b"\xff\xff\xff\xff")
    with pytest.raises(pipe.PipeError, match="more than"):
        r.next()


# ---------------------------------------------------------------------------------- with the SDK
def _episode(command: str, seconds: float, **options):
    from proxybench.domain.params import DomainParams
    from proxybench.domain.simulator import Simulator
    from proxybench.dtps.agent import SdkAgent
    from proxybench.runner.episode import run_episode
    from proxybench.runner.outcomes import camera_filter

    sim = Simulator("loop_3x3", DomainParams(image_width=160, image_height=120))
    options = {"start_timeout": 30.0, "cwd": str(AGENTS)} | options
    with SdkAgent(command, options=SdkOptions(**options)) as agent:
        traj = run_episode(sim, agent, 3, seconds, image_filter=camera_filter())
        return traj, agent.stats()


@sdk
def test_an_unchanged_sdk_agent_drives_proxybench_run(tmp_path, lane):
    out = tmp_path / "run"
    run = subprocess.run([sys.executable, "-m", "proxybench", "run", "--agent", "mine=sdk:python3 lane.py",
                          "--seconds", "2", "--width", "160", "--height", "120", "--no-video", "--out", str(out)],
                         cwd=lane, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr + run.stdout
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["agent"] == "mine" and metrics["termination"] == "timeout" and metrics["survival_time"] == 2.0
    assert (out / "trajectory.parquet").exists() and metrics["driven_lanedir_consec"] > 0.1  # it drove


@sdk
def test_lockstep_runs_repeat_sample_for_sample(lane):
    (a, stats), (b, _) = _episode("python3 lane.py", 1.5, timing="lockstep", cwd=str(lane)), \
        _episode("python3 lane.py", 1.5, timing="lockstep", cwd=str(lane))
    assert a.termination == b.termination == "timeout"
    assert stats["extra_commands"] == 0 and stats["frames_answered"] == round(1.5 * 15) - 1
    np.testing.assert_array_equal(a.pose(), b.pose())


@sdk
@pytest.mark.parametrize(("how", "timing", "reason", "start_timeout"), [
    ("silent", "lockstep", "init-timeout", 5.0),  # waited for in full: short (the others must start in time)
    ("crash", "lockstep", "exited", 15.0), ("flood", "realtime", "stdout-flood", 15.0),
    ("nan", "lockstep", "bad-commands", 15.0)])
def test_misbehaving_sdk_agents_end_as_named_failures(how, timing, reason, start_timeout):
    traj, _ = _episode(f"python3 misbehave.py {how}", 3.0, timing=timing, start_timeout=start_timeout,
                       step_timeout=3.0)
    assert traj.termination == "agent_failure"
    (event,) = [e for e in traj.events if e.kind == "agent_failure"]
    assert event.reason == reason, event
    if how == "crash":
        assert event.exit_code == 3 and any("giving up on frame 3" in line for line in event.stderr_tail)


@pytest.mark.slow
@sdk
def test_an_sdk_agent_is_ranked_by_predictivity(tmp_path, lane):
    out = tmp_path / "p"
    run = subprocess.run([sys.executable, "-m", "proxybench", "predictivity", "--quick", "--agent", "pid",
                          "--agent", "straight", "--agent", f"mine=sdk[lockstep]:cd {lane} && exec python3 lane.py",
                          "--episodes", "1", "--seconds", "1.5", "--sweep", "trim=0,0.2", "--pod-seconds", "0",
                          "--backend", "inline", "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:] + run.stdout[-3000:]
    import pandas as pd

    results = pd.read_parquet(next((out / "runs").rglob("results.parquet")))
    assert {"pid", "straight", "mine"} <= set(results.agent)
    assert set(results[results.agent == "mine"].termination) == {"timeout"}


@sdk
def test_dtps_serve_records_episodes_ended_by_the_agents_reset(tmp_path):
    """The agent is started once the server says it serves (an SDK agent started earlier cannot connect); the
    agent reads the camera and publishes state/reset after a second, which ends the episode as ``reset``."""
    out = tmp_path / "serve"
    server = subprocess.Popen([sys.executable, "-m", "proxybench", "dtps", "serve", "--seconds", "90",
                               "--episode-seconds", "30", "--width", "160", "--height", "120", "--out", str(out)],
                              stdout=subprocess.PIPE, text=True)
    agent = None
    log = tmp_path / "agent.log"
    lines: list[str] = []
    try:
        while not any("serving a SIMULATED DB21J" in line for line in lines):
            line = server.stdout.readline()
            assert line, f"the server ended before serving: {lines}"
            lines.append(line)
        with log.open("w") as err:
            agent = subprocess.Popen([str(sdk_python()), str(AGENTS / "reset.py")], stderr=err)
        while not any("end=reset" in line for line in lines):  # until an episode ends by the agent's reset
            line = server.stdout.readline()  # the server ends within --seconds: this loop does too
            assert line, f"the server ended: {lines}; agent (exit {agent.poll()}): {log.read_text()[-2000:]}"
            lines.append(line)
    finally:
        if agent is not None:
            agent.kill()
            agent.wait()
        server.kill()
        server.wait()
    from proxybench.tasks.trajectory import Trajectory

    trajs = [Trajectory.load(p) for p in sorted(out.glob("episode-*.parquet"))]
    ended = [t for t in trajs if t.termination == "reset"]
    assert ended, [t.termination for t in trajs]
    assert ended[0].meta["served"]["stats"]["resets"] >= 1 and ended[0].duration < 30.0


# ------------------------------------------------------------------ agents you start yourself (issue 39 item 5)
def test_dtps_python_without_the_environment_names_the_setup_command(tmp_path):
    run = subprocess.run([sys.executable, "-m", "proxybench", "dtps", "python", "--path", str(tmp_path / "none"),
                          "agent.py"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 1
    assert f"proxybench dtps setup --path {tmp_path / 'none'}" in run.stderr


@sdk
def test_dtps_python_runs_code_with_the_sdk_interpreter_and_passes_its_exit_status():
    """docs/dtps.md §3: a plain `python3 agent.py` lacks duckietown-sdk; `proxybench dtps python` has it, hands
    everything after its own options to python unchanged (-c included), and exits as the script does."""
    code = "import sys, duckietown.sdk; print(sys.executable); print(sys.argv[1:]); sys.exit(3)"
    run = subprocess.run([sys.executable, "-m", "proxybench", "dtps", "python", "-c", code, "--help", "-x"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 3, run.stderr[-2000:]
    assert run.stdout.splitlines() == [str(sdk_python()), "['--help', '-x']"]


@sdk
def test_dtps_check_names_the_interpreter_an_agent_is_started_with():
    run = subprocess.run([sys.executable, "-m", "proxybench", "dtps", "check"], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    assert f"{sdk_python()} agent.py" in run.stdout and "proxybench dtps python agent.py" in run.stdout
