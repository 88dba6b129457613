"""``--help`` that fits (issue 39 item 6): at 60, 80 and 200 columns every command's help shows each of its option
names, values and defaults in full (typer's table cut them with an ellipsis: ``--robot-start-time…`` at 80
columns), its descriptions are whole paragraphs, and an option that does not apply to a command is not offered."""

from __future__ import annotations

import itertools
import re

import pytest
from rich.text import Text
from typer.main import get_command
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.cli.help import HelpCommand, HelpGroup, help_rows, paragraphs

runner = CliRunner()
WIDTHS = (60, 80, 200)
BOX = re.compile(r"[│╭╮╰╯─\s]")


def _commands():
    """(path, click command, context) of every command and group of the command line, the root included."""
    root = get_command(app)
    out = []

    def walk(cmd, path, parent):
        ctx = cmd.context_class(cmd, info_name=path[-1] if path else "proxybench", parent=parent)
        out.append((path, cmd, ctx))
        for name in getattr(cmd, "commands", {}):
            walk(cmd.commands[name], (*path, name), ctx)

    walk(root, (), None)
    return out


COMMANDS = _commands()


def _help(path: tuple[str, ...], width: int) -> str:
    res = runner.invoke(app, [*path, "--help"], env={"COLUMNS": str(width), "NO_COLOR": "1"})
    assert res.exit_code == 0, res.output
    return res.output


def _squash(text: str) -> str:
    """The text without box lines and white space: what wrapping may move but never cut."""
    return BOX.sub("", text)


@pytest.mark.parametrize("width", WIDTHS)
@pytest.mark.parametrize("path", [c[0] for c in COMMANDS], ids=lambda p: " ".join(p) or "proxybench")
def test_every_option_name_value_and_default_is_shown_in_full(path, width):
    """Each name (``--robot-start-timeout``, ``--robot-no-reflection``) as a whole word, and each option's help with
    click's extras (``[default: out/plan]``) whole once wrapping is undone; no line wider than the terminal."""
    _, cmd, ctx = next(c for c in COMMANDS if c[0] == path)
    out = _help(path, width)
    assert max(len(line) for line in out.splitlines()) <= width
    squashed = _squash(out)
    rows = help_rows(cmd, ctx)
    assert rows, "no parameters (--help at least)"
    for row in rows:
        for name in row.names:
            assert re.search(rf"(?<![\w-]){re.escape(name)}(?![\w-])", out), f"{name} missing or cut at {width}"
        if row.value:
            assert _squash(row.value) in squashed, f"{row.names[0]}'s value {row.value!r} cut at {width}"
        described = Text.from_markup(" ".join(p for p in paragraphs(row.help) if p)).plain + row.extra
        assert _squash(described) in squashed, f"{row.names[0]}'s description or default cut at {width}"
    for name in getattr(cmd, "commands", {}):
        assert re.search(rf"(?m)^│ {re.escape(name)}(?![\w-])", out), f"sub-command {name} missing at {width}"


def test_the_names_column_never_shrinks_a_name_with_an_ellipsis():
    """The cuts the issue saw (80 columns, ``plan --help``) are gone, and long names take a line of their own."""
    out = _help(("plan",), 80)
    assert "…" not in "".join(re.findall(r"--[\w-]+…", out))
    assert "--robot-start-timeout" in out and "--robot-reflection / --robot-no-reflection" in out
    assert "plan: plan:" not in out  # a section's title is not its name twice


def test_every_command_lays_its_help_out_here():
    """A Typer app made with ``typer.Typer`` instead of ``HelpTyper`` would bring typer's cutting table back."""
    plain = [" ".join(p) or "proxybench" for p, cmd, _ in COMMANDS if not isinstance(cmd, HelpCommand | HelpGroup)]
    assert not plain


def test_prose_is_reflowed_as_paragraphs_and_items():
    doc = """First line
    continues here.

    Second paragraph
    on two lines:
    - an item
      that wraps
    - another

    \b
    kept
      as is
    """
    assert paragraphs(doc) == ["First line continues here.", "", "Second paragraph on two lines:",
                               "- an item that wraps", "- another", "", "kept\n  as is"]


def test_study_docstrings_wrap_as_paragraphs_not_at_their_source_line_breaks():
    """A study's help kept its docstring's breaks (``...with  \\n finitely many episodes; the\\n pilot``): a short
    line in the middle of a paragraph."""
    out = _help(("plan",), 80)
    prose = out.split("╭")[0].splitlines()
    short = [line for line, nxt in itertools.pairwise(prose)
             if line.strip() and nxt.strip() and len(line) < 50]
    assert not short, short
    assert not [line for line in out.splitlines() if line != line.rstrip()]  # no trailing spaces in a file


def test_score_proxy_does_not_offer_what_it_does_not_use():
    """``score-proxy`` scores one θ: PLV settings and the known θ of plots belong to other studies."""
    out = _help(("score-proxy",), 200)
    assert not re.search(r"--plv\b", out) and not re.search(r"--truth\b", out)
    assert re.search(r"--vs-param\b", out)
