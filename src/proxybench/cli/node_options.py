"""The options that say how to start an agent node (`run`, `evaluate`, `agent check`) or a robot node (`run
--robot-cmd`, `predictivity` / `optimize` with `--target robot:CMD`, `target record --target robot:CMD`).

Typer declares options per command; rather than each command listing the same five, a command names one
parameter and a decorator puts the five in its place: :func:`with_agent_node_options` (``--agent-cwd``,
``--transport``, ``--start-timeout``, ``--step-timeout``, ``--no-reflection``: names in :data:`OPTION_NAMES`)
hands the command a :class:`~proxybench.protocol.options.NodeOptions` made by :func:`node_options`;
:func:`with_robot_node_options` (``--robot-cwd``, ``--robot-transport``, ``--robot-start-timeout``,
``--robot-step-timeout``, ``--robot-no-reflection``) a ``RobotNodeOptions`` made by :func:`robot_node_options`.
Both validate before the command runs and name the option at fault.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from proxybench.cli.app import err_console, problem

__all__ = ["OPTION_NAMES", "ROBOT_OPTION_NAMES", "RobotCwd", "RobotNoReflection", "RobotStartTimeout",
           "RobotStepTimeout", "RobotTransport", "node_options", "remote_agent", "robot_node_options",
           "robot_option_values", "with_agent_node_options", "with_robot_node_options"]

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


def _param(name: str, annotation: Any, default: Any) -> inspect.Parameter:
    return inspect.Parameter(name, inspect.Parameter.POSITIONAL_OR_KEYWORD, default=default, annotation=annotation)


_ROBOT_PARAMS = (_param("robot_cwd", RobotCwd, None), _param("robot_transport", RobotTransport, None),
                 _param("robot_start_timeout", RobotStartTimeout, None),
                 _param("robot_step_timeout", RobotStepTimeout, None),
                 _param("robot_no_reflection", RobotNoReflection, False))


#: the parameters the decorators below replace (left unresolved: their types are imported for annotations only)
_PLACEHOLDERS = ("options", "robot_options")


def _expand(fn: Callable[..., Any], name: str, params: tuple[inspect.Parameter, ...],
            build: Callable[[dict[str, Any], dict[str, Any]], Any]) -> Callable[..., Any]:
    """``fn`` as a command whose parameter ``name`` stands for ``params``, in its place (so ``--help`` keeps the
    order); ``build(values of params, the command's other values)`` makes what ``fn`` gets as ``name``."""
    own = [p.replace(annotation=eval(p.annotation, fn.__globals__))
           if isinstance(p.annotation, str) and p.name not in _PLACEHOLDERS else p
           for p in inspect.signature(fn).parameters.values() if p.name != name]  # typer needs types, not text
    at = list(inspect.signature(fn).parameters).index(name)
    signature = inspect.Signature([*own[:at], *params, *own[at:]])

    @functools.wraps(fn)
    def command(**kwargs: Any) -> Any:
        values = {p.name: kwargs.pop(p.name) for p in params}
        return fn(**kwargs, **{name: build(values, kwargs)})

    del command.__wrapped__  # typer reads the signature below, not the function's
    command.__signature__ = signature  # type: ignore[attr-defined]
    command.__annotations__ = {p.name: p.annotation for p in signature.parameters.values()}
    return command


def with_robot_node_options(command: str = "robot_cmd", command_option: str = "--robot-cmd"):
    """Decorate a command whose parameter ``robot_options`` takes the five ``--robot-*`` options in its place and
    is handed their ``RobotNodeOptions``; ``command``: the parameter with the robot node's command (the options
    are an error without it), ``command_option`` its option's name."""

    def build(v: dict[str, Any], others: dict[str, Any]) -> Any:
        return robot_node_options(v["robot_cwd"], v["robot_transport"], v["robot_start_timeout"],
                                  v["robot_step_timeout"], v["robot_no_reflection"], command=others[command],
                                  command_option=command_option)

    return lambda fn: _expand(fn, "robot_options", _ROBOT_PARAMS, build)


def with_agent_node_options(cwd_help: str = AGENT_CWD_HELP):
    """Decorate a command whose parameter ``options`` takes the five agent node options in its place
    (``--agent-cwd`` says ``cwd_help``) and is handed their ``NodeOptions``."""
    params = (_param("agent_cwd", Path | None, typer.Option(None, "--agent-cwd", help=cwd_help)),
              _param("transport", str, typer.Option("pipe", "--transport", help=TRANSPORT_HELP)),
              _param("start_timeout", float, typer.Option(30.0, "--start-timeout", help=START_TIMEOUT_HELP)),
              _param("step_timeout", float, typer.Option(5.0, "--step-timeout", help=STEP_TIMEOUT_HELP)),
              _param("no_reflection", bool, typer.Option(False, "--no-reflection", help=NO_REFLECTION_HELP)))

    def build(v: dict[str, Any], _others: dict[str, Any]) -> Any:
        return node_options(v["agent_cwd"], v["transport"], v["start_timeout"], v["step_timeout"],
                            v["no_reflection"])

    return lambda fn: _expand(fn, "options", params, build)


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
        problem(f"agent node {cmd!r} failed to start: {exc.reason}: {exc.detail}", mark="error:")
        if exc.exit_code is not None:
            err_console.print(f"    exit code {exc.exit_code}", highlight=False)
        for line in exc.stderr_tail[-10:]:
            err_console.print(f"    {line}", highlight=False, markup=False)
        raise typer.Exit(1) from exc
    return agent  # a describe_protocol fallback is logged as a warning (proxybench.protocol)
