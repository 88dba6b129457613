"""The options that say how to start an agent node, shared by `run`, `evaluate` and `agent check`.

Typer declares options per command, so each command lists the same five parameters (names from
:data:`OPTION_NAMES`) and hands them to :func:`node_options`, which validates them with
:class:`~proxybench.protocol.options.NodeOptions` and names the option at fault.
"""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape

from proxybench.cli.app import err_console

__all__ = ["OPTION_NAMES", "node_options", "remote_agent"]

#: NodeOptions field → command-line option
OPTION_NAMES = {"cwd": "--agent-cwd", "transport": "--transport", "start_timeout": "--start-timeout",
                "step_timeout": "--step-timeout", "reflection": "--no-reflection"}

AGENT_CWD_HELP = "working directory of the agent command"
TRANSPORT_HELP = "pipe (stdin/stdout) or fifo (AIDO's default: the node's own prints cannot break the protocol)"
START_TIMEOUT_HELP = "seconds for the agent node to start and answer the handshake, and per setup message"
STEP_TIMEOUT_HELP = "seconds for each observations + get_commands exchange"
NO_REFLECTION_HELP = ("do not ask the node for its protocol description (describe_protocol); a node that fails it "
                      "is restarted without it anyway")


def node_options(cwd: Path | None, transport: str, start_timeout: float, step_timeout: float, no_reflection: bool):
    """A validated NodeOptions from the command line; a bad value is a usage error naming its option."""
    from pydantic import ValidationError

    from proxybench.protocol.options import NodeOptions

    if cwd is not None and not cwd.is_dir():
        raise typer.BadParameter(f"{str(cwd)!r} is not a directory", param_hint="--agent-cwd")
    try:
        return NodeOptions(cwd=None if cwd is None else str(cwd), transport=transport, start_timeout=start_timeout,
                           step_timeout=step_timeout, reflection=not no_reflection)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = str(err["loc"][0]) if err["loc"] else "cwd"
        raise typer.BadParameter(f"{err.get('input')!r}: {err['msg']}",
                                 param_hint=OPTION_NAMES.get(field, field)) from None


def remote_agent(cmd: str, options):
    """An agent node started with ``cmd``; a node that fails to start is a clear error, not a traceback."""
    from proxybench.protocol import AgentFailure, RemoteAgent

    try:
        agent = RemoteAgent(cmd, **options.process_kwargs())
    except AgentFailure as exc:
        err_console.print(f"[red]error:[/red] agent node {escape(repr(cmd))} failed to start: "
                          f"{exc.reason}: {escape(exc.detail)}", highlight=False)
        if exc.exit_code is not None:
            err_console.print(f"    exit code {exc.exit_code}", highlight=False)
        for line in exc.stderr_tail[-10:]:
            err_console.print(f"    {line}", highlight=False, markup=False)
        raise typer.Exit(1) from exc
    return agent  # a describe_protocol fallback is logged as a warning (proxybench.protocol)
