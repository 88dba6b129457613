"""`proxybench dtps setup|check|serve|python`: duckietown-sdk agents and DTPS robots (docs/dtps.md)."""

from __future__ import annotations

import os
import shlex
import sys
from pathlib import Path

import typer
from rich.markup import escape

from proxybench.cli.app import app, console, err_console, fail
from proxybench.cli.help import HelpTyper
from proxybench.cli.options import positive

dtps_app = HelpTyper(no_args_is_help=True, help="duckietown-sdk agents and DTPS robots (docs/dtps.md).")
app.add_typer(dtps_app, name="dtps")

PathOpt = typer.Option(None, "--path", help="the SDK environment's folder (default: $PROXYBENCH_DTPS_ENV, else "
                       "~/.cache/proxybench/dtps-env)")


def _show(status) -> None:
    console.print(f"SDK environment: {escape(str(status.path))}", highlight=False)
    for pkg, version in status.versions.items():
        console.print(f"  {pkg} {version}", highlight=False)
    for problem in status.problems:
        err_console.print(f"[red]✗[/red] {escape(problem)}", highlight=False)
    if status.ok:
        console.print("[green]ok[/green]: SDK agents (--agent NAME=sdk:COMMAND) and DTPS robots can run here")
        console.print(f"an agent you start yourself (dtps serve) runs with this interpreter: "
                      f"{escape(shlex.quote(str(status.python)))} agent.py, or: proxybench dtps python agent.py",
                      highlight=False)


@dtps_app.command("setup")
def setup(path: Path | None = PathOpt) -> None:
    """Make the SDK environment (a venv with duckietown-sdk, dtps-http, duckietown-messages; libturbojpeg0 with apt
    when root): a few minutes once, nothing when it is there. Exit 1 when something is still missing."""
    from proxybench.dtps.env import DtpsEnvError, setup_env

    try:
        status = setup_env(path, say=lambda line: console.print(escape(line), highlight=False))
    except DtpsEnvError as exc:
        raise fail(exc) from exc
    _show(status)
    if not status.ok:
        raise typer.Exit(1)


@dtps_app.command("check")
def check(path: Path | None = PathOpt) -> None:
    """Say whether SDK agents and DTPS robots can run here (imports the SDK in its environment); exit 1 if not."""
    from proxybench.dtps.env import check_env

    status = check_env(path)
    _show(status)
    if not status.ok:
        raise typer.Exit(1)


@dtps_app.command(
    "python", context_settings={"allow_extra_args": True, "ignore_unknown_options": True,
                                "allow_interspersed_args": False},
    options_metavar="[--path DIR] [SCRIPT | -c CODE | -m MODULE] [ARGS]...")
def python_cmd(ctx: typer.Context, path: Path | None = PathOpt) -> None:
    """Run python with the SDK environment's interpreter: `proxybench dtps python agent.py ARGS...` (what an
    agent for `dtps serve` is started with; its own `python3` lacks duckietown-sdk). Everything after the
    first argument that is not --path goes to python unchanged; the interpreter replaces this process, so
    signals and the exit status are the script's own."""
    from proxybench.dtps.env import DtpsEnvError, sdk_environ, sdk_python

    try:
        interpreter = sdk_python(path)
    except DtpsEnvError as exc:
        raise fail(exc) from exc
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(interpreter, [str(interpreter), *ctx.args], sdk_environ(interpreter))


def agent_command(path: Path | None = None) -> str:
    """The exact shell command that starts ``agent.py`` with the SDK environment's interpreter (banner, docs);
    ``proxybench dtps python agent.py`` where that environment is not where the default says."""
    from proxybench.dtps.env import DtpsEnvError, sdk_python

    try:
        return f"{shlex.quote(str(sdk_python(path)))} agent.py"
    except DtpsEnvError:
        return "proxybench dtps python agent.py"


def _served_towers(map_name: str, layout: str):
    """(stream spec, sink) of the watchtowers of ``layout`` on the map, served over DTPS (``serve --watchtowers``),
    each watchtower's address printed."""
    from proxybench.autolab.served import served_towers
    from proxybench.autolab.watchtowers import resolve_layout
    from proxybench.domain.maps import load_map

    spec, sink = served_towers(resolve_layout(layout, load_map(map_name)))
    console.print(f"serving {len(spec.cameras)} SIMULATED watchtowers at "
                  f"{escape(sink.server.address(spec.cameras[0].name).rsplit('/', 1)[0])}/NAME", highlight=False)
    return spec, sink


@dtps_app.command("serve")
def serve(
    map_name: str = typer.Option("loop_3x3", "--map", help="built-in map name or YAML file"),
    name: str = typer.Option("map_0/vehicle_0", "--name", help="the robot's name (DB21J(NAME, simulated=True))"),
    port: int = typer.Option(7501, "--port", min=1, max=65535, help="TCP port (the SDK's simulator default)"),
    seconds: float | None = typer.Option(None, callback=positive, help="serve this long [s] (default: until Ctrl-C)"),
    episode_seconds: float = typer.Option(60.0, callback=positive, help="longest episode [s]"),
    seed: int = typer.Option(0, min=0, help="first episode's seed (start pose, noise); +1 per episode"),
    width: int = typer.Option(640, min=8, max=4096, help="camera width [px]"),
    height: int = typer.Option(480, min=8, max=4096, help="camera height [px]"),
    out: Path = typer.Option(Path("out/dtps-serve"), help="folder for the episodes' trajectories"),
    frame_rate: float = typer.Option(15.0, "--frame-rate", callback=positive, help="camera frames per second [Hz]"),
    watchtowers: str | None = typer.Option(None, "--watchtowers", help="also serve this watchtower layout (a file, "
                                           "or auto) of the same world as DTPS camera topics: a stand-in lab"),
) -> None:
    """Serve the simulator as a virtual DB21J on http://127.0.0.1:PORT/robot/NAME/ for an SDK agent you start.

    A SIMULATION in real time, not a robot. The agent connects with DB21J(NAME, simulated=True); its
    state/reset ends the episode and teleports the robot to the next start; so do leaving the road, a
    collision and --episode-seconds. Every episode is written to OUT as a trajectory, and summarised here
    (frames answered, late frames, worst lag). When the machine cannot simulate at the camera's rate, it
    warns (real time is not kept). --seconds is wall time: serving stops then, mid-episode if need be.
    """
    import signal
    import threading
    import time

    from proxybench.autolab.watchtowers import LayoutError
    from proxybench.domain.maps import MapError
    from proxybench.domain.params import DomainParams
    from proxybench.dtps.env import DtpsEnvError
    from proxybench.dtps.link import BridgeError
    from proxybench.runner.dtps_serve import WALL_TIME_UP
    from proxybench.runner.dtps_serve import serve as run_serve

    simulated: list[float] = []
    behind: list[bool] = []

    def said(k: int, traj) -> None:
        st = traj.meta["served"]["stats"]
        simulated.append(traj.duration)
        behind.append(st["behind"])
        cut = " (cut short: --seconds of wall time passed)" if any(e.message == WALL_TIME_UP for e in traj.events) \
            else ""
        console.print(f"episode {k}: {traj.duration:.1f} s, end={traj.termination}{cut}; {st['frames']} frames, "
                      f"{st['frames_answered']} answered by the agent, {st['late_frames']} late, worst lag "
                      f"{st['max_lag_s']:.2f} s", highlight=False)

    def ready(url: str) -> None:
        console.print(f"serving a SIMULATED DB21J at {escape(url)} (start the agent now; Ctrl-C to stop)",
                      highlight=False)
        console.print(f"  start an agent with the SDK environment's interpreter: {escape(agent_command())}\n"
                      f"  (or: proxybench dtps python agent.py; a plain python3 lacks duckietown-sdk)",
                      highlight=False)

    def late(message: str) -> None:
        err_console.print(f"[yellow]warning:[/yellow] {escape(message)}", highlight=False)

    hint = ("run the agent through proxybench in lock-step, which waits for its commands and keeps no wall "
            "clock: proxybench run --agent \"mine=sdk[lockstep]:python3 agent.py\" (docs/dtps.md §2)")
    if width * height > 160 * 120:
        hint = f"serve smaller frames than {width}x{height} (--width 160 --height 120), or {hint}"
    console.print(f"starting a virtual DB21J on port {port} ...", highlight=False)
    began = time.monotonic()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())  # ends the episode, which is saved, then the serve
    towers = None
    try:
        if watchtowers is not None:
            towers = _served_towers(map_name, watchtowers)
        files = run_serve(map_name, out, name=name, port=port, seconds=seconds or float("inf"),
                          episode_seconds=episode_seconds, seed=seed,
                          params=DomainParams(image_width=width, image_height=height, frame_rate=frame_rate),
                          on_episode=said, on_ready=ready, on_late=late, late_hint=hint, stop=stop,
                          streams=None if towers is None else towers[0])
    except (DtpsEnvError, BridgeError, MapError, OSError, LayoutError, ValueError) as exc:
        raise fail(exc) from exc
    except KeyboardInterrupt:
        raise typer.Exit(0) from None
    finally:
        if towers is not None:
            towers[1].server.close()
    wall = time.monotonic() - began
    console.print(f"stopped: --seconds {seconds or 0:g} of wall time passed ({wall:.0f} s with the start); "
                  f"{len(files)} episodes, {sum(simulated):.0f} s simulated, written to {escape(str(out))}",
                  highlight=False)
    if any(behind):
        err_console.print(f"[yellow]warning:[/yellow] {sum(behind)} of {len(behind)} episodes fell behind the wall "
                          f"clock (real time not kept): {escape(hint)}", highlight=False)
