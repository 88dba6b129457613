"""`proxybench params`: every domain parameter θ with its unit, default, accepted range and meaning."""

from __future__ import annotations

import typer
from rich.markup import escape
from rich.table import Table

from proxybench.cli.app import app, console


def _number(v) -> str:
    return "" if v is None else f"{v:g}" if isinstance(v, float | int) and not isinstance(v, bool) else str(v)


@app.command("params")
def params(name: list[str] = typer.Argument(None, help="only these parameters (default: all)")) -> None:
    """List the simulator's domain parameters θ (what --param, --proxy-param, sweeps and searches take): name,
    unit, default, accepted range and meaning, sign conventions included (e.g. positive trim drifts left)."""
    from proxybench.domain.params import DomainParams, describe_params, unknown_parameter

    for n in name or []:
        if n not in DomainParams.model_fields:
            raise typer.BadParameter(unknown_parameter(n), param_hint="NAME")
    table = Table(title="domain parameters θ (proxybench.domain.params.DomainParams)")
    for col, just in (("name", "left"), ("unit", "left"), ("default", "right"), ("range", "right"),
                      ("meaning", "left")):
        table.add_column(col, justify=just, overflow="fold")
    for row in describe_params():
        if name and row["name"] not in name:
            continue
        lo, hi = _number(row["low"]), _number(row["high"])
        rng = f"{lo or '−∞'} … {hi or '∞'}" if lo or hi else ""
        table.add_row(row["name"], escape(row["unit"]), escape(_number(row["default"])), rng,
                      escape(row["description"]))
    console.print(table)
