"""`proxybench run`: drive one agent around a map in simulation and record it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.markup import escape
from rich.progress import BarColumn, TextColumn, TimeRemainingColumn

from proxybench.cli.app import app, console, err_console, fail
from proxybench.cli.node_options import remote_agent, with_agent_node_options, with_robot_node_options
from proxybench.cli.options import positive
from proxybench.cli.progress import progress_bar

if TYPE_CHECKING:
    from proxybench.protocol.options import NodeOptions, RobotNodeOptions

_RUN_METRICS = ("survival_time", "driven_lanedir_consec", "deviation_center_line", "in_drivable_lane", "lane_score")


@app.command()
@with_agent_node_options()
@with_robot_node_options()
def run(
    map_name: str = typer.Option("loop_3x3", "--map", help="built-in map name or YAML file"),
    seconds: float = typer.Option(60.0, callback=positive, help="episode length [s] (simulated time)"),
    seed: int = typer.Option(0, min=0, help="episode seed (start pose, noise)"),
    out: Path = typer.Option(Path("out/run"), help="folder for drive.mp4, drive_strip.png, metrics.json"),
    width: int = typer.Option(640, min=8, max=4096, help="camera width [px]"),
    height: int = typer.Option(480, min=8, max=4096, help="camera height [px]"),
    video: bool = typer.Option(True, help="write drive.mp4 (camera | top-down)"),
    agent_name: str = typer.Option("pid", "--agent", help="zoo agent (see `proxybench agent list`), or "
                                   "NAME=sdk:COMMAND: a duckietown-sdk program (docs/dtps.md)"),
    agent_cmd: str | None = typer.Option(None, "--agent-cmd",
                                         help="drive an agent node instead: any command speaking the AIDO protocol"),
    robot_cmd: str | None = typer.Option(None, "--robot-cmd",
                                         help="drive a robot node instead of the built-in simulator: any command "
                                              "speaking the robot protocol, e.g. 'proxybench robot serve'"),
    options: NodeOptions = None,  # the agent node options: with_agent_node_options
    robot_options: RobotNodeOptions = None,  # the --robot-* options: with_robot_node_options
    watchtowers: str | None = typer.Option(
        None, "--watchtowers", help="also record a lab's watchtowers into OUT/watchtowers (a log for `proxybench "
                                    "localize`): auto (the layout file beside the map, else one generated to cover "
                                    "the road) or a layout file (docs/autolab.md)"),
) -> None:
    """Drive an agent (default: the privileged PID controller) around a map in simulation and record it.

    Writes a video (camera view beside a top-down view), a PNG strip of camera frames and one metrics
    line. This is a *simulated* run: nothing here comes from a real robot. With --robot-cmd the robot is
    a node process (docs/robot-protocol.md) that decides camera size and rates (the video then shows what
    a camera agent saw beside the pose the robot reported) and the metrics say what the robot reported it
    is (``source``). --agent-cmd takes a command as you would
    type it (shell syntax such as `cd dir && exec node` works); --agent-cwd, --transport, the timeouts and
    --no-reflection say how to start and talk to it (docs/protocol.md §7); the --robot-* options do the
    same for the robot node of --robot-cmd.
    """
    from proxybench.cli.maps import load_map_printing_warnings
    from proxybench.domain.maps import MapError
    from proxybench.domain.params import DomainParams
    from proxybench.protocol import RobotFailure
    from proxybench.runner.jobs import DEFAULT_FRAME_RATE, DomainSpec
    from proxybench.runner.record import record_run
    from proxybench.tasks.metrics import METRICS

    try:
        m = load_map_printing_warnings(map_name)
    except (MapError, OSError) as exc:
        raise fail(exc) from exc
    if not m.drivable_tiles():
        raise fail(f"map {m.name!r} has no drivable tile: nothing to drive on")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise fail(f"--out: cannot create the folder {out}: {exc.strerror or exc}") from exc
    layout = streams = None
    if watchtowers is not None:
        from proxybench.autolab.cli_support import layout_streams
        from proxybench.autolab.watchtowers import LayoutError

        if robot_cmd is not None:
            raise fail("--watchtowers are simulated: they need the built-in simulator, not --robot-cmd", 2)
        try:
            layout, streams, _ = layout_streams(watchtowers, m)
        except LayoutError as exc:
            raise fail(f"--watchtowers: {exc}") from exc
    if robot_cmd is not None:  # the robot decides its camera; it is asked to step at the default rate
        domain = DomainSpec.robot(robot_cmd, frame_rate=DEFAULT_FRAME_RATE, options=robot_options)
        seconds_label, frames = f"{seconds:g} s on robot node", None  # the robot says its rate when it starts
    else:
        params = DomainParams(image_width=width, image_height=height)
        domain = DomainSpec("simulation", params)
        seconds_label, frames = f"{seconds:g} s", max(1, round(seconds * params.frame_rate))
    agent = _agent(agent_name, agent_cmd, options)
    with progress_bar(TextColumn("[bold]driving[/bold] {task.description}"), BarColumn(),
                      TextColumn("{task.completed}/{task.total} frames" if frames else "{task.completed} frames"),
                      TimeRemainingColumn(), console=console, transient=True) as progress:
        task = progress.add_task(f"{m.name}, {seconds_label}", total=frames)
        try:
            rec = record_run(domain, agent, m, seed, seconds, out, video=video,
                             meta={"map": m.name}, on_frame=lambda k: progress.advance(task), streams=streams)
        except RobotFailure as exc:
            err_console.print(f"[red]robot failure:[/red] {escape(exc.reason)}: {escape(exc.detail)}", highlight=False)
            for line in exc.stderr_tail[-10:]:
                err_console.print(f"    {line}", highlight=False, markup=False)
            raise typer.Exit(1) from exc
        except ValueError as exc:  # e.g. a privileged agent on a robot without ground truth
            raise fail(exc) from exc
        finally:
            getattr(agent, "close", lambda: None)()
    traj = rec.trajectory
    traj.save(out / "trajectory.parquet")
    if layout is not None:
        from proxybench.autolab.cli_support import finish_sim_log

        rec.files.append(finish_sim_log(out, layout, m.name, agent.name, seed, seconds, traj.termination))
    scores = {name: METRICS[name](traj) for name in _RUN_METRICS}
    source = traj.meta["source"]
    record = {"map": m.name, "agent": agent.name, "privileged": agent.privileged, "seed": seed, "source": source,
              **({"robot": robot_cmd} if robot_cmd is not None else {}),
              **({"robot_options": robot_options.non_default()} if robot_cmd and robot_options.non_default()
                 else {}),
              "termination": traj.termination, **scores, "wall_s": round(rec.wall_s, 2)}
    (out / "metrics.json").write_text(json.dumps(record, indent=2))
    names = [*rec.files, out / "trajectory.parquet", out / "metrics.json"]
    console.print(f"wrote {', '.join(str(f) for f in names)}", markup=False, highlight=False)
    if traj.failure is not None:
        err_console.print(f"[red]agent failure:[/red] {escape(traj.failure.message)}", highlight=False)
    where = "simulated" if robot_cmd is None else f"robot={source}"
    console.print(
        f"metrics: map={m.name} agent={agent.name}{' (privileged)' if agent.privileged else ''} {where} "
        + " ".join(f"{k}={v:.2f}" for k, v in scores.items()) + f" end={traj.termination} wall={rec.wall_s:.1f}s",
        highlight=False, markup=False,
    )


def _agent(agent_name: str, agent_cmd: str | None, options):
    """--agent (a zoo name, NAME=sdk:COMMAND or NAME=image:PATH) or --agent-cmd (an AIDO node); a clear error
    otherwise."""
    from proxybench.agents import make_agent

    if agent_cmd is not None:
        return remote_agent(agent_cmd, options)
    if "=" not in agent_name:
        try:
            return make_agent(agent_name)
        except KeyError as exc:
            raise fail(exc.args[0], 2) from exc
    from proxybench.dtps.env import DtpsEnvError
    from proxybench.experiments.agent_args import AgentArgError, is_image, parse_agent
    from proxybench.runner.jobs import SdkProgram
    from proxybench.runner.outcomes import make_agent_for

    try:
        spec = parse_agent(agent_name)
        if not isinstance(spec, SdkProgram) and not is_image(agent_name):
            raise AgentArgError(f"--agent {agent_name!r}: an AIDO agent node goes in --agent-cmd; --agent takes a zoo "
                                f"name, NAME=sdk:COMMAND or NAME=image:PATH")
        return make_agent_for(spec)
    except (AgentArgError, DtpsEnvError) as exc:
        raise fail(exc, 2) from exc
