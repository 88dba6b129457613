"""`proxybench agent ...`: the built-in agent zoo."""

from __future__ import annotations

import typer
from rich.markup import escape

from proxybench.cli.app import agent_app, console, err_console


@agent_app.command("list")
def agent_list() -> None:
    """The zoo: name, whether it reads privileged ground truth, what it does."""
    from rich.table import Table

    from proxybench.agents import ZOO

    table = Table(title=f"{len(ZOO)} built-in agents")
    for col in ("name", "needs", "description"):
        table.add_column(col)
    for e in ZOO.values():
        table.add_row(e.name, "true lane pose" if e.privileged else "camera only", e.description)
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
        err_console.print(f"[red]error:[/red] cannot load agent {name!r}: {escape(str(exc))}", highlight=False)
        raise typer.Exit(2) from exc
    raise typer.Exit(serve(agent, node_name=node_name))
