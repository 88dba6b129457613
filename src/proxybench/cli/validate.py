"""`proxybench validate`: does tuning a simulator help, on agents and target episodes it was not tuned on?"""

from __future__ import annotations

import time
from pathlib import Path

import typer
from rich.markup import escape

from proxybench.cli.app import app, console, err_console
from proxybench.cli.progress import progress_bar


@app.command()
def validate(
    family: str = typer.Option("heldout", help="target family: heldout (built-in structural stand-ins) | gym "
                                               "(gym-duckietown nodes, after `proxybench gym setup`)"),
    quick: bool = typer.Option(False, "--quick", help="3 targets, 8 agents, 2 + 2 episodes of 6 s, a 3×3 grid"),
    targets: int | None = typer.Option(None, min=2, help="targets (default 40; --quick 3)"),
    out: Path = typer.Option(Path("out/validate"), help="folder for criteria.json, the runs and the report"),
    backend: str = typer.Option("local", help="inline | local (process pool) | ray"),
    workers: int | None = typer.Option(None, min=1, help="worker processes (default: the machine's cores)"),
    seed: int = typer.Option(0, min=0, help="the study's seed (agent splits, episode seeds, BC agents)"),
    bc_agents: int | None = typer.Option(None, min=0, max=8, help="behaviour-cloned agents trained for the pool "
                                                                  "(default 2; --quick 0; needs PyTorch)"),
    interim: bool = typer.Option(False, "--interim", help="run nothing: report the targets finished so far (an "
                                                          "interim look; give the options the study was started "
                                                          "with; the decision waits for all targets)"),
) -> None:
    """Run the validation study (docs/validate.md): per target, choose θ with one half of the agents on some
    target episodes, judge the choice on the other half on fresh episodes, against the nominal θ and the
    oracle θ. criteria.json is written before the first episode; every episode is cached, so an interrupted
    study resumes. Writes report.html, summary.json, targets.csv and figures to --out."""
    from proxybench.experiments.config import ConfigError
    from proxybench.experiments.validate.report import answer, write_validation_report
    from proxybench.experiments.validate.run import ValidateConfig, run_validate, summarize
    from proxybench.runner.backends import make_backend

    try:
        cfg = ValidateConfig(family=family, targets=targets, seed=seed, bc_agents=bc_agents)
    except ValueError as exc:
        err_console.print(f"error: {escape(str(exc))}", highlight=False)
        raise typer.Exit(2) from exc
    t0 = time.perf_counter()
    be = make_backend(backend, workers)
    tasks: dict[str, int] = {}
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    with progress_bar(*columns, console=console, transient=True) as bar:
        def progress(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done, total=total)

        try:
            run = run_validate(cfg, out, be, progress, quick=quick, finished_only=interim)
        except ConfigError as exc:
            err_console.print(f"error: {escape(str(exc))}", highlight=False)
            raise typer.Exit(2) from exc
        finally:
            be.close()
    summary = summarize(run)
    summary["wall_s"] = round(time.perf_counter() - t0, 1)
    files = write_validation_report(run, summary, out)
    console.print(escape(answer(summary)), highlight=False)
    console.print(f"{run.episodes_run} episodes run now; wall {summary['wall_s']:.0f} s; wrote "
                  f"{', '.join(str(p) for p in files.values())}", highlight=False, markup=False)
