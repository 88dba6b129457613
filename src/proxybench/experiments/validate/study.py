"""``proxybench validate``, registered: does tuning a simulator help, on agents and target episodes it was not tuned
on? (docs/validate.md)"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from proxybench.experiments.study import Progress, Study, register
from proxybench.experiments.validate.config import ValidateConfig

if TYPE_CHECKING:
    from proxybench.experiments.validate.own_target import OwnTargetResult
    from proxybench.experiments.validate.run import ValidationResult

__all__ = ["ValidateStudy"]


@register
class ValidateStudy(Study[ValidateConfig, "ValidationResult | OwnTargetResult"]):
    """Run the validation study (docs/validate.md): per target, choose θ with one half of the agents on some
    target episodes, judge the choice on the other half on fresh episodes, against the nominal θ and the
    oracle θ. criteria.json is written before the first episode and never rewritten (other settings on the
    folder are refused); every finished target and every look is logged in the hash-chained looks.jsonl, which
    each report checks (a failed check: the report says so first, and the command exits 1); every episode is
    cached, so an interrupted study resumes. Writes report.html, summary.json, targets.csv and figures to
    --out."""

    name = "validate"
    config = ValidateConfig
    quick_help = "3 targets, 8 agents, 2 + 2 episodes of 6 s, a 3×3 grid"
    out_help = "folder for criteria.json, the runs and the report"

    def help_defaults(self) -> dict[str, str]:
        from proxybench.experiments.study import mode_defaults
        from proxybench.experiments.validate.config import FAMILIES

        modes = FAMILIES["heldout"]
        words = mode_defaults(modes.full.model_dump(), modes.quick.model_dump())
        return {k: f"the family's: {v}" for k, v in words.items() if k in ValidateConfig.model_fields} | {
            "agents": f"the family's: {len(modes.full.agents)} agents; --quick {len(modes.quick.agents)}",
            "tolerances": "AIDO's, scaled to the episode length"}

    def run(self, config: ValidateConfig, out: Path, backend: Any, progress: Progress, *,
            quick: bool = False) -> ValidationResult | OwnTargetResult:
        if config.target:  # the design on the user's own target (own_target.py)
            from proxybench.experiments.validate.own_target import run_own_target

            return run_own_target(config, out, backend, progress, quick=quick)
        from proxybench.experiments.validate.registration import append_look
        from proxybench.experiments.validate.run import ValidationResult, run_validate, summarize

        run = run_validate(config, out, backend, progress, quick=quick, finished_only=config.interim)
        summary = summarize(run)
        return ValidationResult(run, summary, append_look(Path(out), summary))

    def write_report(self, result: ValidationResult | OwnTargetResult, out: Path, *, wall: float = 0.0) -> list[Path]:
        from proxybench.experiments.validate.own_target import OwnTargetResult, write_own_target_report

        if isinstance(result, OwnTargetResult):
            return write_own_target_report(result, out, wall=wall)
        from proxybench.experiments.validate.report import write_validation_report

        summary = result.summary.model_copy(update={"wall_s": round(wall, 1)})
        return list(write_validation_report(result.run, summary, out).values())

    def example(self) -> ValidationResult:
        """Two targets, two candidates each (the nominal θ and trim 0.2), every method picking, no episode run."""
        from proxybench.experiments.validate.config import settings_for
        from proxybench.experiments.validate.measures import Pick, Quality, TargetRecord
        from proxybench.experiments.validate.registration import scoring_hash
        from proxybench.experiments.validate.run import ValidationResult, ValidationRun, summarize

        s = settings_for(ValidateConfig(methods=("prpv", "kendall", "nominal")), True)
        cands = [{"trim": 0.0, "camera_pitch": 19.15}, {"trim": 0.2, "camera_pitch": 19.15}]
        records = [TargetRecord(candidates=cands, nominal_index=0, quality=[
            Quality(prpv_norm=0.3 + 0.1 * k, kendall_gap=0.2, top1_regret=0.1, topk_regret=0.0),
            Quality(prpv_norm=0.1, kendall_gap=0.1, top1_regret=0.0, topk_regret=0.0)],
            picks={"prpv": Pick(index=1, ties=1), "kendall": Pick(index=k, ties=1), "nominal": Pick(index=0, ties=1)},
            scores={}, target=f"target-{k}", map="loop_3x3") for k in range(2)]
        criteria = {"written": "2026-01-01 00:00:00 +0000", "commit": "example", "scoring_sha256": scoring_hash(),
                    "minimum_detectable_effect": {"d_z": 2.0, "targets": 2, "power": 0.8}}
        run = ValidationRun(s, Path("criteria.json"), records, [None, None], 0, 0.0)
        return ValidationResult(run, summarize(run, criteria))

    def show(self, result: ValidationResult | OwnTargetResult, console: Any, *, wall: float = 0.0) -> None:
        from proxybench.experiments.validate.own_target import OwnTargetResult, show_own_target

        if isinstance(result, OwnTargetResult):
            show_own_target(result, console, wall=wall)
            return
        from proxybench.experiments.validate.report import answer, secondary_lines

        for note in result.run.notes:
            console.print(note, highlight=False, markup=False)
        console.print(answer(result.summary), highlight=False, markup=False)
        for line in secondary_lines(result.summary):
            console.print(line, highlight=False, markup=False)
        console.print(f"{result.run.episodes_run} episodes run now; wall {wall:.0f} s", highlight=False, markup=False)
        if result.look_sha256:
            console.print(f"this look is line sha256 {result.look_sha256} of looks.jsonl", highlight=False,
                          markup=False)
        problems = result.summary.criteria.problems
        for p in problems:
            console.print(f"PRE-REGISTRATION CHECK FAILED: {p}", style="bold red", highlight=False, markup=False)
        if problems:
            raise SystemExit(1)  # the report is written, and says so first
