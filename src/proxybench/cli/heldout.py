"""`proxybench heldout`: how often each usefulness metric picks the best available proxy θ on held-out targets."""

from __future__ import annotations

import time
from pathlib import Path

import typer
from rich.table import Table

from proxybench.cli.app import app, console
from proxybench.cli.options import positive
from proxybench.cli.usefulness import _AGENT_HELP, _bars, _fail, _stage_progress


def _grid(items: list[str]) -> dict[str, list[float]]:
    out = {}
    for item in items:
        name, sep, raw = item.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError
            out[name.strip()] = [float(v) for v in raw.split(",") if v.strip()]
        except ValueError:
            raise typer.BadParameter(f"{item!r}: expected NAME=V1,V2,…, e.g. trim=-0.2,0,0.2",
                                     param_hint="--grid") from None
    return out


@app.command()
def heldout(
    quick: bool = typer.Option(False, "--quick", help="3 held-out targets + the negative case, 8 agents, 3×3 grid, "
                               "2 + 4 episodes × 12 s"),
    config: Path | None = typer.Option(None, "--config", help="experiment file (YAML; fields of HeldOutConfig)"),
    targets: int | None = typer.Option(None, min=1, help="held-out targets drawn (default: 12; --quick 3)"),
    negative_case: bool | None = typer.Option(None, "--negative-case/--no-negative-case",
                                              help="add the standing negative case (default: yes)"),
    agent: list[str] = typer.Option([], "--agent", help=f"{_AGENT_HELP} (default: 12 zoo agents; --quick 8)"),
    map_name: str | None = typer.Option(None, "--map", help="map (default: loop_3x3)"),
    episodes: int | None = typer.Option(None, min=1, help="evaluation episodes per agent (default: 3; --quick 2)"),
    reference_episodes: int | None = typer.Option(None, min=2, help="reference episodes per agent, other seeds "
                                                  "(default: 8; --quick 4)"),
    seconds: float | None = typer.Option(None, callback=positive, help="episode length in s (default: 20; "
                                         "--quick 12)"),
    grid: list[str] = typer.Option([], "--grid", help="proxy θ grid axis NAME=V1,V2,… (repeat) (default: trim "
                                   "±0.2 in 5 steps × camera pitch 15.15…23.15 in 5; --quick 3 × 3)"),
    n_boot: int | None = typer.Option(None, min=10, help="bootstrap resamples per θ (default: 100; --quick 50)"),
    agent_boot: int | None = typer.Option(None, min=10, help="bootstrap agent sets (default: 200)"),
    seed: int | None = typer.Option(None, min=0, help="episode and resampling seed (default: 0)"),
    out: Path = typer.Option(Path("out/heldout"), help="report folder (report.html, figures, tables, runs/)"),
    backend: str = typer.Option("local", help="inline | local (process pool) | ray"),
    workers: int | None = typer.Option(None, min=1, help="parallel workers (default: one per core)"),
) -> None:
    """Score PRPV, PPV, SRCC (Pearson), Spearman, Kendall and MMRV on targets they were not tuned on.

    Held-out targets (simulated, with structural differences the proxies cannot express and a θ drawn from a
    hidden seed) and the standing negative case are run as black boxes; the pass criteria are written to
    OUT/criteria.json before any episode runs; hit rates come with Wilson intervals. Episodes are cached
    in OUT/runs, so an interrupted run resumes.
    """
    from proxybench.cli.usefulness import _overrides
    from proxybench.experiments.config import ConfigError
    from proxybench.experiments.heldout import load_heldout_config, run_heldout
    from proxybench.experiments.heldout_analysis import score_heldout
    from proxybench.experiments.reports.heldout import findings, write_heldout_report
    from proxybench.runner.backends import make_backend
    from proxybench.targets.manifest import TargetError

    over = _overrides(targets=targets, negative_case=negative_case, agents=agent, map=map_name, episodes=episodes,
                      reference_episodes=reference_episodes, seconds=seconds, grid=_grid(grid) or None,
                      n_boot=n_boot, agent_boot=agent_boot, seed=seed)
    try:
        cfg = load_heldout_config(config, over)
    except ConfigError as exc:
        _fail(exc)
    be = make_backend(backend, workers)
    t0 = time.perf_counter()
    with _bars() as bar:
        try:
            run = run_heldout(cfg, out, be, _stage_progress(bar), quick=quick)
        except (TargetError, ValueError) as exc:
            _fail(exc)
        finally:
            be.close()
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
