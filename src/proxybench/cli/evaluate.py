"""`proxybench score` and `proxybench repeatability`: scoring recorded runs, and run-to-run spread."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from proxybench.cli.app import app, console, err_console

_SCORE_METRICS = ("survival_time", "driven_lanedir_consec", "driven_any", "deviation_center_line",
                  "deviation_heading", "in_drivable_lane", "lane_score")


@app.command()
def score(
    files: list[Path] = typer.Argument(..., help="trajectory files: proxybench Parquet, or recorded CSV/Parquet"),
    map_name: str = typer.Option("loop_3x3", "--map", help="map of recorded runs (t, x, y, theta in its frame)"),
    episode_seconds: float | None = typer.Option(None, help="cap survival_time at this episode length [s]"),
) -> None:
    """Score trajectories with the task metrics: imported real runs and simulated ones alike.

    Recorded runs need columns t [s], x [m], y [m], theta [rad] in the map frame (as a localisation
    system such as the Autolab's watchtowers produces); the lane pose is recomputed from the map.
    """
    from proxybench.tasks.metrics import METRICS
    from proxybench.tasks.trajectory import Trajectory, TrajectoryError

    table = Table(title="scores")
    for col in ("file", "source", "end", *_SCORE_METRICS):
        table.add_column(col, justify="left" if col in ("file", "source", "end") else "right")
    bad = 0
    for f in files:
        try:
            traj = _load_any(f, map_name, Trajectory, TrajectoryError)
        except (TrajectoryError, FileNotFoundError) as exc:
            err_console.print(f"[red]✗[/red] {exc}", highlight=False)
            bad += 1
            continue
        if episode_seconds:
            traj.meta["episode_seconds"] = episode_seconds
        table.add_row(f.name, str(traj.meta.get("source", "?")), traj.termination,
                      *(f"{METRICS[m](traj):.3f}" for m in _SCORE_METRICS))
    console.print(table)
    if bad:
        raise typer.Exit(1)


def _load_any(path: Path, map_name: str, Trajectory, TrajectoryError):
    """A proxybench trajectory file as saved, else a recorded run imported against ``map_name``."""
    if path.suffix == ".parquet":
        try:
            return Trajectory.load(path)
        except TrajectoryError as exc:
            if "no proxybench metadata" not in str(exc):
                raise
    return Trajectory.from_file(path, map_name)


@app.command()
def repeatability(
    agent: str = typer.Option("vision", help="zoo agent"),
    runs: int = typer.Option(10, min=2, help="runs per setting"),
    seconds: float = typer.Option(30.0, help="length of each run [s]"),
    map_name: str = typer.Option("loop_3x3", "--map"),
    seed: int = typer.Option(0),
    out: Path = typer.Option(Path("out/repeatability"), help="folder for the table and the trajectory plot"),
) -> None:
    """MPD / MOD of one agent: one robot N times, N robots, N labs (thesis figs. 5.8–5.10), simulated.

    All three settings run on the reality model, a simulated stand-in for real Duckiebots.
    """
    import json

    from proxybench.domain.maps import load_map
    from proxybench.plots import plot_trajectories
    from proxybench.runner.repeatability import SETTINGS, repeatability_study

    out.mkdir(parents=True, exist_ok=True)
    with console.status("running") as status:
        res = repeatability_study(agent, runs, seconds, map_name, seed,
                                  progress=lambda s, k: status.update(f"{s}: run {k + 1}/{runs}"))
    table = Table(title=f"repeatability of {agent}: {runs} runs × {seconds:g} s per setting (simulated, reality model)")
    for col in ("setting", "MPD (cm)", "± std", "MOD (deg)", "± std", "runs ended early"):
        table.add_column(col, justify="left" if col == "setting" else "right")
    for s in SETTINGS:
        f = res.figures[s]
        early = sum(t.termination != "timeout" for t in res.runs[s])
        table.add_row(s, f"{f['MPD_cm']:.2f}", f"{f['MPD_std_cm']:.2f}", f"{f['MOD_deg']:.2f}",
                      f"{f['MOD_std_deg']:.2f}", str(early))
    console.print(table)
    (out / "repeatability.json").write_text(json.dumps(res.figures, indent=2))
    png = plot_trajectories(load_map(map_name), res.runs, out / "trajectories.png")
    console.print(f"wrote {out / 'repeatability.json'}, {png} (+ .svg)")
