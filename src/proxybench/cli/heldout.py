"""`proxybench heldout`: how often each usefulness metric picks the best available proxy θ on held-out targets.

Its options are generated from :class:`~proxybench.experiments.heldout.run.HeldOutConfig` (``--config FILE`` for
all of them at once).
"""

from __future__ import annotations

import time
from pathlib import Path

import typer
from rich.table import Table

from proxybench.cli.app import app, console
from proxybench.cli.config_options import study_options
from proxybench.cli.studies import BackendOption, WorkersOption, run_study
from proxybench.experiments.heldout.config import HeldOutConfig, default_help


@app.command()
@study_options(HeldOutConfig, defaults=default_help(), config_help="experiment file (YAML; fields of HeldOutConfig)")
def heldout(
    cfg: HeldOutConfig,
    quick: bool = typer.Option(False, "--quick", help="3 held-out targets + the negative case, 8 agents, 3×3 grid, "
                               "2 + 4 episodes × 12 s"),
    out: Path = typer.Option(Path("out/heldout"), help="report folder (report.html, figures, tables, runs/)"),
    backend: BackendOption = "local",
    workers: WorkersOption = None,
) -> None:
    """Score PRPV, PPV, SRCC (Pearson), Spearman, Kendall and MMRV on targets they were not tuned on.

    Held-out targets (simulated, with structural differences the proxies cannot express and a θ drawn from a
    hidden seed) and the standing negative case are run as black boxes; the pass criteria are written to
    OUT/criteria.json before any episode runs; hit rates come with Wilson intervals. Episodes are cached
    in OUT/runs, so an interrupted run resumes.
    """
    from proxybench.experiments.heldout.analysis import score_heldout
    from proxybench.experiments.heldout.report import findings, write_heldout_report
    from proxybench.experiments.heldout.run import run_heldout

    t0 = time.perf_counter()
    run = run_study(backend, workers, lambda be, progress: run_heldout(cfg, out, be, progress, quick=quick))
    res = score_heldout(run)
    run.wall_s = time.perf_counter() - t0
    files = write_heldout_report(res, out)
    task, ref, tol = res.primary()
    console.print("[bold]targets:[/bold] SIMULATED held-out stand-ins and the shipped reality model; no real robot.",
                  highlight=False)
    table = Table(title=f"hit rates on {sum(cr.case.kind == 'held-out' for cr in run.cases)} held-out targets — "
                        f"task {task}; pick within {tol} step(s) of the "
                        f"{'best available θ' if ref == 'order' else 'θ nearest the truth'}; {run.wall_s:.0f} s")
    for col in ("metric", "hits", "rate [95% Wilson]", "random pick"):
        table.add_column(col, justify="left" if col == "metric" else "right")
    for r in res.rates:
        if (r.task, r.reference, r.tolerance) == (task, ref, tol):
            table.add_row(r.metric, f"{r.hits}/{r.n}", f"{100 * r.rate:.0f}% [{100 * r.low:.0f}, {100 * r.high:.0f}]",
                          f"{100 * r.chance:.0f}%")
    console.print(table)
    for line in findings(res):
        console.print(f"• {line}", highlight=False, markup=False)
    console.print(f"wrote {files['html']}, {files['fig_hits']}, {files['fig_maps']} (+ .svg), {files['rates']}, "
                  f"{files['cases']}, {out / 'criteria.json'}", highlight=False)
