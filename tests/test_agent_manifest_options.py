"""Agent package manifests take agent commands as users write them, with the same start-up options as the
CLI and benchmark files, capped so that a package cannot hold an evaluator for long."""

from __future__ import annotations

import io
import shlex
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import yaml

from proxybench.protocol import RemoteAgent
from proxybench.protocol.package import AgentManifest, PackageError, check_archive

NODE = Path(__file__).resolve().parent / "protocol_agents" / "zuper311_like.py"


def manifest(**fields) -> AgentManifest:
    return AgentManifest(**{"name": "a", "protocol": "aido-z2", "command": ["python3", "agent.py"], **fields})


def archive(fields: dict, files: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("proxybench-agent.yaml", yaml.safe_dump({"name": "a", "protocol": "aido-z2", **fields}))
        for name, data in files.items():
            zf.writestr(name, data)
    return buf.getvalue()


def test_a_command_string_runs_through_a_shell() -> None:
    assert manifest(command="cd sol && exec python3 agent.py").command == ["/bin/sh", "-c",
                                                                          "cd sol && exec python3 agent.py"]


def test_cwd_is_a_folder_inside_the_package_put_in_front_of_the_command(tmp_path: Path) -> None:
    m = manifest(cwd="solution/", command=[sys.executable, "-c", "import os; print(os.getcwd())"])
    assert m.cwd == "solution"
    (tmp_path / "solution").mkdir()
    out = subprocess.run(m.command, cwd=tmp_path, capture_output=True, text=True, check=True).stdout
    assert out.strip() == str(tmp_path / "solution")
    assert manifest(cwd="solution").model_copy().command == manifest(cwd="solution").command  # wrapped once


@pytest.mark.parametrize(("fields", "field"), [
    ({"cwd": "../outside"}, "cwd"), ({"cwd": "/etc"}, "cwd"), ({"step_timeout": 120}, "step_timeout"),
    ({"start_timeout": 3600}, "start_timeout"), ({"transport": "tcp"}, "transport"), ({"command": " "}, "command"),
    ({"reflektion": False}, "reflektion"),
])
def test_bad_fields_are_refused_naming_the_field(fields: dict, field: str) -> None:
    with pytest.raises(PackageError, match=f"field '{field}'"):
        check_archive(archive({"command": ["python3", "agent.py"], **fields}, {"agent.py": b""}))


def test_options_reach_the_node(tmp_path: Path) -> None:
    m = check_archive(archive({"command": f"{shlex.quote(sys.executable)} solution.py --print", "cwd": "sol",
                               "transport": "fifo", "reflection": False, "step_timeout": 2}, {}))
    options = m.node_options()
    assert (options.transport, options.reflection, options.step_timeout) == ("fifo", False, 2.0)
    (tmp_path / "sol").mkdir()
    (tmp_path / "sol" / "solution.py").write_text(NODE.read_text())
    with RemoteAgent(m.command, **{**options.process_kwargs(), "cwd": str(tmp_path)}) as agent:
        agent.reset(seed=0)
    assert (tmp_path / "sol" / "starts.log").read_text().count("\n") == 1
