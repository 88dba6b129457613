"""`proxybench agent ...`: the built-in agent zoo."""

from __future__ import annotations

from proxybench.cli.app import agent_app, console


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
