"""`proxybench localize`: a lab's watchtower logs (image folders, ROS bags) → a recorded target (docs/autolab.md)."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape

from proxybench.cli.app import app, console, fail, require_extra
from proxybench.cli.help import HelpTyper


@app.command()
def localize(
    logdir: Path = typer.Argument(..., help="a run's log (folder with log.yaml and watchtowers/, or a ROS bag), "
                                            "or a folder of them"),
    map_name: str = typer.Option(..., "--map", help="the map the runs were on (built-in, duckietown-world, or file)"),
    out: Path = typer.Option(..., "--out", help="folder of the recorded target to write"),
    watchtowers: Path | None = typer.Option(None, "--watchtowers", help="layout file: the lab's ground tags and "
                                                                        "robots' roof tag ids (docs/autolab.md)"),
    calibrations: Path | None = typer.Option(None, "--calibrations", help="watchtower calibrations of ROS bags: "
                                             "DIR/<name>/calibration.yaml (default: calibrations/ beside the bag)"),
    source: str | None = typer.Option(None, "--source", help="real | simulation | ...: where the runs come from "
                                                             "(default: the logs' log.yaml; bags: real)"),
    agent: str | None = typer.Option(None, "--agent", help="the agent the runs drove (default: the logs')"),
    active: str | None = typer.Option(None, "--active", help="the robot the agent drove (default: the logs', ego)"),
    seconds: float | None = typer.Option(None, "--seconds", min=0.1, help="planned episode length [s]"),
    lost: float = typer.Option(1.0, "--lost-s", min=0.0, help="a run whose robot went unseen longer is invalid [s]"),
    light: float = typer.Option(0.2, "--light-change", min=0.0, help="a run whose light changed by more (relative) "
                                                                     "is invalid"),
    detector: str = typer.Option("apriltag", help="apriltag (pupil-apriltags) | aruco (OpenCV)"),
    solver: str = typer.Option("gtsam", help="gtsam (with per-sample uncertainty) | scipy"),
    decimate: float = typer.Option(2.0, min=1.0, help="detector's quad decimation (apriltag): 1 finds smaller tags, "
                                                     "2 is ~3× faster"),
    workers: int | None = typer.Option(None, min=1, help="detection processes (default: one per core)"),
) -> None:
    """Localise every robot of every run under LOGDIR from its watchtower streams, validate each run (lost robot,
    illumination change, premature end: invalid runs are listed with their reason) and write the valid ones as a
    recorded target that `proxybench target check` accepts."""
    from proxybench.autolab.target import localize_logs
    from proxybench.autolab.validate import Thresholds
    from proxybench.autolab.watchtowers import LayoutError, UnsafeLogError
    from proxybench.cli.maps import load_map_printing_warnings
    from proxybench.domain.maps import MapError

    if detector not in ("apriltag", "aruco") or solver not in ("gtsam", "scipy"):
        raise fail("--detector is apriltag or aruco, --solver gtsam or scipy", 2)
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn

    from proxybench.cli.progress import progress_bar

    try:
        m = load_map_printing_warnings(map_name)
        overrides = {"source": source, "agent": agent, "active": active, "seconds": seconds}
        with progress_bar(TextColumn("[bold]detecting tags[/bold] {task.description}"), BarColumn(),
                          MofNCompleteColumn(), TimeRemainingColumn(), console=console, transient=True) as bar:
            tasks: dict[str, object] = {}

            def tick(run: str, done: int, total: int) -> None:
                if run not in tasks:
                    tasks[run] = bar.add_task(Path(run).name, total=total)
                bar.update(tasks[run], completed=done)

            summary = localize_logs(logdir, m, out, layout=watchtowers, calibrations=calibrations,
                                    overrides=overrides, limits=Thresholds(lost_s=lost, light_change=light),
                                    detector=detector, solver=solver, workers=workers, decimate=decimate,
                                    progress=tick)
    except UnsafeLogError as exc:  # a log that is unsafe to use (a name that is a path, a FIFO, …): refused
        raise fail(exc, 2, mark="✗") from None
    except (LayoutError, MapError, ImportError) as exc:
        raise fail(exc, mark="✗") from None
    for path, verdict, loc in summary.runs:
        tracks = ", ".join(f"{r} {t.t.size} samples" for r, t in loc.robots.items()) or "no robot seen"
        mark = "[green]✓[/green]" if verdict.valid else "[yellow]invalid[/yellow]"
        console.print(f"{mark} {escape(str(path))}: {loc.frames} frames, {loc.detections} tags; {tracks}"
                      + ("" if verdict.valid else f": {escape('; '.join(verdict.reasons))}"), highlight=False)
        for note in loc.notes:
            console.print(f"  note: {escape(note)}", highlight=False)
    mf = summary.manifest
    console.print(f"wrote {escape(str(out))}: {len(mf.agents)} agent(s) × {len(mf.episodes)} episode(s), "
                  f"{len(mf.excluded)} run(s) excluded; check it with: proxybench target check {escape(str(out))}",
                  highlight=False)


autolab_app = HelpTyper(no_args_is_help=True, help="An Autolab: a lab description (lab.yaml) checked, and the lab "
                        "its evaluator drives (docs/autolab.md).")
app.add_typer(autolab_app, name="autolab")


@autolab_app.command("check")
def autolab_check(lab_file: Path = typer.Argument(..., help="the lab description (lab.yaml)")) -> None:
    """Check a lab description: strict fields, its map, its watchtower layout or calibrations, its pose file."""
    from proxybench.autolab.lab import LabError, check_lab, load_lab
    from proxybench.autolab.watchtowers import UnsafeLogError

    try:
        lab = load_lab(lab_file)
        lines = check_lab(lab, str(lab_file))
    except UnsafeLogError as exc:
        raise fail(exc, 2, mark="✗") from None
    except LabError as exc:
        raise fail(exc, mark="✗") from None
    for line in lines:
        console.print(escape(line), highlight=False)
    console.print(f"[green]✓[/green] {escape(str(lab_file))}: lab {escape(lab.name)!r} is usable", highlight=False)


def _operator(lab_file: Path, robot: str, act) -> str:
    """Run the desk's ``act(lab, robot)`` for the lab in ``lab_file``; exit 1 with its one line if it cannot."""
    from proxybench.autolab.lab import LabError, load_lab
    from proxybench.autolab.operator import OperatorError

    try:
        return act(load_lab(lab_file), robot)
    except (LabError, OperatorError, OSError) as exc:
        raise fail(exc, mark="✗") from None
    except KeyError as exc:
        raise fail(str(exc.args[0]), mark="✗") from None


@autolab_app.command("ready")
def autolab_ready(lab_file: Path = typer.Argument(..., help="the lab description (lab.yaml)"),
                  robot: str = typer.Argument(..., help="the robot you placed")) -> None:
    """Confirm that ROBOT stands where the Autolab evaluator asked (reset mode operator): its episode starts."""
    from proxybench.autolab.operator import confirm_ready

    request = _operator(lab_file, robot, confirm_ready)
    console.print(f"[green]✓[/green] confirmed: {escape(request)}", highlight=False)


@autolab_app.command("intervene")
def autolab_intervene(lab_file: Path = typer.Argument(..., help="the lab description (lab.yaml)"),
                      robot: str = typer.Argument(..., help="the robot you stepped in for"),
                      reason: str = typer.Option("the operator intervened", "--reason", help="what happened")) -> None:
    """Say that you intervened in ROBOT's running episode: it ends, and its job is the lab's fault
    (host-error manual_intervention, run again)."""
    from proxybench.autolab.operator import intervene

    episode = _operator(lab_file, robot, lambda lab, name: intervene(lab, name, reason))
    console.print(f"intervention recorded: {escape(episode)} of robot {escape(robot)} ends", highlight=False)


@autolab_app.command("demo")
def autolab_demo(
    out: Path | None = typer.Option(None, "--out", help="a new or empty folder for the server's database, the lab, "
                                                        "tokens, logs and job.json [a temporary folder]"),
    once: bool = typer.Option(False, "--once", help="run the one submission end to end, write OUT/job.json and exit "
                                                    "(0 when the job succeeded)"),
    port: int = typer.Option(0, min=0, max=65535, help="the server's port on 127.0.0.1 [a free one]"),
    seconds: float = typer.Option(10.0, min=0.5, max=120.0, help="the episode's length [s]"),
    frame_rate: float = typer.Option(10.0, min=0.5, max=30.0, help="the robot's camera rate [Hz]"),
    watchtower_rate: float = typer.Option(5.0, min=0.5, max=30.0, help="the watchtowers' frame rate [Hz]"),
    video: bool = typer.Option(True, help="the evaluator uploads a top-down video of the localised episode"),
    dev_unsafe_same_user: bool = typer.Option(False, "--dev-unsafe-same-user", help="DEVELOPMENT ONLY: where the "
                                              "agent user's sandbox is impossible, run the agent as this user"),
) -> None:
    """Stand up a whole simulated Autolab on this machine and evaluate the built-in SDK agent in it.

    The challenges server (SQLite in OUT/server, on 127.0.0.1 only), a lab of a virtual DB21J and simulated
    watchtowers (OUT/lab.yaml), an Autolab evaluator (`proxybench evaluator --autolab`), and a submission of the
    built-in lane-following duckietown-sdk agent, measured by the watchtowers. It prints the leaderboard's URL and
    serves until Ctrl-C, which stops everything it started. Needs `proxybench dtps setup` and the agent sandbox
    (`proxybench sandbox setup`).
    """
    require_extra("server")
    import signal

    from proxybench.autolab.lab import LabError
    from proxybench.cli.autolab_demo import DemoError, DemoOptions, run_demo
    from proxybench.client import ServerError

    def stop(*_: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)  # stopped like Ctrl-C: everything it started is stopped too
    options = DemoOptions(out=out, once=once, port=port, seconds=seconds, frame_rate=frame_rate,
                          watchtower_rate=watchtower_rate, video=video, dev_unsafe=dev_unsafe_same_user)
    try:
        summary = run_demo(options, lambda line: console.print(escape(line), highlight=False))
    except KeyboardInterrupt:
        console.print("stopped: the evaluator, its job and the server")
        return
    except (DemoError, LabError, ServerError) as exc:
        raise fail(exc, mark="✗") from None
    scores = ", ".join(f"{k} {v:.3f}" for k, v in summary.scores.items() if v is not None and k.endswith("_median"))
    error = summary.localization_median_error_m
    console.print(f"job {summary.job}: {summary.status}: {escape(summary.message)}", highlight=False)
    if scores:
        console.print(f"  scores (measured by the watchtowers): {escape(scores)}"
                      + ("" if error is None else f"; localisation median error {100 * error:.2f} cm"), highlight=False)
    console.print(f"  leaderboard: {summary.leaderboard}", highlight=False)
    if summary.status != "success":
        raise typer.Exit(1)
