"""`proxybench sandbox setup|check`: prepare and inspect the sandbox evaluators run agent packages in."""

from __future__ import annotations

import os
import shutil
import subprocess

import typer

from proxybench.cli.app import app, console, fail
from proxybench.cli.help import HelpTyper

sandbox_app = HelpTyper(no_args_is_help=True, help="The sandbox that evaluators run agent packages in.")
app.add_typer(sandbox_app, name="sandbox")

AgentUserOpt = typer.Option("proxybench-agent", help="the unprivileged user agent packages run as")


def _show(isolation) -> None:
    from rich.markup import escape
    from rich.table import Table

    table = Table(show_header=False, box=None, pad_edge=False)
    verdict = "[green]safe[/green]" if isolation.safe else \
        "[red]UNSAFE[/red]" if isolation.usable else "[red]agent packages refused[/red]"
    table.add_row("sandbox", f"{verdict} ({isolation.kind})")
    table.add_row("agents run as", escape(isolation.user))
    table.add_row("bubblewrap", escape(isolation.bwrap or "-"))
    table.add_row("runtime (read-only)", escape(", ".join(["/usr", *isolation.runtime])))
    if isolation.pythonpath:
        table.add_row("PYTHONPATH", escape(isolation.pythonpath))
    table.add_row("note", escape(isolation.note or isolation.problem))
    table.add_row("container images", escape(_images(isolation)))
    console.print(table)


def _images(isolation) -> str:
    """Whether ``--agent NAME=image:PATH`` can run here, and where images are unpacked."""
    from proxybench.evaluator.image_agent import images_problem, probe_image
    from proxybench.evaluator.images import default_cache

    problem = images_problem(isolation)
    if problem is not None:
        return f"refused: {problem}"
    how = "as the agent user" if isolation.safe else "UNSAFE, as this user"
    return (f"run in bubblewrap {how}, their own root file system read-only as / (cache: {default_cache()}); "
            f"{probe_image(isolation)}")


@sandbox_app.command("check")
def check(agent_user: str = AgentUserOpt) -> None:
    """Say how this host would run agent packages (starts Python in the sandbox once) and container images (starts a
    cached image once, if one is cached); exit 1 unless safe."""
    from proxybench.evaluator.sandbox import detect_isolation

    isolation = detect_isolation(agent_user)
    _show(isolation)
    if not isolation.safe:
        raise typer.Exit(1)


@sandbox_app.command("setup")
def setup(agent_user: str = AgentUserOpt) -> None:
    """As root: create the agent user if missing, then check the sandbox (bubblewrap must be installed)."""
    from proxybench.evaluator.sandbox import detect_isolation

    if os.geteuid() != 0:
        raise fail("run this as root: it creates a system user, and evaluators that run agent packages must run "
                   "as root too (they drop to that user for the agents only)", 2, mark="✗")
    if shutil.which("bwrap") is None:
        raise fail("bubblewrap is not installed: apt-get install bubblewrap (dnf install bubblewrap on Fedora)",
                   mark="✗")
    import pwd

    try:
        pwd.getpwnam(agent_user)
        exists = True
    except KeyError:
        exists = False
    if exists:
        console.print(f"user {agent_user!r} exists", highlight=False)
    else:
        cmd = ["useradd", "--system", "--user-group", "--no-create-home", "--home-dir", "/nonexistent",
               "--shell", "/usr/sbin/nologin", "--comment", "proxybench agent sandbox", agent_user]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            raise fail(f"{' '.join(cmd)} failed: {done.stderr.strip()}", mark="✗")
        console.print(f"created the system user {agent_user!r}", highlight=False)
    isolation = detect_isolation(agent_user)
    _show(isolation)
    if not isolation.safe:
        raise typer.Exit(1)
