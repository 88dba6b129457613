"""`proxybench robot serve`: the simulator as a robot node (`proxybench run --robot-cmd` drives one); `proxybench
robot check`: the plant contract on a robot node (yours: a bridge)."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

import typer

from proxybench.cli.app import fail, robot_app
from proxybench.cli.node_options import with_robot_node_options

if TYPE_CHECKING:

    from proxybench.domain.params import DomainParams
    from proxybench.protocol.options import RobotNodeOptions


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
        from proxybench.untrusted import problems

        raise typer.BadParameter(problems(exc), param_hint="--param") from exc


@robot_app.command("serve")
def robot_serve(
    map_name: str | None = typer.Option("loop_3x3", "--map", help="map to prepare (built-in name or YAML file); "
                                        "set_map may choose another"),
    param: list[str] = typer.Option([], "--param", help="domain parameter k=v (repeatable), e.g. image_width=160"),
    seed: int = typer.Option(0, min=0, help="episode seed when neither `seed` nor episode_start gives one"),
    name: str = typer.Option("robot", help="node name in timing information"),
    watchtowers: str | None = typer.Option(None, "--watchtowers", help="also serve this watchtower layout (a file, "
                                           "or auto) of the robot's world as DTPS camera topics: a stand-in lab "
                                           "(docs/autolab.md, 'A real robot')"),
    watchtower_port: int | None = typer.Option(None, "--watchtower-port", min=1, max=65535, help="the "
                                               "watchtowers' TCP port on 127.0.0.1 (default: a free one, printed)"),
) -> None:
    """Serve the proxybench simulator as a robot node on stdin/stdout (or $AIDONODE_DATA_IN/_OUT).

    This is a SIMULATED robot: one proxybench Simulator behind AIDO's simulator protocol
    (docs/robot-protocol.md), the reference for a physical robot's bridge. Messages go to stderr only. With
    --watchtowers its world's watchtowers are served as a lab's DTPS cameras, each frame stamped with the wall time
    of the episode's first command plus the world's time (what a camera of a real-time world would stamp).
    """
    from proxybench.domain.maps import MapError
    from proxybench.protocol.robot_node import RobotNode, serve_robot
    from proxybench.runner.sim_robot import SimRobot

    if watchtower_port is not None and watchtowers is None:
        raise fail("--watchtower-port: give --watchtowers LAYOUT too")
    params = parse_params(param)
    towers = None
    try:
        try:
            if watchtowers is not None:
                towers = _node_towers(map_name, watchtowers, watchtower_port, name)
            robot = SimRobot(params, map_name, streams=None if towers is None else towers[0])
            node = RobotNode(robot, seed=seed, node_name=name)
        except (MapError, ValueError, RuntimeError) as exc:  # a layout's LayoutError, a server's ReaderError
            raise fail(exc) from exc
        print(f"[{name}] serving a SIMULATED robot (proxybench simulator, {params.image_width}x"
              f"{params.image_height} at {params.frame_rate:g} Hz) on the robot protocol", file=sys.stderr, flush=True)
        code = serve_robot(node, exit_on_abort=False)
        robot.close_streams()  # the last episode's recording ends with the node
    finally:
        if towers is not None:
            towers[1].server.close()
    raise typer.Exit(code)


def _node_towers(map_name: str | None, layout: str, port: int | None, name: str):
    """(stream spec, sink) of ``layout``'s watchtowers on the map served over DTPS for a robot node, their address
    printed on stderr (stdout is the protocol's)."""
    from proxybench.autolab.served import served_towers
    from proxybench.autolab.watchtowers import resolve_layout
    from proxybench.domain.maps import load_map

    spec, sink = served_towers(resolve_layout(layout, load_map(map_name or "loop_3x3")), port=port, node=True)
    print(f"[{name}] serving {len(spec.cameras)} SIMULATED watchtowers at "
          f"{sink.server.address(spec.cameras[0].name).rsplit('/', 1)[0]}/NAME", file=sys.stderr, flush=True)
    return spec, sink


@robot_app.command("check")
@with_robot_node_options(command="command")
def robot_check(
    command: str = typer.Argument(..., help="the robot node's command, as typed in a shell (e.g. your bridge)"),
    map_name: str = typer.Option("loop_3x3", "--map", help="map the test episodes are driven on (sent by set_map)"),
    frame_rate: float = typer.Option(15.0, "--frame-rate", min=0.1, help="frame rate the robot must keep [Hz] (the "
                                     "benchmark's)"),
    seconds: float = typer.Option(1.0, min=0.1, help="length of each test episode [s]"),
    position_tolerance: float = typer.Option(1e-3, min=0.0, help="start pose: how far off the requested position "
                                             "the robot may start [m] (a robot placed by hand needs more)"),
    heading_tolerance: float = typer.Option(1e-3, min=0.0, help="start pose: heading tolerance [rad]"),
    time_tolerance: float = typer.Option(1e-6, min=0.0, help="how far frame and sample times may be off [s]"),
    robot_options: RobotNodeOptions = None,  # the --robot-* options: with_robot_node_options
) -> None:
    """Run the plant contract on a robot node: what a lab's bridge must do for proxybench to drive it.

    Starts the node as `run --robot-cmd` would and checks, one line each: it starts (or fails with a named
    reason), starts episodes at the requested pose, steps, sends frames of one size at the frame rate, gives
    the same trajectory for the same seed, and fails cleanly when killed (docs/robot-protocol.md, "Checking a
    bridge"). Exits 1 if a check fails. E.g. `proxybench robot check "python3 my_bridge.py"`.
    """
    from proxybench.cli.checks import print_report
    from proxybench.domain.maps import MapError
    from proxybench.testing import PlantContract

    try:
        suite = PlantContract.for_robot_command(command, map_name, robot_options, frame_rate, seconds=seconds,
                                                position_tolerance=position_tolerance,
                                                heading_tolerance=heading_tolerance, time_tolerance=time_tolerance)
    except (MapError, FileNotFoundError) as exc:
        raise fail(exc, 2) from exc
    if not print_report(suite.run()):
        raise typer.Exit(1)
