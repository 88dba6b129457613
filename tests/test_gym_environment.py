"""`gym setup`'s environment check tells a setup that has not finished from one made with other pins (issue 39:
an environment still being built read "was not installed from this proxybench's pins", like a version conflict)."""

from __future__ import annotations

from pathlib import Path

from proxybench.gym.environment import _STAMP, check_environment


def _fake_venv(tmp_path: Path) -> Path:
    (tmp_path / "bin").mkdir()
    (tmp_path / "bin" / "python").write_text("")
    return tmp_path


def test_an_unfinished_setup_says_so_and_how_to_finish(tmp_path: Path) -> None:
    problems = check_environment(_fake_venv(tmp_path), render=False).problems
    said = [p for p in problems if str(tmp_path) in p]
    assert said and "not finished" in said[0] and "proxybench gym setup" in said[0] and "pins" not in said[0]


def test_other_pins_say_so(tmp_path: Path) -> None:
    (_fake_venv(tmp_path) / _STAMP).write_text("gym-duckietown==0.0\n")
    said = [p for p in check_environment(tmp_path, render=False).problems if str(tmp_path) in p]
    assert said and "other pins" in said[0] and "proxybench gym setup" in said[0]
