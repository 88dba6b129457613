"""The ``proxybench`` command line: thin Typer commands over the library."""

from __future__ import annotations

import json
import time
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

app = typer.Typer(add_completion=False, no_args_is_help=True, help=__doc__)
map_app = typer.Typer(no_args_is_help=True, help="Check, list and draw Duckietown map files.")
app.add_typer(map_app, name="map")
agent_app = typer.Typer(no_args_is_help=True, help="The built-in agent zoo.")
app.add_typer(agent_app, name="agent")
console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)


_RUN_METRICS = ("survival_time", "driven_lanedir_consec", "deviation_center_line", "in_drivable_lane", "lane_score")


@app.command()
def run(
    map_name: str = typer.Option("loop_3x3", "--map", help="built-in map name or YAML file"),
    seconds: float = typer.Option(60.0, help="episode length [s] (simulated time)"),
    seed: int = typer.Option(0, help="episode seed (start pose, noise)"),
    out: Path = typer.Option(Path("out/run"), help="folder for drive.mp4, strip.png, metrics.json"),
    width: int = typer.Option(640, help="camera width [px]"),
    height: int = typer.Option(480, help="camera height [px]"),
    video: bool = typer.Option(True, help="write drive.mp4 (camera | top-down)"),
    agent_name: str = typer.Option("pid", "--agent", help="zoo agent (see `proxybench agent list`)"),
) -> None:
    """Drive an agent (default: the privileged PID controller) around a map in simulation and record it.

    Writes a video (camera view beside a top-down view), a PNG strip of camera frames and one metrics
    line. This is a *simulated* run: nothing here comes from a real robot.
    """
    from proxybench.agents import make_agent
    from proxybench.domain.maps import MapError, load_map
    from proxybench.domain.params import DomainParams
    from proxybench.domain.simulator import Simulator
    from proxybench.domain.topdown import top_down
    from proxybench.media import VideoWriter, side_by_side, write_strip
    from proxybench.runner import run_episode
    from proxybench.tasks.metrics import METRICS

    try:
        m = load_map(map_name)
    except (MapError, FileNotFoundError) as exc:
        err_console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(1) from exc
    params = DomainParams(image_width=width, image_height=height)
    sim = Simulator(m, params)
    try:
        agent = make_agent(agent_name)
    except KeyError as exc:
        err_console.print(f"[red]error:[/red] {exc.args[0]}", highlight=False)
        raise typer.Exit(2) from exc
    out.mkdir(parents=True, exist_ok=True)
    steps = round(seconds * params.frame_rate)
    strip_every = max(1, steps // 11)
    strip, labels = [], []
    writer = VideoWriter(out / "drive.mp4", params.frame_rate) if video else None
    t0 = time.perf_counter()
    with Progress(TextColumn("[bold]driving[/bold] {task.description}"), BarColumn(),
                  TextColumn("{task.completed}/{task.total} frames"), TimeRemainingColumn(),
                  console=console, transient=True) as progress:
        task = progress.add_task(f"{m.name}, {seconds:g} s", total=steps + 1)

        def on_frame(k, image, s):
            if writer is not None:
                writer.append(side_by_side(image, top_down(m, s.state[:1, :3], px_per_tile=160)))
            if k % strip_every == 0:
                strip.append(image)
                labels.append(f"t={k / params.frame_rate:.1f}s")
            progress.advance(task)

        try:
            traj = run_episode(sim, agent, seed, seconds, camera=True, on_frame=on_frame, meta={"map": m.name})
        finally:
            if writer is not None:
                writer.close()
    elapsed = time.perf_counter() - t0
    write_strip(strip, out / "strip.png", labels)
    traj.save(out / "trajectory.parquet")
    scores = {name: METRICS[name](traj) for name in _RUN_METRICS}
    record = {"map": m.name, "agent": agent.name, "privileged": agent.privileged, "seed": seed,
              "source": "simulation", "termination": traj.termination, **scores, "wall_s": round(elapsed, 2)}
    (out / "metrics.json").write_text(json.dumps(record, indent=2))
    names = (["drive.mp4"] if video else []) + ["strip.png", "trajectory.parquet", "metrics.json"]
    console.print(f"wrote {', '.join(str(out / f) for f in names)}")
    failure = [e["message"] for e in traj.events if e["kind"] == "agent_failure"]
    if failure:
        err_console.print(f"[red]agent failure:[/red] {failure[0]}", highlight=False)
    console.print(
        f"metrics: map={m.name} agent={agent.name}{' (privileged)' if agent.privileged else ''} simulated "
        + " ".join(f"{k}={v:.2f}" for k, v in scores.items()) + f" end={traj.termination} wall={elapsed:.1f}s",
        highlight=False,
    )


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


@map_app.command("check")
def map_check(files: list[Path] = typer.Argument(..., help="map YAML files or built-in names")) -> None:
    """Validate map files; print a one-line summary each. Exit 1 if any is invalid."""
    from proxybench.domain.maps import MapError, load_map

    bad = 0
    for f in files:
        try:
            m = load_map(f if f.exists() else str(f))
        except MapError as exc:
            bad += 1
            err_console.print(f"[red]✗[/red] {f}: {len(exc.issues)} problem(s)")
            for issue in exc.issues:
                err_console.print(f"    {issue}", markup=False, highlight=False)
            continue
        except (FileNotFoundError, IsADirectoryError, UnicodeDecodeError) as exc:
            bad += 1
            err_console.print(f"[red]✗[/red] {f}: {exc}", highlight=False)
            continue
        console.print(f"[green]✓[/green] {f}: {m.summary()}", highlight=False)
    if bad:
        raise typer.Exit(1)


@map_app.command("show")
def map_show(
    file: str = typer.Argument(..., help="map YAML file or built-in name"),
    output: Path | None = typer.Option(None, "-o", "--output", help="PNG path (default: <map name>.png)"),
) -> None:
    """Draw a map top-down with its lane centre lines (arrows: driving direction) to a PNG."""
    from proxybench.domain.maps import MapError, load_map
    from proxybench.domain.topdown import save_map_plot

    try:
        m = load_map(file)
    except (MapError, FileNotFoundError) as exc:
        err_console.print(f"[red]error:[/red] {exc}", highlight=False)
        raise typer.Exit(1) from exc
    path = save_map_plot(m, output or Path(f"{m.name}.png"))
    console.print(f"wrote {path}")


@map_app.command("list")
def map_list() -> None:
    """List the built-in maps."""
    from proxybench.domain.maps import builtin_map_names, load_map

    for name in builtin_map_names():
        console.print(f"{name:16s} {load_map(name).summary()}", highlight=False)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
