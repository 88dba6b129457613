"""``proxybench predictivity``, registered: rank agents on a target and on swept proxy instances θ."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from proxybench.experiments.config import ExperimentConfig, ExperimentStudy
from proxybench.experiments.study import Progress, register

if TYPE_CHECKING:
    from proxybench.experiments.predictivity.run import PredictivityResult

__all__ = ["PredictivityStudy", "ci"]


@register
class PredictivityStudy(ExperimentStudy):
    """Rank agents on a target and on swept simulator instances; PRPV, PPV, SRCC, POD beside \
the target's noise floor.

    Proxies replay each target episode from its start pose and seed. Episodes are cached in OUT/runs, so
    an interrupted run resumes where it stopped; a recorded target costs no simulation.
    """

    name = "predictivity"
    quick_help = "12 agents × 3 episodes × 20 s (a minute or two)"
    out_help = "report folder (figures, tables, report.html) and episode cache (OUT/runs)"
    exclude = ("search", "plan", "plv")

    def run(self, config: ExperimentConfig, out: Path, backend: Any, progress: Progress, *,
            quick: bool = False) -> PredictivityResult:
        from proxybench.experiments.predictivity.run import run_predictivity

        return run_predictivity(config, out / "runs", backend, progress, quick=quick)

    def write_report(self, result: PredictivityResult, out: Path, *, wall: float = 0.0) -> list[Path]:
        from proxybench.experiments.predictivity.report import write_report

        files = write_report(result, out, wall)
        return [files["html"], files["fig3_3"], files["fig3_4"], files["csv"]]

    def example(self) -> PredictivityResult:
        """A canned result: five agents, a three-value trim sweep, made-up scores (no episode runs)."""
        from proxybench.experiments.examples import canned_experiment, canned_proxies, canned_target
        from proxybench.experiments.predictivity.run import measure_predictivity, proxy_domains

        exp = canned_experiment()
        tgt = canned_target(exp)
        domains = proxy_domains(exp)
        return measure_predictivity(exp, tgt, domains, canned_proxies(tgt, [d.name for _, _, d in domains]))

    def show(self, result: PredictivityResult, console: Any, *, wall: float = 0.0) -> None:
        from proxybench.experiments.predictivity.report import findings

        console.print(f"[bold]target:[/bold] {result.target.info.statement}", highlight=False)
        _print_table(result, wall, console)
        for line in findings(result):
            console.print(f"• {line}", highlight=False, markup=False)


def ci(e: Any, fmt: str) -> str:
    """``value [low, high]`` as a table cell (no brackets where the interval is undefined)."""
    from rich.markup import escape

    if not (math.isfinite(e.low) and math.isfinite(e.high)):
        return f"{e.value:{fmt}}"
    return escape(f"{e.value:{fmt}} [{e.low:{fmt}}, {e.high:{fmt}}]")


def _print_table(res: PredictivityResult, wall: float, console: Any) -> None:
    import numpy as np
    from rich.markup import escape
    from rich.table import Table

    exp = res.experiment
    title = (f"usefulness of proxy instances — target: {res.target.info.label}; {len(exp.agents)} agents × "
             f"{exp.episode_count} episodes × {exp.seconds:g} s; {wall:.0f} s")
    table = Table(title=title)
    for col in ("parameter", "value", "PRPV [order range]", "Δ vs best [paired CI]", "PPV (mean/agent)", "Pearson r",
                "Spearman ρ", "Kendall τ", "POD"):
        table.add_column(escape(col), justify="left" if col == "parameter" else "right")  # "[…]" is not markup
    df = res.frame()
    for name in exp.sweep:
        claim = res.claims.get(name)
        for _, r in df[df.parameter == name].sort_values("value").iterrows():
            mark = " ←known θ" if np.isfinite(r.truth) and abs(r.value - r.truth) < 1e-9 else ""
            best = claim is not None and claim.best == r.value
            delta = "best" + ("" if claim.separated else " (not separated)") if best else \
                f"{r.delta_best:+.1f} [{r.delta_best_low:+.1f}, {r.delta_best_high:+.1f}]"
            table.add_row(name, f"{r.value:g}{mark}", f"{r.prpv:.1f} [{r.prpv_low:.1f}, {r.prpv_high:.1f}]", delta,
                          f"{r.ppv:.2f} [{r.ppv_low:.2f}, {r.ppv_high:.2f}]", f"{r.pearson:.2f}", f"{r.spearman:.2f}",
                          f"{r.kendall:.2f}",
                          "n/a" if not np.isfinite(r.pod) else f"{r.pod:.3f}")
    nf = res.noise
    pf = res.ppv_noise
    table.add_row("target noise floor", "", f"{nf.value:.1f} [{nf.low:.1f}, {nf.high:.1f}]", "",
                  f"{pf.value:.2f} [{pf.low:.2f}, {pf.high:.2f}]" if pf is not None else "", "", "", "", "")
    console.print(table)
