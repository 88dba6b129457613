"""`proxybench predictivity`: the thesis' experiment on the usefulness of simulators for prediction."""

from __future__ import annotations

import time
from pathlib import Path

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from proxybench.cli.app import app, console


@app.command()
def predictivity(
    quick: bool = typer.Option(False, "--quick", help="12 agents × 3 episodes × 20 s (a minute or two)"),
    out: Path = typer.Option(Path("out/predictivity"), help="report folder (figures, tables, report.html)"),
    backend: str = typer.Option("local", help="inline | local (process pool) | ray"),
    workers: int | None = typer.Option(None, help="parallel workers (default: one per core)"),
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
    with Progress(*columns, console=console, transient=True) as bar:
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
