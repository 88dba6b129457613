"""`proxybench predictivity`: the thesis' experiment on the usefulness of simulators for prediction."""

from __future__ import annotations

import time
from pathlib import Path

import typer
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
from rich.table import Table

from proxybench.cli.app import app, console
from proxybench.cli.progress import progress_bar


@app.command()
def predictivity(
    quick: bool = typer.Option(False, "--quick", help="12 agents × 3 episodes × 20 s (a minute or two)"),
    out: Path = typer.Option(Path("out/predictivity"), help="report folder (figures, tables, report.html)"),
    backend: str = typer.Option("local", help="inline | local (process pool) | ray"),
    workers: int | None = typer.Option(None, min=1, help="parallel workers (default: one per core)"),
) -> None:
    """Rank agents on the target and on swept simulator instances; plot PRPV, PPV, SRCC, POD (figs 3.3, 3.4).

    The target is the reality model, a *simulated* stand-in for a real Duckiebot. Episodes are cached in
    OUT/runs, so an interrupted run resumes where it stopped.
    """
    from proxybench.runner.backends import make_backend
    from proxybench.usefulness.predictivity import PredictivityConfig, run_predictivity
    from proxybench.usefulness.report import findings, write_report

    cfg = PredictivityConfig.quick() if quick else PredictivityConfig()
    be = make_backend(backend, workers)
    t0 = time.perf_counter()
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with progress_bar(*columns, console=console, transient=True) as bar:
        tasks: dict[str, int] = {}

        def progress(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done, total=total)

        try:
            res = run_predictivity(cfg, out / "runs", be, progress)
        finally:
            be.close()
    wall = time.perf_counter() - t0
    files = write_report(res, out, wall)
    df = res.frame()
    table = Table(title=f"usefulness of proxy instances (target: reality model, simulated) — {wall:.0f} s")
    for col in ("parameter", "value", "PRPV [95% CI]", "PPV", "SRCC", "Kendall τ", "MMRV", "POD"):
        table.add_column(col, justify="left" if col == "parameter" else "right")
    for _, r in df.iterrows():
        truth = " ←truth" if abs(r.value - r.truth) < 1e-9 else ""
        table.add_row(r.parameter, f"{r.value:g}{truth}", f"{r.prpv:.0f} [{r.prpv_low:.0f}, {r.prpv_high:.0f}]",
                      f"{r.ppv:.2f}", f"{r.srcc:.2f}", f"{r.kendall:.2f}", f"{r.mmrv:.2f}", f"{r.pod:.3f}")
    console.print(table)
    for line in findings(res):
        console.print(f"• {line}", highlight=False)
    console.print(f"wrote {files['html']}, {files['fig3_3']}, {files['fig3_4']} (+ .svg), {files['csv']}")


def _parse_space(items: list[str]) -> dict[str, tuple[float, float]]:
    space = {}
    for item in items:
        try:
            name, rng = item.split("=", 1)
            lo, hi = (float(v) for v in rng.split(":"))
        except ValueError as exc:
            raise typer.BadParameter(f"{item!r}: expected NAME=LOW:HIGH, e.g. trim=-0.3:0.3") from exc
        space[name.strip()] = (lo, hi)
    return space


@app.command()
def optimize(
    param: list[str] = typer.Option(["trim=-0.3:0.3", "camera_pitch=12:26"], "--param",
                                    help="a parameter to search, NAME=LOW:HIGH (repeat)"),
    objective: str = typer.Option("mix", help="prpv | ppv | mix (normalised PRPV + PPV)"),
    trials: int = typer.Option(60, min=1),
    sampler: str = typer.Option("tpe", help="tpe | gp | random"),
    storage: str | None = typer.Option(None, help="SQLite file or SQLAlchemy URL (PostgreSQL to share a study)"),
    study_name: str = typer.Option("proxybench-proxy"),
    quick: bool = typer.Option(False, "--quick", help="fewer agents, episodes and trials"),
    out: Path = typer.Option(Path("out/optimize"), help="folder for plots, trials table and episode cache"),
    backend: str = typer.Option("local", help="inline | local | ray"),
    workers: int | None = typer.Option(None, min=1),
) -> None:
    """Find the simulator parameters θ* whose agent ranking best matches the target's (Optuna).

    The target is the reality model (a simulated stand-in for a real Duckiebot); its calibrated values
    are printed beside what was recovered, with the residual gap.
    """
    import json

    from proxybench.runner.backends import make_backend
    from proxybench.usefulness.optimize import OptimizeConfig, optimize_proxy, plot_optimization

    try:
        space = _parse_space(param)
        cfg = OptimizeConfig(space=space, objective=objective, n_trials=trials, sampler=sampler, storage=storage,
                             study_name=study_name)
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from exc
    if quick:
        cfg.agents, cfg.episodes, cfg.seconds = cfg.agents[:8], 2, 12.0
        cfg.n_trials = min(cfg.n_trials, 20)
    be = make_backend(backend, workers)
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    with progress_bar(TextColumn("trials"), BarColumn(), MofNCompleteColumn(), TextColumn("best {task.fields[best]}"),
                      TimeRemainingColumn(), console=console, transient=True) as bar:
        task = bar.add_task("trials", total=cfg.n_trials, best="–")
        best = [float("inf")]

        def progress(done: int, total: int, value: float) -> None:
            best[0] = min(best[0], value)
            bar.update(task, completed=done, best=f"{best[0]:.4f}")

        try:
            res = optimize_proxy(cfg, out / "runs", be, progress)
        finally:
            be.close()
    paths = plot_optimization(res, out)
    (out / "trials.json").write_text(json.dumps(res.trials, indent=1))
    table = Table(title=f"proxy optimisation: {len(res.trials)} trials, objective {cfg.objective}, "
                        f"{time.perf_counter() - t0:.0f} s (target: reality model, simulated)")
    for col in ("parameter", "recovered (best decile)", "truth", "error", "single best trial"):
        table.add_column(col, justify="left" if col == "parameter" else "right")
    for name, v in res.recovered.items():
        t = res.truth.get(name)
        table.add_row(name, f"{v:.3f}", "–" if t is None else f"{t:g}", "–" if t is None else f"{v - t:+.3f}",
                      f"{res.best_params[name]:.3f}")
    console.print(table)
    console.print(f"residual (best objective, the gap no θ in this family closes): {res.best_value:.4f}")
    console.print(f"wrote {', '.join(str(p) for p in paths)}, {out / 'trials.json'}")
