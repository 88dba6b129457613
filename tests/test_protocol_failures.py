"""Every way a node can misbehave ends in one AgentFailure with its reason code, fast, process reaped."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from proxybench.agents.base import Observation
from proxybench.protocol import REASONS, AgentFailure, AgentProcess

MISBEHAVE = [sys.executable, str(Path(__file__).resolve().parent / "protocol_agents" / "misbehave.py")]
STEP_TIMEOUT = 0.5
INIT_TIMEOUT = 1.0
MARGIN = 2.0  # process start, kill and reap, slow CI


def provoke(mode: str, trigger: str = "get_commands", **kwargs) -> tuple[AgentFailure, float, AgentProcess | None]:
    """Drive the misbehaving node through a short episode; (failure, seconds taken, process if built)."""
    kwargs = {"init_timeout": INIT_TIMEOUT, "step_timeout": STEP_TIMEOUT, **kwargs}
    proc = None
    t0 = time.monotonic()
    try:
        proc = AgentProcess([*MISBEHAVE, mode, trigger], **kwargs)
        proc.seed(1)
        proc.episode_start("e")
        proc.observe(Observation(np.zeros((12, 16, 3), np.uint8), 0.0, (0.0, 0.0), 0.01))
        proc.get_commands(0.0)
    except AgentFailure as failure:
        return failure, time.monotonic() - t0, proc
    pytest.fail(f"mode {mode!r} did not fail")


def assert_reaped(failure: AgentFailure, proc: AgentProcess | None) -> None:
    assert failure.pid is not None and failure.exit_code is not None
    with pytest.raises(ChildProcessError):
        os.waitpid(failure.pid, os.WNOHANG)  # already reaped: no longer our child
    if proc is not None:
        assert proc.poll() is not None and not proc.alive


CASES = [
    ("crash", "get_commands", "exited"),
    ("crash", "capabilities", "exited"),
    ("exit0", "observations", "exited"),
    ("garbage", "get_commands", "garbage"),
    ("text", "get_commands", "garbage"),
    ("not-a-map", "get_commands", "not-a-map"),
    ("truncated", "get_commands", "truncated"),
    ("bad-message", "seed", "bad-message"),
    ("unknown-topic", "get_commands", "unknown-topic"),
    ("not-understood", "get_commands", "not-understood"),
    ("aborted", "get_commands", "aborted"),
    ("missing-understood", "get_commands", "out-of-order"),
    ("no-commands", "get_commands", "out-of-order"),
    ("two-commands", "get_commands", "out-of-order"),
    ("nan", "get_commands", "bad-commands"),
    ("range", "get_commands", "bad-commands"),
    ("wrong-type", "get_commands", "bad-commands"),
    ("bool", "get_commands", "bad-commands"),
    ("incompatible", "wrapper.describe_protocol", "incompatible"),
    ("stdout-flood", "get_commands", "stdout-flood"),
    ("stdout-flood-messages", "get_commands", "stdout-flood"),
    ("stderr-flood", "get_commands", "stderr-flood"),
]


@pytest.mark.parametrize(("mode", "trigger", "reason"), CASES, ids=[f"{m}@{t}" for m, t, _ in CASES])
def test_misbehaviour_is_classified(mode, trigger, reason):
    failure, took, proc = provoke(mode, trigger, max_reply_bytes=1 << 20, max_stderr_bytes=256 << 10)
    assert failure.reason == reason, failure
    assert reason in REASONS
    assert took < MARGIN, f"took {took:.2f} s"
    assert_reaped(failure, proc)


def test_crash_reports_exit_code_and_stderr():
    failure, _, _ = provoke("crash")
    assert failure.exit_code == 3 and failure.stderr_tail[-2:] == ["starting to fail", "boom: something broke"]
    assert "exit code 3" in str(failure) and "boom: something broke" in str(failure)


def test_aborted_keeps_the_traceback():
    failure, _, _ = provoke("aborted")
    assert failure.exit_code == 1 and failure.detail.endswith("ValueError: kaput")


@pytest.mark.parametrize("transport", ["pipes", "fifos"])
def test_hang_at_init_times_out(transport):
    failure, took, _ = provoke("hang", "capabilities", transport=transport)
    assert failure.reason == "init-timeout"
    assert INIT_TIMEOUT <= took < INIT_TIMEOUT + MARGIN
    assert_reaped(failure, None)


@pytest.mark.parametrize(("trigger", "reason"), [("get_commands", "step-timeout"), ("observations", "step-timeout"),
                                                 ("episode_start", "init-timeout")])
def test_hang_at_step_times_out(trigger, reason):
    failure, took, proc = provoke("hang", trigger)
    assert failure.reason == reason and took < INIT_TIMEOUT + MARGIN
    assert_reaped(failure, proc)


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_timeout_kills_the_whole_process_group():
    failure, took, _ = provoke("spawn-and-hang")
    assert failure.reason == "step-timeout" and took < STEP_TIMEOUT + MARGIN
    child = int(next(line for line in failure.stderr_tail if line.startswith("spawned")).split()[1])
    deadline = time.monotonic() + 2.0
    while not _gone(child) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert _gone(child)


@pytest.mark.parametrize("mode", ["crash", "garbage", "aborted"])
def test_failures_over_fifos(mode):
    failure, took, proc = provoke(mode, transport="fifos")
    assert failure.reason == {"crash": "exited", "garbage": "garbage", "aborted": "aborted"}[mode]
    assert took < MARGIN
    assert_reaped(failure, proc)


def test_start_failure():
    with pytest.raises(AgentFailure) as exc:
        AgentProcess(["/nonexistent/agent-binary"])
    assert exc.value.reason == "start-failed" and exc.value.exit_code is None


def test_failure_pickles():
    import pickle

    failure = AgentFailure("aborted", "tb", 1, ["x"], pid=7)
    back = pickle.loads(pickle.dumps(failure))
    assert (back.reason, back.detail, back.exit_code, back.stderr_tail, back.pid) == ("aborted", "tb", 1, ["x"], 7)
    with pytest.raises(ValueError):
        AgentFailure("weird", "")


def test_every_reason_is_documented():
    doc = (Path(__file__).resolve().parents[1] / "docs" / "protocol.md").read_text()
    for reason in REASONS:
        assert f"| `{reason}` |" in doc, reason
