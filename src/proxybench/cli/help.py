"""``--help`` that fits: option names and defaults are never cut, descriptions wrap as paragraphs, at any width.

Typer's rich help puts each option's long name, short name, ``--no-`` name, type and help in columns of one table
and lets rich shrink the name column with an ellipsis when the row is too wide (``--robot-start-time…`` at 80
columns, the width of a file or a pipe), and it keeps a docstring's hard line breaks, so prose re-wraps raggedly.
Here every panel is laid out by hand: the names (and the value they take) in a column as wide as the longest
name that still leaves the description room; a name wider than that gets a line of its own with its description
below. Descriptions and prose are wrapped as whole paragraphs (a docstring's single line breaks are spaces; a
blank line, a ``- `` item or a click ``\\b`` block starts a new one). Help texts are rich markup, as with typer's
``rich`` mode (study options escape theirs).

Every Typer app of the command line is a :class:`HelpTyper`, whose groups and commands use this layout.
"""

from __future__ import annotations

import inspect
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import typer
from typer.core import TyperCommand, TyperGroup

if TYPE_CHECKING:  # typer 0.29 carries its own click (typer._click): its commands are no Command
    from rich.console import Console, RenderableType
    from rich.text import Text
    from typer._click.core import Command, Context, Parameter

__all__ = ["HelpCommand", "HelpGroup", "HelpTyper", "Row", "help_rows", "paragraphs", "render_help"]

#: the narrowest the help is laid out for (a narrower terminal wraps the lines itself)
MIN_WIDTH = 40
#: the name column takes at most this share of a panel; wider names go on a line of their own
NAME_SHARE = 0.45
#: a description narrower than this reads badly: every row then puts its names on a line of their own
MIN_HELP = 24

_ITEM = re.compile(r"^\s*(?:[-*•]|\d+[.)])\s")


def paragraphs(text: str) -> list[str]:
    """A docstring's paragraphs, each on one line: hard line breaks inside a paragraph are spaces, a blank line,
    a list item (``- ``, ``* ``, ``1. ``) or a click ``\\b`` block (kept verbatim) starts a new one; ``\\f`` ends
    the help."""
    text = inspect.cleandoc(text or "").partition("\f")[0]
    out: list[str] = []
    for block in re.split(r"\n[ \t]*\n", text):
        if block.startswith("\b"):
            out.append(block.lstrip("\b\n"))
            continue
        current: list[str] = []
        for line in block.splitlines():
            if _ITEM.match(line) and current:
                out.append(" ".join(current))
                current = []
            current.append(line.strip())
        if current:
            out.append(" ".join(current))
        out.append("")  # a blank line between blocks
    while out and not out[-1]:
        out.pop()
    return out


def _markup(text: str, style: str = "") -> Text:
    """Help text as rich markup (typer's ``rich`` mode); text that is not valid markup shows as it is."""
    from rich.errors import MarkupError
    from rich.text import Text

    try:
        return Text.from_markup(text, style=style, emoji=False)
    except MarkupError:
        return Text(text, style=style)


@dataclass(frozen=True)
class Row:
    """One parameter as the help shows it."""

    panel: str
    names: tuple[str, ...]  # every spelling: --flag, -f, --no-flag (an argument: its name)
    value: str  # what an option takes (metavar or type); "" for a flag or an argument
    help: str  # the parameter's own help (rich markup)
    extra: str  # click's extras: [default: …; x>=1; required]
    argument: bool


def help_rows(cmd: Command, ctx: Context) -> list[Row]:
    """Each shown parameter of ``cmd``, arguments first, then the "Options" panel, then the others in order."""
    from typer.core import TyperArgument

    rows: list[Row] = []
    for param in cmd.get_params(ctx):
        if getattr(param, "hidden", False):
            continue
        record = param.get_help_record(ctx)
        if record is None:
            continue
        argument = isinstance(param, TyperArgument)
        own = getattr(param, "help", None) or ""
        extra = record[1][len(own):].strip() if record[1].startswith(own) else ""
        panel = getattr(param, "rich_help_panel", None) or ("Arguments" if argument else "Options")
        if argument:  # FILES... (typer writes "files... <list[Path]>", and {files}... in the usage)
            shown = (getattr(param, "metavar", None) or param.name or "").upper()
            names, value = (shown + ("..." if param.nargs != 1 else ""),), ""
        else:
            names = (*param.opts, *param.secondary_opts)
            flag = getattr(param, "is_flag", False) or getattr(param, "count", False)
            value = "" if flag else _value_name(param, ctx)
        rows.append(Row(panel, names, value, own, extra, argument))
    return sorted(rows, key=lambda r: (not r.argument, r.panel not in ("Arguments", "Options")))


#: typer's type names (``<int range>``) in one word each, as click wrote them
_TYPE_WORDS = {"int": "INT", "int range": "INT", "float": "FLOAT", "float range": "FLOAT", "str": "TEXT",
               "list[str]": "TEXT", "path": "PATH", "bool": "BOOL"}


def _value_name(param: Parameter, ctx: Context) -> str:
    """What an option takes: its metavar (choices ``a|b``), else its type in one word (``INT``, ``PATH``)."""
    shown = str(param.display_type_rich(ctx=ctx) or "")  # type: ignore[attr-defined]
    if param.metavar or not (shown.startswith("<") and shown.endswith(">")):
        return shown
    return _TYPE_WORDS.get(shown[1:-1], shown[1:-1].upper())


def _names_text(row: Row, negative: tuple[str, ...]) -> Text:
    from rich.text import Text

    text = Text()
    if row.argument:
        text.append(row.names[0], style="bold cyan")
        return text
    positive = [n for n in row.names if n not in negative]
    value = row.value
    for i, name in enumerate(positive):
        text.append(", " if i else "", style="")
        text.append(name, style="bold cyan" if name.startswith("--") else "bold green")
    if value:
        text.append(" ")
        text.append(value, style="bold yellow")
    for name in negative:
        text.append(" / ")
        text.append(name, style="bold magenta")
    return text


def _help_text(row: Row) -> Text:
    """The parameter's help (markup) and click's extras (plain, dim: ``[default: …; x>=1]``)."""
    text = _markup(" ".join(p for p in paragraphs(row.help) if p))
    if row.extra:
        text.append(("  " if text.plain else "") + row.extra, style="dim")
    return text


def _columns(console: Console, rows: list[tuple[Text, Text]], inner: int) -> Text:
    """Rows of (names, description) laid out in ``inner`` columns; names are never cut."""
    from rich.text import Text

    widest = max((r[0].cell_len for r in rows), default=0)
    col = min(widest, max(16, int(inner * NAME_SHARE)))
    stacked = inner - col - 2 < MIN_HELP
    help_w = inner - 4 if stacked else inner - col - 2
    indent = 4 if stacked else col + 2
    lines: list[Text] = []
    for names, desc in rows:
        name_lines = list(names.wrap(console, inner, overflow="fold"))
        desc_lines = list(desc.wrap(console, max(help_w, 8), overflow="fold")) if desc.plain else []
        if not stacked and len(name_lines) == 1 and names.cell_len <= col:
            first = names.copy()
            first.pad_right(col + 2 - names.cell_len)
            if desc_lines:
                first.append_text(desc_lines.pop(0))
            name_lines = [first]
        lines += name_lines
        lines += [Text(" " * indent) + d for d in desc_lines]
    out = Text("\n").join(lines)
    out.no_wrap = True
    out.overflow = "ignore"
    return out


def _panel(console: Console, title: str, rows: list[tuple[Text, Text]]) -> RenderableType:
    """A titled box of rows; a title too wide for its rule is shortened to its head (before ``:``), the rest the
    box's first line."""
    from rich.panel import Panel
    from rich.text import Text

    inner = console.width - 4
    head, lead = title, ""
    if len(title) > inner - 4:
        head, _, lead = title.partition(": ")
        if len(head) > inner - 4:
            head, lead = "", title
    body = _columns(console, rows, inner)
    if lead:
        wrapped = Text("\n").join(list(Text(lead, style="dim").wrap(console, inner, overflow="fold")))
        body = Text("\n").join([wrapped, body])
        body.no_wrap, body.overflow = True, "ignore"
    return Panel(body, title=head or None, title_align="left", border_style="dim", width=console.width)


def _prose(console: Console, text: str, first_style: str = "bold") -> list[Text]:
    """A help text as lines: paragraphs wrapped one column in from the edge (no trailing spaces, for files and
    pipes), a list item's marker in front of its first line and the rest under its text (a hanging indent)."""
    from rich.text import Text

    out: list[Text] = []
    for i, para in enumerate(paragraphs(text)):
        if not para:
            out.append(Text())
            continue
        match = _ITEM.match(para)
        if "\n" in para:  # a click \b block: its lines as they are
            out += [Text(" " + line) for line in para.splitlines()]
            continue
        marker = para[: match.end()] if match else ""
        body = _markup(para[len(marker):], first_style if i == 0 else "")
        lines = body.wrap(console, max(console.width - 2 - len(marker), 8), overflow="fold")
        for j, line in enumerate(lines):
            line.rstrip()
            out.append(Text(" " + (marker if j == 0 else " " * len(marker))) + line)
    return out


def _first_sentence(text: str) -> str:
    """A command's line in its group's list: the first sentence of its first paragraph."""
    first = next((p for p in paragraphs(text) if p), "")
    match = re.search(r"(?<=[.!?])\s+(?=[A-Z`(])", first)
    return first[: match.start()] if match else first


def _console() -> Console:
    """A console for help on stdout: the terminal's width (``COLUMNS`` where set; 80 off a terminal), no emoji
    codes and no highlighting of numbers (the styles are the layout's own)."""
    from rich.console import Console

    console = Console(emoji=False, highlight=False)
    if console.width < MIN_WIDTH:
        console.width = MIN_WIDTH
    return console


def render_help(cmd: Command, ctx: Context, console: Console | None = None) -> None:
    """Print ``cmd``'s help: usage, its prose, a box per panel of options (arguments first), a group's commands."""
    from rich.text import Text

    console = console or _console()
    usage = Text("Usage: ", style="yellow")
    pieces = [re.sub(r"\{(\w+)\}", lambda m: m[1].upper(), p) for p in cmd.collect_usage_pieces(ctx)]
    usage.append(" ".join([ctx.command_path, *pieces]), style="bold")
    console.print()
    for line in usage.wrap(console, console.width - 2, overflow="fold"):
        line.rstrip()
        console.print(Text(" ") + line, overflow="ignore", crop=False)
    console.print()
    if cmd.help:
        for line in _prose(console, cmd.help):
            console.print(line, overflow="ignore", crop=False)
        console.print()
    panels: dict[str, list[tuple[Text, Text]]] = {}
    secondary = {n for p in cmd.get_params(ctx) for n in getattr(p, "secondary_opts", ())}
    for row in help_rows(cmd, ctx):
        negative = tuple(n for n in row.names if n in secondary)
        panels.setdefault(row.panel, []).append((_names_text(row, negative), _help_text(row)))
    for title, rows in panels.items():
        console.print(_panel(console, title, rows))
    if isinstance(cmd, TyperGroup):
        groups: dict[str, list[tuple[Text, Text]]] = {}
        for name in cmd.list_commands(ctx):
            sub = cmd.get_command(ctx, name)
            if sub is None or sub.hidden:
                continue
            first = sub.short_help or _first_sentence(sub.help or "")
            panel = getattr(sub, "rich_help_panel", None) or "Commands"
            groups.setdefault(panel, []).append((Text(name, style="bold cyan"), _markup(first)))
        for title, rows in groups.items():
            console.print(_panel(console, title, rows))
    if cmd.epilog:
        console.print()
        for line in _prose(console, cmd.epilog, first_style=""):
            console.print(line, overflow="ignore", crop=False)


class HelpCommand(TyperCommand):
    """A Typer command whose ``--help`` is :func:`render_help`'s."""

    def format_help(self, ctx: Context, formatter: Any) -> None:
        render_help(self, ctx)


class HelpGroup(TyperGroup):
    """A Typer group whose ``--help`` is :func:`render_help`'s."""

    def format_help(self, ctx: Context, formatter: Any) -> None:
        render_help(self, ctx)


class HelpTyper(typer.Typer):
    """``typer.Typer`` whose groups and commands lay their help out with :func:`render_help` (names never cut)."""

    def __init__(self, **kwargs: Any) -> None:
        kwargs.setdefault("cls", HelpGroup)
        super().__init__(**kwargs)

    def command(self, name: str | None = None, *, cls: type[TyperCommand] | None = None, **kwargs: Any) -> Any:
        return super().command(name, cls=cls or HelpCommand, **kwargs)
