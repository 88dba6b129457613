"""`proxybench results ...`: the shipped evidence — export a finished study into ``results/``, rebuild every README
number from what is shipped (docs/results.md)."""

from __future__ import annotations

from pathlib import Path

import typer

from proxybench.cli.app import app, console, fail, problem
from proxybench.cli.help import HelpTyper

results_app = HelpTyper(no_args_is_help=True, help="The shipped evidence in results/: export a finished study, "
                          "rebuild (and check) every README number from what is shipped.")
app.add_typer(results_app, name="results")

_ROOT = typer.Option(None, help="the repository root holding results/ (default: the first folder from here upwards "
                     "that has one)")


@results_app.command("export")
def results_export(
    study: Path = typer.Argument(..., help="a finished study's --out folder (validate, rank-check or plv)"),
    name: str = typer.Argument(..., help="the run's folder in results/ (e.g. validate_gym)"),
    replace: bool = typer.Option(False, help="overwrite an existing results/NAME"),
    root: Path | None = _ROOT,
    command: str | None = typer.Option(None, help="the command that ran the study, for the run's README.md"),
    commit: str | None = typer.Option(None, help="the code commit that ran it (default: criteria.json's; rank-check "
                                      "records none)"),
    machine: str | None = typer.Option(None, help="the machine it ran on, for the run's README.md"),
    note: list[str] = typer.Option([], help="a line for the run's README.md (deviations, context); repeatable"),
) -> None:
    """Copy what a reviewer needs to recompute a finished study into results/NAME/: for validate criteria.json,
    looks.jsonl, summary.json, targets.csv, targets/NNN.json; for rank-check summary.json and targets.csv; for plv
    plv.json (without its runs) and the training runs' table (runs.csv.gz); the per-episode score table
    (episodes.csv.gz) and a README.md. No caches, no trajectories. Refuses an unfinished
    study (an interim look), a failed pre-registration check, and an existing results/NAME without --replace."""
    from proxybench.experiments.evidence import EvidenceError, export_study, find_root

    try:
        done = export_study(study, name, root or find_root(), replace=replace, command=command, commit=commit,
                            machine=machine, notes=tuple(note))
    except EvidenceError as exc:
        raise fail(exc) from None
    for n in done.notes:
        problem(n, mark="note:", style="yellow")
    console.print(f"wrote {done.folder}: {len(done.files)} files, {done.size:,} bytes; next: `proxybench results "
                  "rebuild`, then tag README's quotes with <!-- n:NAME --> (docs/results.md)", highlight=False,
                  markup=False)


@results_app.command("rebuild")
def results_rebuild(
    check: bool = typer.Option(False, help="write nothing; exit 1 if a recomputed number differs from "
                               "results/numbers.json or from the figure README.md tags with it"),
    root: Path | None = _ROOT,
) -> None:
    """Recompute every number of every run in results/ through its study's own summary code, check the shipped files
    against their recomputation, and write results/numbers.json (name → value and source file)."""
    from proxybench.experiments.evidence import EvidenceError, find_root, write_numbers
    from proxybench.experiments.evidence import check as check_numbers

    try:
        where = root or find_root()
        got, problems = check_numbers(where)
    except EvidenceError as exc:
        raise fail(exc) from None
    if check:
        for p in problems:
            problem(p)
        if problems:
            raise typer.Exit(1)
        console.print(f"results/numbers.json and README.md agree with the {len(got.numbers)} numbers recomputed from "
                      f"{where / 'results'}", highlight=False, markup=False)
        return
    path = write_numbers(where, got.numbers)
    for p in got.problems:
        problem(p)
    readme = [p for p in problems if p.startswith("README.md")]
    for p in readme:
        problem(p)
    console.print(f"wrote {path}: {len(got.numbers)} numbers", highlight=False, markup=False)
    if got.problems or readme:
        raise typer.Exit(1)


@results_app.command("plan-episodes")
def results_plan_episodes(
    study: Path = typer.Argument(..., help="a validation study with its per-episode table (results/NAME, as "
                                 "exported)"),
    out: Path | None = typer.Option(None, help="where episode_plan.json and .csv go (default: the study's folder)"),
    p_correct: float = typer.Option(0.8, min=0.05, max=0.99, help="goal: the chance PRPV picks the world's best "
                                    "grid candidate"),
    width: float = typer.Option(0.05, min=0.0, help="goal: the mean width of PRPV's order range, in PRPV/K(K−1)"),
    reps: int = typer.Option(100, min=20, help="posterior worlds per planned n"),
    targets: int | None = typer.Option(None, min=1, help="plan only the first N targets"),
    seed: int = typer.Option(0, min=0),
) -> None:
    """How many target episodes per agent the study needed: `plan` on each target's own episodes and the grid's
    replays of them (no episode runs). Sizes E1/E2 of the next study (docs/validate.md, "Choosing E1 and E2")."""
    from proxybench.cli.progress import stage_bars, stage_progress
    from proxybench.experiments.config import ConfigError
    from proxybench.experiments.validate.episode_plan import plan_study, write_episode_plan

    try:
        with stage_bars() as bar:
            res = plan_study(study, p_correct=p_correct, width=width, reps=reps, seed=seed, targets=targets,
                             progress=stage_progress(bar))
    except ConfigError as exc:
        raise fail(exc) from None
    files = write_episode_plan(res, out or study)
    def n(v: float | None) -> str:
        return "beyond 320" if v is None else f"{v:g}"

    lo, hi = res.quartiles_n_for_p_correct
    console.print(
        f"{res.study}: {len(res.targets)} targets, {res.episodes_tune} + {res.episodes_eval} episodes per agent. With "
        f"the study's episodes PRPV picks the world's best of the grid with median chance "
        f"{res.median_p_correct_at_pilot:.2f} over targets; a chance of {res.p_correct_goal:g} needs a median "
        f"{n(res.median_n_for_p_correct)} episodes per agent (quartiles {n(lo)}, {n(hi)}); PRPV's order range is "
        f"{res.median_width_at_pilot:.3f} wide (median, PRPV/K(K−1)), ≤ {res.width_goal:g} needs "
        f"{n(res.median_n_for_width)}. Wrote {', '.join(str(f) for f in files)}", highlight=False, markup=False)
