"""The Typer application and its consoles, shared by every command module."""

from __future__ import annotations

import sys

import typer
from rich.console import Console

from proxybench.cli.help import HelpTyper

app = HelpTyper(add_completion=False, no_args_is_help=True,
                  help="proxybench: develop, benchmark and measure the usefulness of Duckietown simulators.")
map_app = HelpTyper(no_args_is_help=True, help="Check, list and draw Duckietown map files.")
app.add_typer(map_app, name="map")
agent_app = HelpTyper(no_args_is_help=True, help="The built-in agent zoo.")
app.add_typer(agent_app, name="agent")
robot_app = HelpTyper(no_args_is_help=True, help="Robots behind AIDO's simulator protocol (simulated or real).")
app.add_typer(robot_app, name="robot")
gym_app = HelpTyper(no_args_is_help=True, help="gym-duckietown (another simulator) as a robot node: setup, check, "
                      "serve.")
app.add_typer(gym_app, name="gym")
# wide enough for result tables when the output is a file or a pipe (rich assumes 80 columns there);
# no emoji codes: user text such as ``file.yaml:100:5`` must print as it is, not as ``file.yaml💯5``
console = Console(soft_wrap=True, width=None if sys.stdout.isatty() else 160, emoji=False)
err_console = Console(stderr=True, soft_wrap=True, width=None if sys.stderr.isatty() else 160, emoji=False)

def problem(text: object, *, mark: str = "✗", style: str = "red") -> None:
    """Print ``text`` to stderr, each line after a styled ``mark``. The text is shown as it is: nothing in it
    is read as rich markup (a user's ``[x]`` stays), and off a terminal the mark is plain (no styles, and
    no literal ``[red]…[/red]`` either: the mark is styled text, not markup)."""
    from rich.text import Text

    for line in str(text).splitlines() or [""]:
        err_console.print(Text.assemble((mark, style), " ", line), highlight=False)


def fail(text: object, code: int = 1, *, mark: str = "error:") -> typer.Exit:
    """The command line's one error exit: ``text`` (naming the value at fault) as :func:`problem` prints it,
    after ``mark``, then the exit to raise, with ``code``: ``raise fail(exc)``, ``raise fail(msg, 2, mark="✗")``."""
    problem(text, mark=mark)
    return typer.Exit(code)


#: what the optional ``server`` extra provides (the challenges server, its clients and evaluators)
SERVER_MODULES = ("fastapi", "uvicorn", "sqlalchemy", "alembic", "httpx", "jinja2", "multipart")


def require_extra(extra: str, modules: tuple[str, ...] = SERVER_MODULES) -> None:
    """Exit with an install hint, not a traceback, when an optional extra is missing."""
    from importlib.util import find_spec

    missing = [m for m in modules if find_spec(m) is None]
    if missing:
        raise fail(f"this command needs the '{extra}' extra (missing: {', '.join(missing)}): "
                   f"pip install -e '.[{extra}]'", 2, mark="✗")
