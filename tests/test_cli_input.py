"""Bad command-line input gets a clear error naming the option, never a traceback or a nonsense result;
user text prints as it is; long commands print plain progress lines when the output is not a terminal."""

from __future__ import annotations

import io
import re

import pytest
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.cli.progress import PlainProgress, PlainStatus, progress_bar, stage_progress, status

runner = CliRunner()


def flat(text: str) -> str:
    """Output with rich's boxes and line wrapping taken out."""
    return " ".join(re.sub(r"[│╭╮╰╯─]", " ", text).split())


# ---------------------------------------------------------------------------------------------------
# Numeric options: every one is checked, and the error names it


BAD_OPTIONS = [
    (["run", "--seconds", "-5"], "--seconds"),
    (["run", "--seconds", "0"], "--seconds"),
    (["run", "--seconds", "nan"], "--seconds"),
    (["run", "--seconds", "inf"], "--seconds"),
    (["run", "--width", "0"], "--width"),
    (["run", "--height", "100000"], "--height"),
    (["run", "--seed", "-1"], "--seed"),
    (["score", "x.csv", "--episode-seconds", "-1"], "--episode-seconds"),
    (["repeatability", "--seconds", "0"], "--seconds"),
    (["repeatability", "--seed", "-3"], "--seed"),
    (["evaluate", "aido_lf", "--workers", "0"], "--workers"),
    (["predictivity", "--workers", "0"], "--workers"),
    (["optimize", "--workers", "-2"], "--workers"),
    (["plv", "--eta-on", "0"], "--eta-on"),
    (["plv", "--eta-off", "-1"], "--eta-off"),
    (["learn", "dataset", "reality", "--out", "d", "--noise", "-0.1"], "--noise"),
    (["learn", "dataset", "reality", "--out", "d", "--width", "0"], "--width"),
    (["learn", "train", "d", "--out", "m.pt", "--epochs", "0"], "--epochs"),
    (["learn", "train", "d", "--out", "m.pt", "--lr", "nan"], "--lr"),
    (["learn", "train", "d", "--out", "m.pt", "--max-steps", "0"], "--max-steps"),
    (["learn", "evaluate", "m.pt", "--seconds", "-1"], "--seconds"),
    (["robot", "serve", "--seed", "-1"], "--seed"),
    (["serve", "--port", "70000"], "--port"),
    (["serve", "--lease-seconds", "0"], "--lease-seconds"),
    (["serve", "--evaluators", "-1"], "--evaluators"),
    (["submit", "pid", "--timeout", "-1"], "--timeout"),
    (["server", "user-add", "ann", "--daily-limit", "-1"], "--daily-limit"),
    (["evaluator", "--poll", "nan"], "--poll"),
]


@pytest.mark.parametrize("args, option", BAD_OPTIONS, ids=[" ".join(a) for a, _ in BAD_OPTIONS])
def test_bad_numbers_are_usage_errors_naming_the_option(args, option, tmp_path):
    res = runner.invoke(app, args, env={"COLUMNS": "200"})
    out = flat(res.output)
    assert res.exit_code == 2, out
    assert f"Invalid value for '{option}'" in out, out
    assert res.exception is None or isinstance(res.exception, SystemExit)


def test_run_with_negative_seconds_records_nothing(tmp_path):
    res = runner.invoke(app, ["run", "--seconds", "-5", "--out", str(tmp_path / "run")])
    assert res.exit_code == 2 and not (tmp_path / "run").exists()


def test_run_into_a_file_and_on_a_map_without_roads_are_clear_errors(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    res = runner.invoke(app, ["run", "--seconds", "1", "--out", str(blocker / "run")])
    assert res.exit_code == 1 and f"--out: cannot create the folder {blocker / 'run'}" in flat(res.output)
    field = tmp_path / "field.yaml"
    field.write_text("tiles:\n- [asphalt, grass]\ntile_size: 0.585\n")
    res = runner.invoke(app, ["run", "--map", str(field), "--out", str(tmp_path / "r")])
    assert res.exit_code == 1 and "has no drivable tile" in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)


def test_map_show_makes_missing_folders_and_names_the_option_when_it_cannot_write(tmp_path):
    png = tmp_path / "missing" / "dir" / "x.png"
    res = runner.invoke(app, ["map", "show", "loop_3x3", "-o", str(png)])
    assert res.exit_code == 0, res.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    blocker = tmp_path / "file"
    blocker.write_text("x")
    res = runner.invoke(app, ["map", "show", "loop_3x3", "-o", str(blocker / "x.png")])
    assert res.exit_code == 1 and f"--output: cannot write {blocker / 'x.png'}" in flat(res.output)
    assert not isinstance(res.exception, OSError)


# ---------------------------------------------------------------------------------------------------
# User text is printed as it is: no emoji codes, no markup


def test_file_line_column_prints_as_written_not_as_an_emoji(tmp_path):
    bad = tmp_path / "zigzag_dists.yaml"
    bad.write_text("tiles:\n- [straight/E]\ntile_size: 0.585\n" + "#\n" * 96 + "objects: [{kind: duckie}]\n")
    res = runner.invoke(app, ["map", "check", str(bad)])
    assert res.exit_code == 1
    assert f"{bad}:100:11: objects[0]: no position" in res.output and "💯" not in res.output


def test_markup_in_names_is_printed_not_interpreted(tmp_path):
    odd = tmp_path / "a [red]x.yaml"
    odd.write_text("tiles:\n- [straight/E]\ntile_size: 0.585\nobjects: [{kind: '[bold]ufo', pos: [0.5, 0.5]}]\n")
    res = runner.invoke(app, ["map", "check", str(odd), "[/nothing].yaml"])
    assert res.exit_code == 1, res.output  # the second file does not exist
    assert f"✓ {odd}:" in res.output and "unknown object kind '[bold]ufo'" in res.output
    assert "[/nothing].yaml" in res.output


def test_errors_keep_their_brackets(tmp_path):
    """``[x, y]`` in a message is text, not a rich style that swallows it."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("tiles:\n- [straight/E]\ntile_size: 0.585\nobjects: [{kind: duckie, pos: [1]}]\n")
    for args in (["run", "--map", str(bad), "--out", str(tmp_path / "r")], ["map", "show", str(bad)]):
        res = runner.invoke(app, args)
        assert res.exit_code == 1 and "'pos' must be [x, y] in tiles (y down the listing), got [1]" in flat(res.output)


def test_map_check_prints_warnings_and_passes(tmp_path):
    f = tmp_path / "m.yaml"
    f.write_text("tiles:\n- [straight/E, straight/E]\ntile_size: 0.585\nstart_tile: [7, 0]\n")
    res = runner.invoke(app, ["map", "check", str(f)])
    assert res.exit_code == 0
    assert f"warning: {f}:4:13: 'start_tile' [7, 0] is outside the map" in flat(res.output)


# ---------------------------------------------------------------------------------------------------
# Progress when the output is not a terminal


def test_run_prints_plain_progress_lines_when_not_a_terminal(tmp_path):
    res = runner.invoke(app, ["run", "--seconds", "2", "--width", "32", "--height", "24", "--no-video",
                              "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("driving loop_3x3, 2 s")]
    assert lines[0] == "driving loop_3x3, 2 s 0/30 frames -:--:-- (0%)"
    assert lines[-1].startswith("driving loop_3x3, 2 s 30/30 frames") and lines[-1].endswith("(100%)")
    assert 3 <= len(lines) <= 12  # a line per tenth, not per frame


def _plain() -> tuple[PlainProgress, io.StringIO]:
    buf = io.StringIO()
    bar = progress_bar(TextColumn("work"), BarColumn(), MofNCompleteColumn(), console=Console(file=buf, width=200))
    assert isinstance(bar, PlainProgress)
    return bar, buf


def test_plain_progress_prints_at_start_each_tenth_and_the_end(monkeypatch):
    monkeypatch.setenv("PROXYBENCH_PROGRESS_SECONDS", "1000")
    bar, buf = _plain()
    with bar:
        task = bar.add_task("", total=1000)
        for _ in range(1000):
            bar.advance(task)
    lines = buf.getvalue().splitlines()
    assert lines[0] == "work 0/1000 (0%)" and lines[-1] == "work 1000/1000 (100%)"
    assert len(lines) == 11


def test_plain_progress_prints_every_interval_while_it_moves_and_unknown_totals(monkeypatch):
    monkeypatch.setenv("PROXYBENCH_PROGRESS_SECONDS", "0")
    bar, buf = _plain()
    task = bar.add_task("", total=None)
    bar.update(task, completed=3)
    bar.update(task, completed=3)  # no move, no line
    bar.update(task, completed=7, total=10)
    assert buf.getvalue().splitlines() == ["work 0/?", "work 3/?", "work 7/10 (70%)"]


def test_plain_status_prints_the_first_and_changed_states_and_where_it_ended(monkeypatch):
    monkeypatch.setenv("PROXYBENCH_PROGRESS_SECONDS", "1000")
    buf = io.StringIO()
    with status("[bold]starting[/bold]", console=Console(file=buf)) as s:
        assert isinstance(s, PlainStatus)
        for k in range(5):
            s.update(f"run {k}")
    assert buf.getvalue().splitlines() == ["starting", "run 4"]


def test_a_stage_first_reported_done_has_no_time_left_until_it_moves_again(monkeypatch):
    """A study reports a stage first when its first unit is done (or resumes at a count): that count is the
    baseline, as it took an unknown time. A validate study's targets once read 0:00:01 left of some 4 hours."""
    monkeypatch.setenv("PROXYBENCH_PROGRESS_SECONDS", "0")
    clock = [100.0]
    buf = io.StringIO()
    bar = progress_bar(TextColumn("{task.description}"), MofNCompleteColumn(), TimeRemainingColumn(),
                       console=Console(file=buf, width=200), get_time=lambda: clock[0])
    progress = stage_progress(bar)
    progress("targets", 1, 10)
    clock[0] += 600.0  # the second target took 10 min
    progress("targets", 2, 10)
    assert buf.getvalue().splitlines() == ["targets 1/10 -:--:-- (10%)", "targets 2/10 1:20:00 (20%)"]


def test_a_terminal_gets_rich_bars():
    term = Console(file=io.StringIO(), force_terminal=True)
    assert not isinstance(progress_bar(TextColumn("x"), console=term), PlainProgress)
