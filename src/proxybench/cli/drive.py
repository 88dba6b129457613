"""`proxybench run`: drive one agent around a map in simulation and record it."""

from __future__ import annotations

import json
import time
from pathlib import Path

import typer
from rich.markup import escape
from rich.progress import BarColumn, TextColumn, TimeRemainingColumn

from proxybench.cli.app import app, console, err_console
from proxybench.cli.node_options import (
    AGENT_CWD_HELP,
    NO_REFLECTION_HELP,
    START_TIMEOUT_HELP,
    STEP_TIMEOUT_HELP,
    TRANSPORT_HELP,
    RobotCwd,
    RobotNoReflection,
    RobotStartTimeout,
    RobotStepTimeout,
    RobotTransport,
    node_options,
    remote_agent,
    robot_node_options,
)
from proxybench.cli.options import positive
from proxybench.cli.progress import progress_bar

_RUN_METRICS = ("survival_time", "driven_lanedir_consec", "deviation_center_line", "in_drivable_lane", "lane_score")


@app.command()
def run(
    map_name: str = typer.Option("loop_3x3", "--map", help="built-in map name or YAML file"),
    seconds: float = typer.Option(60.0, callback=positive, help="episode length [s] (simulated time)"),
    seed: int = typer.Option(0, min=0, help="episode seed (start pose, noise)"),
    out: Path = typer.Option(Path("out/run"), help="folder for drive.mp4, drive_strip.png, metrics.json"),
    width: int = typer.Option(640, min=8, max=4096, help="camera width [px]"),
    height: int = typer.Option(480, min=8, max=4096, help="camera height [px]"),
    video: bool = typer.Option(True, help="write drive.mp4 (camera | top-down)"),
    agent_name: str = typer.Option("pid", "--agent", help="zoo agent (see `proxybench agent list`)"),
    agent_cmd: str | None = typer.Option(None, "--agent-cmd",
                                         help="drive an agent node instead: any command speaking the AIDO protocol"),
    robot_cmd: str | None = typer.Option(None, "--robot-cmd",
                                         help="drive a robot node instead of the built-in simulator: any command "
                                              "speaking the robot protocol, e.g. 'proxybench robot serve'"),
    agent_cwd: Path | None = typer.Option(None, "--agent-cwd", help=AGENT_CWD_HELP),
    transport: str = typer.Option("pipe", "--transport", help=TRANSPORT_HELP),
    start_timeout: float = typer.Option(30.0, "--start-timeout", help=START_TIMEOUT_HELP),
    step_timeout: float = typer.Option(5.0, "--step-timeout", help=STEP_TIMEOUT_HELP),
    no_reflection: bool = typer.Option(False, "--no-reflection", help=NO_REFLECTION_HELP),
    robot_cwd: RobotCwd = None,
    robot_transport: RobotTransport = None,
    robot_start_timeout: RobotStartTimeout = None,
    robot_step_timeout: RobotStepTimeout = None,
    robot_no_reflection: RobotNoReflection = False,
    watchtowers: str | None = typer.Option(
        None, "--watchtowers", help="also record a lab's watchtowers into OUT/watchtowers (a log for `proxybench "
                                    "localize`): auto (the layout file beside the map, else one generated to cover "
                                    "the road) or a layout file (docs/autolab.md)"),
) -> None:
    """Drive an agent (default: the privileged PID controller) around a map in simulation and record it.

    Writes a video (camera view beside a top-down view), a PNG strip of camera frames and one metrics
    line. This is a *simulated* run: nothing here comes from a real robot. With --robot-cmd the robot is
    a node process (docs/robot-protocol.md) that decides camera size and rates; no video is written and
    the metrics say what the robot reported it is (``source``). --agent-cmd takes a command as you would
    type it (shell syntax such as `cd dir && exec node` works); --agent-cwd, --transport, the timeouts and
    --no-reflection say how to start and talk to it (docs/protocol.md §7); the --robot-* options do the
    same for the robot node of --robot-cmd.
    """
    from proxybench.agents import make_agent
    from proxybench.cli.maps import load_map_printing_warnings
    from proxybench.domain.maps import MapError
    from proxybench.domain.params import DomainParams
    from proxybench.domain.simulator import Simulator
    from proxybench.runner.record import record_episode
    from proxybench.tasks.metrics import METRICS

    options = node_options(agent_cwd, transport, start_timeout, step_timeout, no_reflection)
    robot_options = robot_node_options(robot_cwd, robot_transport, robot_start_timeout, robot_step_timeout,
                                       robot_no_reflection, command=robot_cmd)
    try:
        m = load_map_printing_warnings(map_name)
    except (MapError, OSError) as exc:
        err_console.print(f"[red]error:[/red] {escape(str(exc))}", highlight=False)
        raise typer.Exit(1) from exc
    if not m.drivable_tiles():
        err_console.print(f"[red]error:[/red] map {escape(m.name)!r} has no drivable tile: nothing to drive on",
                          highlight=False)
        raise typer.Exit(1)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        err_console.print(f"[red]error:[/red] --out: cannot create the folder {escape(str(out))}: "
                          f"{escape(exc.strerror or str(exc))}", highlight=False)
        raise typer.Exit(1) from exc
    if robot_cmd is not None and watchtowers is not None:
        err_console.print("[red]error:[/red] --watchtowers are simulated: they need the built-in simulator, not "
                          "--robot-cmd", highlight=False)
        raise typer.Exit(2)
    if robot_cmd is not None:
        from proxybench.cli.robot import run_on_robot

        try:
            agent = make_agent(agent_name) if agent_cmd is None else remote_agent(agent_cmd, options)
        except KeyError as exc:
            err_console.print(f"[red]error:[/red] {escape(str(exc.args[0]))}", highlight=False)
            raise typer.Exit(2) from exc
        run_on_robot(robot_cmd, agent, map_name, seconds, seed, out, robot_options)
        return
    params = DomainParams(image_width=width, image_height=height)
    layout = streams = None
    if watchtowers is not None:
        from proxybench.autolab.cli_support import layout_streams
        from proxybench.autolab.watchtowers import LayoutError

        try:
            layout, streams, m = layout_streams(watchtowers, m)
        except LayoutError as exc:
            err_console.print(f"[red]error:[/red] --watchtowers: {escape(str(exc))}", highlight=False)
            raise typer.Exit(1) from exc
    sim = Simulator(m, params)
    try:
        agent = make_agent(agent_name) if agent_cmd is None else remote_agent(agent_cmd, options)
    except KeyError as exc:
        err_console.print(f"[red]error:[/red] {escape(str(exc.args[0]))}", highlight=False)
        raise typer.Exit(2) from exc
    steps = round(seconds * params.frame_rate)
    t0 = time.perf_counter()
    with progress_bar(TextColumn("[bold]driving[/bold] {task.description}"), BarColumn(),
                      TextColumn("{task.completed}/{task.total} frames"), TimeRemainingColumn(),
                      console=console, transient=True) as progress:
        task = progress.add_task(f"{m.name}, {seconds:g} s", total=steps)
        try:
            traj, files = record_episode(sim, agent, seed, seconds, out, video=video, meta={"map": m.name},
                                         on_frame=lambda k: progress.advance(task), streams=streams)
        finally:
            getattr(agent, "close", lambda: None)()
    elapsed = time.perf_counter() - t0
    traj.save(out / "trajectory.parquet")
    if layout is not None:
        from proxybench.autolab.cli_support import finish_sim_log

        files.append(finish_sim_log(out, layout, m.name, agent.name, seed, seconds, traj.termination))
    scores = {name: METRICS[name](traj) for name in _RUN_METRICS}
    record = {"map": m.name, "agent": agent.name, "privileged": agent.privileged, "seed": seed,
              "source": "simulation", "termination": traj.termination, **scores, "wall_s": round(elapsed, 2)}
    (out / "metrics.json").write_text(json.dumps(record, indent=2))
    names = [*files, out / "trajectory.parquet", out / "metrics.json"]
    console.print(f"wrote {', '.join(str(f) for f in names)}", markup=False, highlight=False)
    failure = [e["message"] for e in traj.events if e["kind"] == "agent_failure"]
    if failure:
        err_console.print(f"[red]agent failure:[/red] {escape(failure[0])}", highlight=False)
    console.print(
        f"metrics: map={m.name} agent={agent.name}{' (privileged)' if agent.privileged else ''} simulated "
        + " ".join(f"{k}={v:.2f}" for k, v in scores.items()) + f" end={traj.termination} wall={elapsed:.1f}s",
        highlight=False, markup=False,
    )
