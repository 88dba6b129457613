"""`proxybench robot serve`: the simulator as a robot node (`proxybench run --robot-cmd` drives one)."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

import typer
from rich.markup import escape

from proxybench.cli.app import err_console, robot_app

if TYPE_CHECKING:

    from proxybench.domain.params import DomainParams


def parse_params(items: list[str]) -> DomainParams:
    """``k=v`` items (values read as YAML: numbers, booleans, lists) → DomainParams; a bad key or value is
    a usage error naming it."""
    import yaml
    from pydantic import ValidationError

    from proxybench.domain.params import DomainParams
    from proxybench.untrusted import UntrustedInputError, load_yaml

    values = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise typer.BadParameter(f"{item!r} is not k=v", param_hint="--param")
        try:
            values[key.strip()] = load_yaml(raw, max_depth=8)
        except (yaml.YAMLError, UntrustedInputError) as exc:
            raise typer.BadParameter(f"{item!r}: the value is not YAML ({exc})", param_hint="--param") from None
    try:
        return DomainParams.model_validate(values)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
        raise typer.BadParameter(problems, param_hint="--param") from exc


@robot_app.command("serve")
def robot_serve(
    map_name: str | None = typer.Option("loop_3x3", "--map", help="map to prepare (built-in name or YAML file); "
                                        "set_map may choose another"),
    param: list[str] = typer.Option([], "--param", help="domain parameter k=v (repeatable), e.g. image_width=160"),
    seed: int = typer.Option(0, min=0, help="episode seed when neither `seed` nor episode_start gives one"),
    name: str = typer.Option("robot", help="node name in timing information"),
) -> None:
    """Serve the proxybench simulator as a robot node on stdin/stdout (or $AIDONODE_DATA_IN/_OUT).

    This is a SIMULATED robot: one proxybench Simulator behind AIDO's simulator protocol
    (docs/robot-protocol.md), the reference for a physical robot's bridge. Messages go to stderr only.
    """
    from proxybench.domain.maps import MapError
    from proxybench.protocol.robot_node import RobotNode, serve_robot

    params = parse_params(param)
    try:
        node = RobotNode(params, map_name, seed=seed, node_name=name)
    except (MapError, ValueError) as exc:
        err_console.print(f"[red]error:[/red] {escape(str(exc))}", highlight=False)
        raise typer.Exit(1) from exc
    print(f"[{name}] serving a SIMULATED robot (proxybench simulator, {params.image_width}x{params.image_height} "
          f"at {params.frame_rate:g} Hz) on the robot protocol", file=sys.stderr, flush=True)
    raise typer.Exit(serve_robot(node, exit_on_abort=False))
