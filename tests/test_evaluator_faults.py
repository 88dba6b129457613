"""Whose fault, and how long (issue 23 §5): a job runs at most its benchmark's wall-clock budget and then ends
``failed`` with the reason; archives that cannot be unpacked and absurd numbers from an agent node are the
submission's fault, never a dead worker (``error``); tar packages unpack on every Python the project accepts.
"""

from __future__ import annotations

import io
import tarfile
import time
import zipfile
from pathlib import Path

import pytest

from proxybench.protocol import wire
from proxybench.protocol.package import PackageError, check_archive
from support.sandbox import AGENT_USER_GROUP, require_safe_sandbox
from test_evaluator import Served, evaluator, the_job
from test_evaluator import served as served_fixture  # noqa: F401 - the fixture, under this name

pytestmark = AGENT_USER_GROUP  # its agents and evaluators run as the agent user: one test at a time

MANIFEST = b"name: mine\nprotocol: aido-z2\ncommand: [python3, agent.py]\n"
SLOW_NODE = """\
import sys, time
import numpy as np
from proxybench.agents.base import Agent
from proxybench.protocol import serve

class Slow(Agent):
    name = "slow"
    def reset(self, seed, episode=None):
        pass
    def act(self, obs):
        time.sleep(4.0)  # just under the step timeout (5 s), every step
        return np.array([0.3, 0.3])

sys.exit(serve(Slow()))
"""
BUDGETED = """\
name: budgeted
map: small_loop
episodes: {count: 1, seed: 3}
duration: 2.0
physics_rate: 30.0
frame_rate: 5.0
wall_time_factor: 1.0
metrics: [survival_time]
scoring:
  - {metric: survival_time_median}
"""


def test_a_job_past_its_wall_clock_budget_fails_with_the_reason(served_fixture: Served,  # noqa: F811
                                                                tmp_path: Path) -> None:
    served = served_fixture
    require_safe_sandbox()
    served.admin.post("/benchmarks", {"yaml": BUDGETED, "hidden_split": False})
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("proxybench-agent.yaml", "name: slow\nprotocol: aido-z2\ncommand: [python3, agent.py]\n")
        zf.writestr("agent.py", SLOW_NODE)
    (tmp_path / "slow.zip").write_bytes(buf.getvalue())
    sub = served.developer.submit_archive(tmp_path / "slow.zip", "slow", benchmark="budgeted")
    ev = evaluator(served, tmp_path, video=False, start_allowance_s=15.0)
    t0 = time.monotonic()
    assert ev.take_one() == "failed"
    took = time.monotonic() - t0
    job, (result,) = the_job(served, sub["id"])
    assert job["status"] == "failed" and "wall-clock budget of 17 s" in result["message"], result["message"]
    assert "1× the simulated time" in result["message"] and took < 40  # 10 steps of 4 s would take 40 s
    assert any(a["name"] == "evaluator.log" for a in result["artifacts"])


def _tar(members: list[tuple[str, bytes | None]]) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tf:
        for name, data in members:
            info = tarfile.TarInfo(name)
            if data is None:
                info.type = tarfile.DIRTYPE
                info.mode = 0o755
                tf.addfile(info)
            else:
                info.size = len(data)
                tf.addfile(info, io.BytesIO(data))
    return buf.getvalue()


def _zip(members: list[tuple[str, bytes]]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in members:
            zf.writestr(name, data)
    return buf.getvalue()


def test_tar_packages_unpack_without_extractall_filter(tmp_path: Path, monkeypatch) -> None:
    """Debian 12's system Python (3.11.2) has no ``extractall(filter=)``: every .tar* package ended ``error``."""
    def extractall_of_3_11_2(self, path=".", members=None, *, numeric_owner=False):
        raise AssertionError("extractall of an unchecked archive")

    from proxybench.protocol.unpack import extract_archive

    monkeypatch.setattr(tarfile.TarFile, "extractall", extractall_of_3_11_2)
    data = _tar([("proxybench-agent.yaml", MANIFEST), ("pkg", None), ("pkg/agent.py", b"print('hi')\n")])
    manifest = extract_archive(data, tmp_path / "out")
    assert manifest.name == "mine" and (tmp_path / "out" / "pkg" / "agent.py").read_bytes() == b"print('hi')\n"


@pytest.mark.parametrize(("members", "says"), [
    ([("a", b"x"), ("a/b", b"y")], "'a' is both a file and a folder"),
    ([("a/b", b"y"), ("a", b"x")], "'a' is both a file and a folder"),
    ([(".", b"x")], "a file must have a name"),
    ([("d/" + "n" * 300, b"x")], "longer than 255 bytes"),
])
@pytest.mark.parametrize("kind", ["zip", "tar"])
def test_archives_that_cannot_be_unpacked_are_refused_naming_the_member(tmp_path: Path, members, says, kind) -> None:
    from proxybench.protocol.unpack import extract_archive

    everything = [("proxybench-agent.yaml", MANIFEST), *members]
    data = _zip(everything) if kind == "zip" else _tar(everything)
    with pytest.raises(PackageError, match=says):
        check_archive(data)
    with pytest.raises(PackageError, match=says):
        extract_archive(data, tmp_path / "out")


@pytest.mark.parametrize("value", [2**1024, -(2**1024), 10**400])
def test_absurd_numbers_from_a_node_are_a_protocol_violation(value: int) -> None:
    with pytest.raises(wire.MessageTypeError, match="motor_left"):
        wire.parse_commands({"wheels": {"motor_left": value, "motor_right": 0.0}})
