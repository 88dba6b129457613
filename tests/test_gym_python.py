"""`gym setup` says which interpreter its pins need before it starts (issue 38 item 5: on Debian 12's own Python
3.11.2 pip stopped half-way, soupsieve 4.1.3 needing 3.11.5). Nothing here installs anything."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.gym import environment
from proxybench.gym.environment import (
    PYTHON_NEEDED,
    PYTHON_WHY,
    REQUIREMENTS,
    GymPythonError,
    check_python,
    python_version,
    setup_environment,
)


def _venv_of(tmp_path: Path, version: str) -> Path:
    """A fake environment whose ``bin/python`` says it is ``version`` (and does nothing else)."""
    (tmp_path / "bin").mkdir(parents=True)
    python = tmp_path / "bin" / "python"
    python.write_text(f"#!/bin/sh\necho {version.replace('.', ' ')}\n")
    python.chmod(0o755)
    return tmp_path


@pytest.mark.parametrize("version", [(3, 11, 5), (3, 11, 7), (3, 11, 14)])
def test_interpreters_the_pins_install_on_pass(version) -> None:
    check_python(version, Path("/usr/bin/python3"), Path("/env"), made=False)


@pytest.mark.parametrize("version", [(3, 11, 2), (3, 11, 4), (3, 12, 0), (3, 13, 1), (3, 10, 14)])
def test_other_interpreters_are_one_line_naming_what_is_needed(version) -> None:
    with pytest.raises(GymPythonError) as exc:
        check_python(version, Path("/usr/bin/python3"), Path("/env"), made=False)
    message = str(exc.value)
    assert "\n" not in message and "/usr/bin/python3 is Python " + ".".join(map(str, version)) in message
    assert "need Python 3.11.5 or a later 3.11" in message and "python3.11 -m venv /env" in message


def test_the_stated_need_is_the_pins_need() -> None:
    """PYTHON_NEEDED is derived from two pins; a changed pin must revisit it (and this test)."""
    pins = dict(line.split("==") for line in REQUIREMENTS.read_text().splitlines() if "==" in line)
    assert pins["soupsieve"] == "4.1.3" and "soupsieve 4.1.3 needs 3.11.5" in PYTHON_WHY
    assert pins["numpy"] == "1.23.5" and "numpy 1.23.5 has no wheels past 3.11" in PYTHON_WHY
    assert PYTHON_NEEDED == ((3, 11, 5), (3, 12, 0))


def test_python_version_asks_the_interpreter(tmp_path: Path) -> None:
    assert python_version(Path(sys.executable)) == tuple(sys.version_info[:3])
    assert python_version(_venv_of(tmp_path, "3.11.2") / "bin" / "python") == (3, 11, 2)


def test_setup_refuses_an_environment_made_by_3_11_2_before_anything_runs(tmp_path: Path) -> None:
    venv = _venv_of(tmp_path / "gym", "3.11.2")
    said: list[str] = []
    with pytest.raises(GymPythonError, match=r"the environment's interpreter .* is Python 3\.11\.2: remove "):
        setup_environment(venv, say=said.append)
    assert said == [] and sorted(os.listdir(venv)) == ["bin"]


def test_setup_refuses_to_make_an_environment_with_3_11_2(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(environment, "python_version", lambda python: (3, 11, 2))
    said: list[str] = []
    with pytest.raises(GymPythonError, match=r"this interpreter .* is Python 3\.11\.2: make the environment first"):
        setup_environment(tmp_path / "gym", say=said.append)
    assert said == [] and not (tmp_path / "gym").exists()


def test_the_cli_says_it_in_one_line_with_exit_2(tmp_path: Path) -> None:
    venv = _venv_of(tmp_path / "gym", "3.11.2")
    res = CliRunner().invoke(app, ["gym", "setup", "--path", str(venv)])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert "Python 3.11.2" in res.output and "3.11.5" in res.output
