"""``proxybench plv-vs-prpv``, registered: do argmin PRPV (predict) and argmax PLV (teach) pick the same θ?"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from proxybench.experiments.config import ConfigError, ExperimentConfig, ExperimentStudy
from proxybench.experiments.study import Progress, register

if TYPE_CHECKING:
    from proxybench.experiments.plv_prpv.run import ChoiceResult

__all__ = ["PLVvsPRPVStudy"]


@register
class PLVvsPRPVStudy(ExperimentStudy):
    """Do the two uses of a simulator pick the same θ? argmin PRPV (predict) and argmax PLV (teach) on \
one target.

    For every candidate θ: PRPV of the agents' replays with its order range and the paired difference to the
    lowest, and PLV of a network pre-trained on it (fitted curves) with its interval; then both picks and their
    tied sets (docs/learning.md). Work is cached in OUT, so an interrupted run resumes.
    """

    name = "plv-vs-prpv"
    defaults_of = "predictivity"
    quick_help = "the quick predictivity defaults and PLVConfig.quick()"
    out_help = "folder for choice.json/.csv/.png and the caches"
    exclude = ("search", "plan", "pod_seconds", "truth", "dtps_options")
    extra_defaults = {"sweep": "camera_pitch=12,19.15,26 (one parameter changed at a time)"}  # noqa: RUF012

    def run(self, config: ExperimentConfig, out: Path, backend: Any, progress: Progress, *,
            quick: bool = False) -> ChoiceResult:
        from proxybench.experiments.optimize.plv_search import torch_available
        from proxybench.experiments.plv_prpv.run import run_plv_prpv
        from proxybench.protocol import RobotFailure

        if not torch_available():
            raise ConfigError("PLV needs PyTorch: pip install -e '.[learning]'")
        try:
            return run_plv_prpv(config, out, quick=quick, backend=backend, progress=progress)
        except (RuntimeError, RobotFailure) as exc:
            raise ConfigError(str(exc)) from exc

    def write_report(self, result: ChoiceResult, out: Path, *, wall: float = 0.0) -> list[Path]:
        from proxybench.experiments.plv_prpv.report import write_choice

        files = write_choice(result, out, wall)
        return [files["json"], files["csv"], files["png"]]

    def example(self) -> ChoiceResult:
        """A canned result: three candidate pitches, made-up PRPV and PLV figures (nothing runs or trains)."""
        from proxybench.experiments.plv_prpv.run import Candidate, ChoiceResult

        cands = [Candidate("camera_pitch=12", {"camera_pitch": 12.0}, 14.0, 8.0, 20.0, (6.0, 1.0, 11.0), 300.0, 100.0,
                           500.0, "300 [100, 500]", 0.9, 10.0),
                 Candidate("camera_pitch=19.15", {"camera_pitch": 19.15}, 8.0, 4.0, 12.0, (0.0, 0.0, 0.0), 900.0,
                           600.0, 1200.0, "900 [600, 1,200]", 1.0, 15.0),
                 Candidate("camera_pitch=26", {"camera_pitch": 26.0}, 10.0, 6.0, 16.0, (2.0, -1.0, 5.0), None, None,
                           400.0, "not reached", 0.3, 6.0)]
        return ChoiceResult(cands, "camera_pitch=19.15", ["camera_pitch=19.15", "camera_pitch=26"],
                            "camera_pitch=19.15", ["camera_pitch=19.15"], "a canned example: made-up figures",
                            ["straight", "pid", "vision"], 3, 2, 19.0, 2000.0)

    def show(self, result: ChoiceResult, console: Any, *, wall: float = 0.0) -> None:
        from rich.markup import escape
        from rich.table import Table

        from proxybench.experiments.plv_prpv.report import table_rows

        res = result
        rows = table_rows(res)
        table = Table(title=f"predict (argmin PRPV) vs teach (argmax PLV) — {len(res.agents)} agents × "
                            f"{res.episodes} episodes; PLV over {res.plv_seeds} seeds; {wall:.0f} s")
        for col in rows[0]:
            table.add_column(escape(col), justify="left" if col == "candidate θ" else "right")
        for r in rows:
            table.add_row(*(escape(str(v)) for v in r.values()))
        console.print(f"[bold]target:[/bold] {escape(res.target)}", highlight=False)
        console.print(table)
        console.print(f"• argmin PRPV: {res.prpv_pick} (not separated from it: {', '.join(res.prpv_tied)}); argmax "
                      f"PLV: {res.plv_pick or 'none'} (intervals reaching it: {', '.join(res.plv_tied) or '–'})",
                      highlight=False, markup=False)
        console.print(f"• {res.verdict()}", highlight=False, markup=False)
