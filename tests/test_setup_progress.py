"""`gym setup` and `dtps setup` say what they do (issue 39 item 3: both were silent for 9–10 minutes): numbered
steps with their times, pip's progress, the total; a second run with nothing to do says "in place" and never
reaches pip. No wall clock here: the steps' clock is a fake one, and pip is a fake process."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import pytest

from proxybench import venv
from proxybench.dtps import env as dtps_env
from proxybench.gym import environment as gym_env
from proxybench.venv import PipError, Steps, duration, pip_install, requirement_count


class _NoPip:
    """subprocess.run / Popen that answer the checks' probes and fail on pip, venv and apt-get."""

    def __init__(self, probe_stdout: str):
        self.calls: list[list[str]] = []
        self.probe_stdout = probe_stdout

    def run(self, cmd: list[str], *args: Any, **kwargs: Any) -> subprocess.CompletedProcess:
        cmd = [str(c) for c in cmd]
        self.calls.append(cmd)
        if "pip" in cmd or "venv" in cmd or cmd[0] == "apt-get":
            raise AssertionError(f"a setup with nothing to do ran {cmd}")
        if any("sys.version_info" in c for c in cmd):  # gym setup asks the interpreter's version first
            return subprocess.CompletedProcess(cmd, 0, "3 11 7\n", "")
        return subprocess.CompletedProcess(cmd, 0, self.probe_stdout, "")

    def popen(self, cmd: list[str], *args: Any, **kwargs: Any) -> None:
        raise AssertionError(f"a setup with nothing to do started {cmd}")


def _in_place(path: Path) -> Path:
    (path / "bin").mkdir(parents=True)
    (path / "bin" / "python").write_text("")
    return path


def _no_venv(*args: Any) -> None:
    raise AssertionError("a setup with nothing to do made a virtual environment")


def test_a_second_gym_setup_says_in_place_and_does_not_call_pip(tmp_path, monkeypatch):
    path = _in_place(tmp_path / "gym")
    (path / gym_env._STAMP).write_text(gym_env.REQUIREMENTS.read_text())
    fake = _NoPip(json.dumps({"duckietown-gym-daffy": gym_env.GYM_VERSION, "numpy": "1.23.5", "pyglet": "1.5.31",
                              "frame": [24, 32, 3]}))
    monkeypatch.setattr(subprocess, "run", fake.run)
    monkeypatch.setattr(subprocess, "Popen", fake.popen)
    monkeypatch.setattr(gym_env, "make_venv", _no_venv)
    monkeypatch.setattr(gym_env, "missing_apt_packages", lambda: [])
    said: list[str] = []
    env = gym_env.setup_environment(path, say=said.append)
    assert env.ok, env.problems
    assert said[-1].startswith("nothing to do") and "in place" in said[-1] and str(path) in said[-1]
    assert [line[:4] for line in said if line[:1].isdigit()] == ["1/4 ", "2/4 ", "3/4 ", "4/4 "]
    assert any("98 pinned packages: in place" in line for line in said), said


def test_a_second_dtps_setup_says_in_place_and_does_not_call_pip(tmp_path, monkeypatch):
    path = _in_place(tmp_path / "sdk")
    (path / dtps_env._MARKER).write_text(json.dumps({"packages": list(dtps_env.PACKAGES)}))
    fake = _NoPip(json.dumps({"duckietown-sdk": "0.2.0", "dtps-http": "1.6.1", "duckietown-messages": "0.0.28",
                              "pydantic": "2.10.6"}))
    monkeypatch.setattr(subprocess, "run", fake.run)
    monkeypatch.setattr(subprocess, "Popen", fake.popen)
    monkeypatch.setattr(dtps_env, "make_venv", _no_venv)
    monkeypatch.setattr(dtps_env, "turbojpeg_found", lambda: True)
    said: list[str] = []
    status = dtps_env.setup_env(path, say=said.append)
    assert status.ok, status.problems
    assert said[-1].startswith("nothing to do") and "in place" in said[-1]
    assert sum(": in place" in line for line in said) == 3
    assert fake.calls and all("pip" not in c for c in fake.calls)  # the check ran, pip did not


def test_a_fresh_gym_setup_says_each_step_pips_progress_and_the_total(tmp_path, monkeypatch):
    """A missing environment: the venv is made, pip runs (a fake one printing what pip prints), the stamp is
    written, and the output names the package count, the steps' times and the total."""
    path = tmp_path / "gym"
    made: list[Path] = []
    installed: list[list[str]] = []

    def fake_make(where: Path) -> None:
        _in_place(where)
        made.append(where)

    def fake_pip(python: Path, args: list[str], say, *, expected: int | None = None, **kw: Any) -> None:
        installed.append(list(args))
        say(f"    {expected}/{expected} packages fetched; installing {expected} of them (1.0 s)")

    fake = _NoPip(json.dumps({"duckietown-gym-daffy": gym_env.GYM_VERSION, "numpy": "1.23.5", "pyglet": "1.5.31",
                              "frame": [24, 32, 3]}))
    monkeypatch.setattr(subprocess, "run", fake.run)
    monkeypatch.setattr(gym_env, "make_venv", fake_make)
    monkeypatch.setattr(gym_env, "missing_apt_packages", lambda: [])
    monkeypatch.setattr(gym_env, "pip_install", fake_pip)
    said: list[str] = []
    env = gym_env.setup_environment(path, say=said.append)
    assert env.ok, env.problems
    assert made == [path] and installed == [["-r", str(gym_env.REQUIREMENTS)]]
    assert (path / gym_env._STAMP).read_text() == gym_env.REQUIREMENTS.read_text()
    assert any(line.startswith("2/4 creating the virtual environment") for line in said), said
    assert any(line.startswith("3/4 installing 98 packages") for line in said), said
    assert sum("done in" in line for line in said) == 3  # venv, pip, check
    assert said[-1].startswith("gym setup took ")
    # and the next run has nothing to do
    monkeypatch.setattr(gym_env, "make_venv", _no_venv)
    monkeypatch.setattr(gym_env, "pip_install", lambda *a, **k: pytest.fail("pip ran again"))
    said.clear()
    gym_env.setup_environment(path, say=said.append)
    assert said[-1].startswith("nothing to do")


def test_steps_number_and_time_themselves_on_their_clock():
    now = [100.0]
    said: list[str] = []
    steps = Steps(3, said.append, clock=lambda: now[0])
    steps.in_place("first: in place")
    with steps.step("second"):
        now[0] += 75.0
    with steps.step("third", work=False):
        now[0] += 2.5
    assert said == ["1/3 first: in place", "2/3 second ...", "    2/3 done in 1 min 15 s", "3/3 third ...",
                    "    3/3 done in 2.5 s"]
    assert steps.worked and duration(steps.elapsed()) == "1 min 18 s"


def test_requirement_count_skips_comments_blanks_and_options():
    assert requirement_count(["# a freeze", "", "numpy==1.23.5", "  -r other.txt", "--index-url x", "a==1"]) == 2


def test_pip_progress_is_said_and_a_failure_keeps_pips_last_lines(tmp_path, monkeypatch):
    """pip_install reads pip's own output: packages fetched (rate-limited by its clock), the install step, and on
    failure pip's last lines in the error."""
    lines = ([f"Collecting pkg{i}==1.0\n" for i in range(4)] + ["Processing /opt/wheels/pkg4-1.0-py3-none-any.whl\n",
             "  Downloading pkg4-1.0.whl (1 kB)\n", "Installing collected packages: a, b, c\n"])

    class FakePopen:
        def __init__(self, cmd: list[str], **kwargs: Any):
            self.cmd, self.stdout, self.returncode = cmd, iter(lines), 0

        def __enter__(self) -> FakePopen:
            return self

        def __exit__(self, *exc: object) -> None:
            return None

    monkeypatch.setattr(venv.subprocess, "Popen", FakePopen)
    ticks = iter(range(0, 1000, 10))  # each clock reading 10 s later
    said: list[str] = []
    pip_install(tmp_path / "python", ["-r", "req.txt"], said.append, expected=5, every=15.0,
                clock=lambda: float(next(ticks)))
    assert said and all("packages fetched" in line for line in said)
    assert any("/5 packages fetched" in line and "installing" not in line for line in said)
    assert "5/5 packages fetched; installing 3 of them" in said[-1]

    lines[:] = ["Collecting nothing-such==9\n", "ERROR: No matching distribution found for nothing-such==9\n"]

    class FailingPopen(FakePopen):
        def __init__(self, cmd: list[str], **kwargs: Any):
            super().__init__(cmd, **kwargs)
            self.returncode = 1

    monkeypatch.setattr(venv.subprocess, "Popen", FailingPopen)
    with pytest.raises(PipError, match="No matching distribution found for nothing-such"):
        pip_install(tmp_path / "python", ["nothing-such==9"], said.append)
