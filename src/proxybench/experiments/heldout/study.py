"""``proxybench heldout``, registered: how often each usefulness metric picks the best available θ on held-out
targets."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from proxybench.experiments.heldout.config import HeldOutConfig, default_help
from proxybench.experiments.study import Progress, Study, register

if TYPE_CHECKING:
    from proxybench.experiments.heldout.analysis import HeldOutResult

__all__ = ["HeldOutStudy"]


@register
class HeldOutStudy(Study[HeldOutConfig, "HeldOutResult"]):
    """Score PRPV, PPV, SRCC (Pearson), Spearman, Kendall and MMRV on targets they were not tuned on.

    Held-out targets (simulated, with structural differences the proxies cannot express and a θ drawn from a
    hidden seed) and the standing negative case are run as black boxes; the pass criteria are written to
    OUT/criteria.json before any episode runs; hit rates come with Wilson intervals. Episodes are cached
    in OUT/runs, so an interrupted run resumes.
    """

    name = "heldout"
    config = HeldOutConfig
    quick_help = "3 held-out targets + the negative case, 8 agents, 3×3 grid, 2 + 4 episodes × 12 s"
    out_help = "report folder (report.html, figures, tables, runs/)"

    def help_defaults(self) -> dict[str, str]:
        return default_help()

    def run(self, config: HeldOutConfig, out: Path, backend: Any, progress: Progress, *,
            quick: bool = False) -> HeldOutResult:
        from proxybench.experiments.heldout.analysis import score_heldout
        from proxybench.experiments.heldout.run import run_heldout

        return score_heldout(run_heldout(config, out, backend, progress, quick=quick))

    def write_report(self, result: HeldOutResult, out: Path, *, wall: float = 0.0) -> list[Path]:
        from proxybench.experiments.heldout.report import write_heldout_report

        result.run.wall_s = wall
        files = write_heldout_report(result, out)
        return [files["html"], files["fig_hits"], files["fig_maps"], files["rates"], files["cases"],
                out / "criteria.json"]

    def show(self, result: HeldOutResult, console: Any, *, wall: float = 0.0) -> None:
        from rich.table import Table

        from proxybench.experiments.heldout.report import findings

        res, run = result, result.run
        task, ref, tol = res.primary()
        console.print("[bold]targets:[/bold] SIMULATED held-out stand-ins and the shipped reality model; no real "
                      "robot.", highlight=False)
        table = Table(title=f"hit rates on {sum(cr.case.kind == 'held-out' for cr in run.cases)} held-out targets — "
                            f"task {task}; pick within {tol} step(s) of the "
                            f"{'best available θ' if ref == 'order' else 'θ nearest the truth'}; {wall:.0f} s")
        for col in ("metric", "hits", "rate [95% Wilson]", "random pick"):
            table.add_column(col, justify="left" if col == "metric" else "right")
        for r in res.rates:
            if (r.task, r.reference, r.tolerance) == (task, ref, tol):
                table.add_row(r.metric, f"{r.hits}/{r.n}",
                              f"{100 * r.rate:.0f}% [{100 * r.low:.0f}, {100 * r.high:.0f}]", f"{100 * r.chance:.0f}%")
        console.print(table)
        for line in findings(res):
            console.print(f"• {line}", highlight=False, markup=False)
