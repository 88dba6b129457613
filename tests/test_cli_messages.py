"""Messages off a terminal (issue 23 §6, issue 28 §3): no literal rich markup (``[red]✗[/red]``) and no numpy
reprs (``np.float64(0.0)``) in what a command prints when its output is a file or a pipe, and a user's own
text (``[x]``) printed as it is."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from proxybench.cli import app


def _bad_recording(root: Path) -> Path:
    root.mkdir()
    (root / "target.yaml").write_text(yaml.safe_dump({"source": "real", "map": "loop_3x3", "seconds": 2.0,
                                                      "agents": ["a[x]"], "episodes": [0],
                                                      "trajectories": "{agent}-{episode}.csv"}))
    t = np.array([0.0, 0.1, 0.1, 0.3])  # time stands still at row 3
    pd.DataFrame({"t": t, "x": 0.3 + t, "y": np.full(4, 0.9), "theta": np.zeros(4)}).to_csv(root / "a[x]-0.csv",
                                                                                           index=False)
    return root


def test_target_check_off_a_terminal_prints_plain_text(tmp_path: Path) -> None:
    result = CliRunner().invoke(app, ["target", "check", str(_bad_recording(tmp_path / "rec"))],
                                env={"COLUMNS": "200"})
    assert result.exit_code == 1
    out = result.output
    assert "[red]" not in out and "[/red]" not in out and "np.float64" not in out, out
    assert "✗ " in out and "time is not increasing (0.1 → 0.1 s)" in out and "a[x]-0.csv" in out, out


def test_the_error_printer_shows_user_text_as_it_is(capsys: pytest.CaptureFixture[str]) -> None:
    from proxybench.cli.app import problem

    problem("file [bold]x[/bold].yaml: line 1\nsecond line")
    err = capsys.readouterr().err
    assert err.splitlines() == ["✗ file [bold]x[/bold].yaml: line 1", "✗ second line"]


def test_trajectory_messages_show_plain_numbers(tmp_path: Path) -> None:
    from proxybench.tasks.trajectory import Trajectory, TrajectoryError

    path = tmp_path / "run.csv"
    pd.DataFrame({"t": [0.0, 0.5, 0.25], "x": [0.3] * 3, "y": [0.9] * 3, "theta": [0.0] * 3}).to_csv(path, index=False)
    with pytest.raises(TrajectoryError) as info:
        Trajectory.from_file(path, "loop_3x3")
    assert "(0.5 → 0.25)" in str(info.value) and "np." not in str(info.value), str(info.value)
