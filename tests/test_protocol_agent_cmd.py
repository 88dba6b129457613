"""Agent commands as users write them: shell strings, working directories, pipe or FIFO transport,
timeouts, and nodes whose ``describe_protocol`` crashes (the zuper-nodes wrapper on Python >= 3.11).

The node is ``protocol_agents/zuper311_like.py``, a stand-in that behaves like such a node; the real one
is driven in ``test_aido_real.py``.
"""

from __future__ import annotations

import os
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from proxybench.agents.base import Observation
from proxybench.protocol import AgentFailure, RemoteAgent
from proxybench.protocol.options import NodeOptions
from proxybench.protocol.transport import SHELL, needs_shell, node_argv
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
from proxybench.runner.outcomes import make_agent_for

NODE = Path(__file__).resolve().parent / "protocol_agents" / "zuper311_like.py"
PY = shlex.quote(sys.executable)
OBS = Observation(np.zeros((12, 16, 3), np.uint8), 0.0, (0.0, 0.0), 0.01)


@pytest.fixture
def solution(tmp_path: Path) -> Path:
    """A submission folder as users have them: the node script and a file it needs, in a subfolder."""
    sub = tmp_path / "solution"
    sub.mkdir()
    (sub / "solution.py").write_text(NODE.read_text())
    (sub / "model.bin").write_bytes(b"weights")
    return sub


def drive(agent: RemoteAgent, frames: int = 3) -> np.ndarray:
    agent.reset(seed=1)
    out = None
    for k in range(frames):
        out = agent.act(Observation(OBS.camera, k / 15, (0.0, 0.0), 0.01))
    return out


def starts(folder: Path) -> int:
    return len((folder / "starts.log").read_text().split())


# ------------------------------------------------------------------------------------------ commands
@pytest.mark.parametrize(("cmd", "shell"), [
    ("python node.py --x 1", False),
    ("python 'a b.py'", False),
    (shlex.join(["bwrap", "--", "python3", "-c", "cd x && y"]), False),  # quoted: no shell needed
    ("cd dir && exec node-launch", True),
    ("FOO=1 python a.py", True),
    ("python a.py > log.txt", True),
    ("python $HOME/a.py", True),
    ('python "$X"', True),
    ("python a.py; echo done", True),
    ("exec python a.py", True),
])
def test_shell_syntax_is_detected_outside_quotes(cmd: str, shell: bool) -> None:
    assert needs_shell(cmd) is shell
    assert (node_argv(cmd)[:2] == [SHELL, "-c"]) is shell


def test_argv_lists_never_go_through_a_shell() -> None:
    assert node_argv(["cd", "x", "&&", "y"]) == ["cd", "x", "&&", "y"]
    assert node_argv("python a.py", shell=True) == [SHELL, "-c", "python a.py"]
    with pytest.raises(ValueError, match="empty"):
        node_argv("  ")


def test_a_shell_string_with_cd_runs_the_node_in_that_folder(solution: Path) -> None:
    cmd = f"cd {shlex.quote(str(solution))} && exec {PY} solution.py --need model.bin"
    with RemoteAgent(cmd, transport="pipe", init_timeout=20) as agent:
        assert agent.process.argv[:2] == [SHELL, "-c"]
        assert list(drive(agent)) == [0.2, 0.25]
    assert starts(solution) == 2  # describe_protocol crashed once; started again without it


def test_cwd_option(solution: Path) -> None:
    with RemoteAgent(f"{PY} solution.py --need model.bin", cwd=str(solution), reflection=False,
                     init_timeout=20) as agent:
        assert list(drive(agent)) == [0.2, 0.25]


def test_a_missing_working_directory_is_a_start_failure_naming_it(tmp_path: Path) -> None:
    with pytest.raises(AgentFailure) as info:
        RemoteAgent(f"{PY} solution.py", cwd=str(tmp_path / "nowhere"))
    assert info.value.reason == "start-failed" and "nowhere" in info.value.detail


def test_a_node_missing_its_file_fails_with_its_stderr(tmp_path: Path) -> None:
    (tmp_path / "solution.py").write_text(NODE.read_text())
    with pytest.raises(AgentFailure) as info:
        RemoteAgent(f"{PY} solution.py --need model.bin", cwd=str(tmp_path), init_timeout=20)
    assert info.value.reason == "exited" and info.value.exit_code == 2
    assert any("model.bin" in line for line in info.value.stderr_tail)


# ------------------------------------------------------------------------------------------ transport
def test_over_fifos_a_node_may_print_to_stdout(solution: Path) -> None:
    with RemoteAgent(f"{PY} solution.py --print", cwd=str(solution), transport="fifo", init_timeout=20,
                     on_stderr=None) as agent:
        assert agent.process._os.transport == "fifos"
        assert list(drive(agent)) == [0.2, 0.25]
        deadline = time.monotonic() + 10  # the drain reads the node's stderr pipe on its own thread
        while not any("loading the model" in line for line in agent.process._os.stderr.tail()) \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        tail = agent.process._os.stderr.tail()
    assert any("loading the model" in line for line in tail), tail  # its stdout went to the stderr drain


def test_over_pipes_a_printing_node_fails_with_a_hint(solution: Path) -> None:
    with pytest.raises(AgentFailure) as info:
        agent = RemoteAgent(f"{PY} solution.py --print", cwd=str(solution), reflection=False, init_timeout=20)
        drive(agent)
    assert info.value.reason == "garbage"
    assert "loading the model" in info.value.detail and "fifo" in info.value.detail


def test_fifos_in_a_given_folder(solution: Path, tmp_path: Path) -> None:
    shared = tmp_path / "fifos"
    shared.mkdir()
    with RemoteAgent(f"{PY} solution.py", cwd=str(solution), transport="fifo", fifo_dir=str(shared),
                     reflection=False, init_timeout=20) as agent:
        made = list(shared.iterdir())
        assert len(made) == 1 and (made[0] / "in").exists() and (made[0] / "out").exists()
        assert list(drive(agent)) == [0.2, 0.25]
    assert list(shared.iterdir()) == []  # removed with the node


@pytest.mark.parametrize("plant", ["os.symlink(SECRET, OUT)", "open(OUT, 'w').write(open(SECRET).read())"])
def test_only_a_fifo_is_read_as_the_nodes_output(tmp_path: Path, plant: str) -> None:
    """A node that puts a link to (or a copy of) a file where its output FIFO belongs gets the caller to read
    nothing of it: a ``garbage`` failure that quotes none of the file."""
    secret = tmp_path / "job.json"
    secret.write_text('{"hidden_seed": 424242}')
    code = (f"import os, time; SECRET = {str(secret)!r}; OUT = os.environ['AIDONODE_DATA_OUT'][5:]; {plant}; "
            "time.sleep(30)")
    with pytest.raises(AgentFailure) as info:
        RemoteAgent([sys.executable, "-c", code], transport="fifo", init_timeout=20)
    assert info.value.reason == "garbage" and "FIFO" in info.value.detail
    assert "424242" not in str(info.value)


# ------------------------------------------------------------------------------------------ reflection
def test_describe_protocol_crash_falls_back_once(solution: Path, caplog: pytest.LogCaptureFixture) -> None:
    with RemoteAgent(f"{PY} solution.py", cwd=str(solution), init_timeout=20) as agent:
        assert agent.process.description is None
        assert "describe_protocol failed (aborted" in agent.process.reflection_note
        assert list(drive(agent)) == [0.2, 0.25]
    assert starts(solution) == 2
    assert any("started again without protocol reflection" in r.message for r in caplog.records)


def test_no_reflection_starts_once(solution: Path) -> None:
    with RemoteAgent(f"{PY} solution.py", cwd=str(solution), reflection=False, init_timeout=20) as agent:
        assert agent.process.reflection_note is None and agent.process.description is None
        assert not agent.privileged
        drive(agent)
    assert starts(solution) == 1


# ------------------------------------------------------------------------------------------ timeouts, reaping
def test_start_timeout(solution: Path) -> None:
    t0 = time.monotonic()
    with pytest.raises(AgentFailure) as info:
        RemoteAgent(f"{PY} solution.py --slow 30", cwd=str(solution), init_timeout=1.0)
    assert info.value.reason == "init-timeout" and time.monotonic() - t0 < 6.0


def test_step_timeout_kills_the_node_behind_a_shell(solution: Path) -> None:
    """A shell that does not exec (node as its child): the whole group is killed and the node is gone."""
    pid_file = solution / "pid"
    cmd = f"cd {shlex.quote(str(solution))} && {PY} solution.py --hang-on get_commands --pid-file pid; echo after"
    agent = RemoteAgent(cmd, reflection=False, init_timeout=20, step_timeout=0.5)
    agent.reset(seed=1)
    t0 = time.monotonic()
    with pytest.raises(AgentFailure) as info:
        agent.act(OBS)
    assert info.value.reason == "step-timeout" and time.monotonic() - t0 < 5.0
    node = int(pid_file.read_text())
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and _alive(node):
        time.sleep(0.05)
    assert not _alive(node), "the node behind the shell survived the failure"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie waiting for its new parent counts as gone
        return f.read().split(")")[-1].split()[0] != "Z"


# ------------------------------------------------------------------------------------------ options, specs
def test_node_options_validate_and_name_the_field() -> None:
    assert NodeOptions(transport="fifo").process_kwargs()["transport"] == "fifos"
    for bad, field in ((dict(transport="tcp"), "transport"), (dict(step_timeout=0), "step_timeout"),
                       (dict(start_timeout=float("inf")), "start_timeout"), (dict(reflektion=False), "reflektion")):
        with pytest.raises(ValidationError) as info:
            NodeOptions(**bad)
        assert info.value.errors()[0]["loc"] == (field,)


def test_agent_spec_carries_options_and_old_job_keys_stay(solution: Path) -> None:
    plain = AgentSpec("pid")
    job = Job(plain, DomainSpec("default"), "loop_3x3", 0, 0, 1.0)
    assert plain.key_data() == {"name": "pid", "command": None}
    spec = AgentSpec.node("mine", f"{PY} solution.py", NodeOptions(cwd=str(solution), reflection=False,
                                                                  step_timeout=2.0))
    assert hash(spec) and spec.node_options().step_timeout == 2.0
    assert Job(spec, job.domain, job.map, 0, 0, 1.0).key != Job(AgentSpec.node("mine", f"{PY} solution.py"), job.domain,
                                                                 job.map, 0, 0, 1.0).key
    agent = make_agent_for(spec)
    try:
        assert agent.name == "mine" and agent.process.step_timeout == 2.0
        assert list(drive(agent)) == [0.2, 0.25]
    finally:
        agent.close()
    assert starts(solution) == 1


def test_a_restarted_node_skips_the_request_that_failed_before(solution: Path) -> None:
    agent = RemoteAgent(f"{PY} solution.py --hang-on get_commands", cwd=str(solution), init_timeout=20,
                        step_timeout=0.5)
    assert starts(solution) == 2  # the crash on describe_protocol, then the fallback
    agent.reset(seed=1)
    with pytest.raises(AgentFailure):
        agent.act(OBS)
    agent.reset(seed=2)  # a fresh process, started without describe_protocol
    assert agent.restarts == 1 and agent.process.reflection is False and starts(solution) == 3
    agent.close()
