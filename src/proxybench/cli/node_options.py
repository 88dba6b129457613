"""The options that say how to start an agent node (`run`, `evaluate`, `agent check`) or a robot node (`run
--robot-cmd`, `predictivity` / `optimize` with `--target robot:CMD`, `target record --robot-cmd`).

Typer declares options per command, so each command lists the same five parameters (names from
:data:`OPTION_NAMES`) and hands them to :func:`node_options`, which validates them with
:class:`~proxybench.protocol.options.NodeOptions` and names the option at fault. The robot node's five
are typed once here (``RobotCwd``, …: ``--robot-cwd``, ``--robot-transport``, ``--robot-start-timeout``,
``--robot-step-timeout``, ``--robot-no-reflection``) and checked by :func:`robot_option_values`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from proxybench.cli.app import err_console

__all__ = ["OPTION_NAMES", "ROBOT_OPTION_NAMES", "RobotCwd", "RobotNoReflection", "RobotStartTimeout",
           "RobotStepTimeout", "RobotTransport", "node_options", "remote_agent", "robot_node_options",
           "robot_option_values"]

#: NodeOptions field → command-line option
OPTION_NAMES = {"cwd": "--agent-cwd", "transport": "--transport", "start_timeout": "--start-timeout",
                "step_timeout": "--step-timeout", "reflection": "--no-reflection"}

AGENT_CWD_HELP = "working directory of the agent command"
TRANSPORT_HELP = "pipe (stdin/stdout) or fifo (AIDO's default: the node's own prints cannot break the protocol)"
START_TIMEOUT_HELP = "seconds for the agent node to start and answer the handshake, and per setup message"
STEP_TIMEOUT_HELP = "seconds for each observations + get_commands exchange"
NO_REFLECTION_HELP = ("do not ask the node for its protocol description (describe_protocol); a node that fails it "
                      "is restarted without it anyway")


#: RobotNodeOptions field → command-line option
ROBOT_OPTION_NAMES = {"cwd": "--robot-cwd", "transport": "--robot-transport", "start_timeout": "--robot-start-timeout",
                      "step_timeout": "--robot-step-timeout", "reflection": "--robot-no-reflection",
                      "fifo_dir": "--robot-fifo-dir"}
RobotCwd = Annotated[Path | None, typer.Option("--robot-cwd", help="working directory of the robot node's command")]
RobotTransport = Annotated[str | None, typer.Option(
    "--robot-transport", help="pipe (default) or fifo (AIDO's: what the node prints cannot break the protocol)")]
RobotStartTimeout = Annotated[float | None, typer.Option(
    "--robot-start-timeout", help="seconds for the robot node to start and answer, and per episode setup (default: "
                                  "120)")]
RobotStepTimeout = Annotated[float | None, typer.Option(
    "--robot-step-timeout", help="seconds for each per-frame exchange with the robot node (default: 10)")]
RobotNoReflection = Annotated[bool, typer.Option(
    "--robot-no-reflection", help="do not ask the robot node for its protocol description (describe_protocol)")]


def robot_option_values(cwd: Path | None, transport: str | None, start_timeout: float | None,
                        step_timeout: float | None, no_reflection: bool) -> dict[str, Any]:
    """The robot node options given on the command line (unset ones left out, so an experiment file's stay),
    checked by :class:`~proxybench.protocol.options.RobotNodeOptions`; a bad one is a usage error naming its
    option. A working directory is made absolute (it is relative to where the command runs)."""
    from pydantic import ValidationError

    from proxybench.protocol.options import RobotNodeOptions

    given: dict[str, Any] = {k: v for k, v in (("transport", transport), ("start_timeout", start_timeout),
                                               ("step_timeout", step_timeout)) if v is not None}
    if no_reflection:
        given["reflection"] = False
    if cwd is not None:
        if not cwd.is_dir():
            raise typer.BadParameter(f"{str(cwd)!r} is not a directory", param_hint="--robot-cwd")
        given["cwd"] = str(cwd.resolve())
    try:
        RobotNodeOptions(**given)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = str(err["loc"][0]) if err["loc"] else "cwd"
        raise typer.BadParameter(f"{err.get('input')!r}: {err['msg']}",
                                 param_hint=ROBOT_OPTION_NAMES.get(field, field)) from None
    return given


def robot_node_options(cwd: Path | None, transport: str | None, start_timeout: float | None,
                       step_timeout: float | None, no_reflection: bool, *, command: str | None,
                       command_option: str = "--robot-cmd"):
    """A validated ``RobotNodeOptions`` from the command line; options without a robot command are an error."""
    from proxybench.protocol.options import RobotNodeOptions

    given = robot_option_values(cwd, transport, start_timeout, step_timeout, no_reflection)
    if given and command is None:
        names = ", ".join(ROBOT_OPTION_NAMES[k] for k in given)
        raise typer.BadParameter(f"only with {command_option} (these options say how to start its robot node)",
                                 param_hint=names)
    return RobotNodeOptions(**given)


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
