"""`proxybench agent ...`: the built-in agent zoo, serving an agent as a node, checking an agent node."""

from __future__ import annotations

from typing import TYPE_CHECKING

import typer
from rich.markup import escape

from proxybench.cli.app import agent_app, console, fail
from proxybench.cli.node_options import remote_agent, with_agent_node_options

if TYPE_CHECKING:
    from proxybench.protocol.options import NodeOptions


@agent_app.command("list")
def agent_list() -> None:
    """The zoo: name, family (agents of one concept), whether it reads privileged ground truth, what it does."""
    from rich.table import Table

    from proxybench.agents import ZOO
    from proxybench.agents.families import family_of

    table = Table(title=f"{len(ZOO)} built-in agents in {len({family_of(n) for n in ZOO})} families")
    for col in ("name", "family", "needs", "description"):
        table.add_column(col)
    for e in ZOO.values():
        table.add_row(e.name, family_of(e.name), "true lane pose" if e.privileged else "camera only", e.description)
    console.print(table)


@agent_app.command("serve")
def agent_serve(
    name: str = typer.Argument(..., help="zoo name, or package.module:Class"),
    node_name: str = typer.Option("agent", help="node name reported in timing information"),
) -> None:
    """Serve an agent as an AIDO node: CBOR on stdin/stdout (or AIDONODE_DATA_IN / AIDONODE_DATA_OUT).

    Any caller that speaks the AIDO agent protocol can then drive it, e.g.
    `proxybench run --agent-cmd "proxybench agent serve vision"`.
    """
    from proxybench.protocol.__main__ import load_agent
    from proxybench.protocol.node import serve

    try:
        agent = load_agent(name)
    except (KeyError, ImportError, AttributeError) as exc:
        raise fail(f"cannot load agent {name!r}: {exc}", 2) from exc
    raise typer.Exit(serve(agent, node_name=node_name))


def _image_node(text: str):
    """(sandboxed command, node options) of ``image:PATH``; a bad image is a one-line error."""
    from proxybench.experiments.agent_args import AgentArgError, parse_agent

    try:
        spec = parse_agent(f"image={text}")
    except AgentArgError as exc:
        raise fail(exc, 2) from exc
    return spec.command, spec.node_options()


@agent_app.command("check")
@with_agent_node_options()
def agent_check(
    command: str = typer.Argument(..., help="the agent node's command, as typed in a shell"),
    options: NodeOptions = None,  # the agent node options: with_agent_node_options
    seconds: float = typer.Option(2.0, min=0.1, help="length of the test episode [s] (simulated time)"),
    map_name: str = typer.Option("loop_3x3", "--map", help="map of the test episode"),
    contract: bool = typer.Option(True, "--contract/--no-contract",
                                  help="then run the agent contract (proxybench.testing.AgentContract)"),
) -> None:
    """Start an agent node as `run` and `evaluate` would and drive it through one short simulated episode.

    Reports how it started (protocol reflection, privileged or camera-only), each exchange's time and the
    commands it sent; a node that fails says why (reason, exit code, last stderr lines) and the command
    exits 1. Then the agent contract, one line per check (commands, determinism, privileged flag, isolation
    between episodes, clean failure; docs/protocol.md); a failed check exits 1 too.
    E.g. `proxybench agent check "cd sub && exec python3 solution.py" --transport fifo`; a container image as
    `proxybench agent check image:PATH` (its labels or side file give the start-up options).
    """
    import time

    import numpy as np

    from proxybench.domain.params import DomainParams
    from proxybench.protocol import AgentFailure
    from proxybench.runner.episode import play

    t0 = time.perf_counter()
    if command.startswith("image:"):  # a container image: its own start-up options, run in the sandbox
        command, options = _image_node(command)
    agent = remote_agent(command, options)
    started = time.perf_counter() - t0
    proc = agent.process
    how = ("described its protocol" if proc.description is not None else
           "no protocol description (--no-reflection)" if not options.reflection else
           proc.reflection_note or "no protocol reflection offered")
    console.print(f"[green]✓[/green] started and handshaken in {started:.2f} s over {options.transport} "
                  f"(pid {proc.pid}); {escape(how)}; "
                  f"{'privileged (reads the true lane pose)' if agent.privileged else 'camera only'}", highlight=False)
    times: list[float] = []
    commands: list[np.ndarray] = []
    inner = agent.act

    def timed(obs):
        t = time.perf_counter()
        out = inner(obs)
        times.append(time.perf_counter() - t)
        commands.append(np.asarray(out))
        return out

    agent.act = timed  # type: ignore[method-assign]
    try:
        traj = play(map_name, DomainParams(image_width=160, image_height=120), agent, 0, seconds)
    finally:
        code = agent.close()
    failure = traj.failure.message if traj.failure is not None else None
    if failure is not None or isinstance(proc.failure, AgentFailure):
        raise fail(f"the agent failed after {len(times)} frames: {failure}", mark="✗")
    ms = np.array(times) * 1000
    cmd = np.array(commands)
    console.print(f"[green]✓[/green] {len(times)} frames (160x120 JPEG, {seconds:g} s simulated): exchange median "
                  f"{np.median(ms):.1f} ms, max {ms.max():.1f} ms; wheel PWM left {cmd[:, 0].min():+.2f}..."
                  f"{cmd[:, 0].max():+.2f}, right {cmd[:, 1].min():+.2f}...{cmd[:, 1].max():+.2f}; episode end: "
                  f"{traj.termination}; node exit code {code}", highlight=False)
    if contract:
        from proxybench.cli.checks import print_report
        from proxybench.testing import AgentContract, StreamSpec

        stream = StreamSpec(map=map_name, params=DomainParams(image_width=160, image_height=120))
        if proc.reflection_note is not None:  # it failed describe_protocol: its next starts need not ask
            options = options.model_copy(update={"reflection": False})
        if not print_report(AgentContract.for_command(command, options, stream=stream).run()):
            raise typer.Exit(1)
