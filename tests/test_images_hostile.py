"""The sandbox's hostile agent (tests/hostile_agents/hostile.py) run from a container image: each attack runs
inside the image's own root file system, ends the node as a failure, and nothing gets through — no secret read,
no connection to the host's listeners, no process of the host signalled, no file written outside, no process
left behind (issue 37, "the sandbox's existing hostile-agent suite passes when run from an image"; the CPU hog with
a CPU limit of 3 s, so that it spins for seconds, not a minute)."""

from __future__ import annotations

import json
import os
import secrets
import shlex
from pathlib import Path

import numpy as np
import pytest

from proxybench.agents.base import Observation
from proxybench.evaluator.image_agent import image_spec
from proxybench.evaluator.sandbox import Limits
from proxybench.protocol import AgentFailure, AgentProcess
from support.images import agent_image
from support.sandbox import AGENT_USER_GROUP, processes_left, require_safe_sandbox

pytestmark = AGENT_USER_GROUP  # its agents run as the agent user: one test at a time
HOSTILE = Path(__file__).with_name("hostile_agents") / "hostile.py"
#: case → what its stderr must say (the attack ran and was stopped)
CASES = {
    "read_secrets": "job, token or database files visible: []",
    "network": "blocked: connect the test's listener, after setns",
    "kill_parent": "now kill(-1)",
    "fork_bomb": "blocked: fork bomb stopped after",
    "leave_child": "leaving a daemon behind",
    "fill_scratch": "/dev/shm full after",
    "memory_hog": "blocked: MemoryError after",
    "artifacts": "blocked: write",
    "fake_outcome": "blocked: write",
    "cpu_hog": "spinning",  # until RLIMIT_CPU (3 s here) or the step timeout ends it
}
#: CPU seconds each case may use (the rlimit): the CPU hog's is short, so that it spins for seconds, not a minute
CPU_SECONDS = {"cpu_hog": 3}


@pytest.fixture(scope="module")
def host(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """What a careless host leaves within reach: a world-readable secret, a work folder, a listener."""
    import socket

    require_safe_sandbox()
    root = tmp_path_factory.mktemp("host")
    os.chmod(root, 0o755)
    secret = root / "admin.token"
    secret.write_text("pbt_" + secrets.token_hex(16))
    secret.chmod(0o644)
    work = root / "work"
    work.mkdir(mode=0o755)
    listener = socket.create_server(("127.0.0.1", 0))
    listener.setblocking(False)
    targets = {"secrets": [str(secret), "/etc/shadow"], "work_dir": str(work), "evaluator_pid": os.getpid(),
               "db": str(root / "server.sqlite3"), "data_dir": str(root), "listener_port": listener.getsockname()[1],
               "server_port": listener.getsockname()[1]}
    # at /agent, where the sandbox shows a package: the agent's own files are not a leak
    image = agent_image(root / "image", HOSTILE, args=("CASE",), user="4242:4242", workdir="/agent", at="agent",
                        files={"targets.json": json.dumps(targets).encode()})
    cache = tmp_path_factory.mktemp("image-cache")
    yield {"image": image, "work": work, "root": root, "listener": listener, "cache": cache}
    listener.close()


def _attack(host: dict, case: str) -> list[str]:
    """Start the image with CASE as its argument, drive it to its first get_commands; its stderr lines."""
    isolation = require_safe_sandbox()
    spec = image_spec("hostile", host["image"], isolation, cache=host["cache"], parent=None,
                      limits=Limits(memory_bytes=1 << 30, cpu_seconds=CPU_SECONDS.get(case, 60)))
    argv = shlex.split(spec.command)
    argv[-1] = case  # the ENTRYPOINT's last word is the case
    lines: list[str] = []
    obs = Observation(np.zeros((60, 80, 3), np.uint8), 0.0, (0.0, 0.0), 0.01)
    with pytest.raises(AgentFailure) as failure, AgentProcess(argv, init_timeout=60, step_timeout=30,
                                                              on_stderr=lines.append) as proc:
        proc.seed(0)
        proc.episode_start("hostile")
        proc.step(obs)
    if case == "cpu_hog":  # killed by its CPU limit (SIGXCPU, then SIGKILL), or the step timeout on a busy machine
        assert failure.value.reason in ("exited", "step-timeout"), failure.value
    return lines


@pytest.mark.parametrize("case", list(CASES))
def test_a_hostile_image_fails_and_nothing_gets_through(host: dict, case: str) -> None:
    before = sorted(os.listdir(host["root"]))
    lines = _attack(host, case)
    text = "\n".join(lines)
    assert f"ATTEMPTED {case}" in text, text[-3000:]  # the attack did run, in the image
    assert CASES[case] in text, text[-3000:]
    assert "ESCAPED" not in text, text[-3000:]
    assert os.listdir(host["work"]) == [] and sorted(os.listdir(host["root"])) == before
    with pytest.raises(BlockingIOError):
        host["listener"].accept()  # no connection reached the host's listener
    assert processes_left(require_safe_sandbox().uid) == []
