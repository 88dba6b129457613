"""`proxybench predictivity` and `proxybench optimize`: how well simulators predict a target, and the best θ.

Both take the experiment's options, generated from :class:`~proxybench.experiments.config.ExperimentConfig`
(``--config FILE`` for all of them at once; a command-line option beats the file, the file beats the
command's default), and any target: ``--target reality`` (default), ``--target DIR`` (a recorded target)
or ``--target "robot:CMD"`` (a robot node).
"""

from __future__ import annotations

import time
from pathlib import Path

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
from rich.table import Table

from proxybench.cli.app import app, console, err_console
from proxybench.cli.config_options import fail, study_options
from proxybench.cli.progress import progress_bar, stage_bars, stage_progress
from proxybench.cli.studies import BackendOption, WorkersOption, run_study
from proxybench.experiments.config import ExperimentConfig, default_help, load_config

OUT_HELP = "report folder (figures, tables, report.html) and episode cache (OUT/runs)"


def experiment_options(command: str, exclude: tuple[str, ...], defaults: dict[str, str] | None = None):
    """The options of :class:`ExperimentConfig` for ``command`` (its defaults worded as it settles them, or as
    ``defaults`` says)."""
    return study_options(ExperimentConfig, load=lambda path, over, _own: load_config(path, over), exclude=exclude,
                         defaults=default_help(command) | (defaults or {}),
                         config_help="experiment file (YAML; every field: docs/targets.md)")


@app.command()
@experiment_options("predictivity", exclude=("search", "plan", "plv"))
def predictivity(
    cfg: ExperimentConfig,
    quick: bool = typer.Option(False, "--quick", help="12 agents × 3 episodes × 20 s (a minute or two)"),
    out: Path = typer.Option(Path("out/predictivity"), help=OUT_HELP),
    backend: BackendOption = "local",
    workers: WorkersOption = None,
) -> None:
    """Rank agents on a target and on swept simulator instances; PRPV, PPV, SRCC, POD beside the target's noise floor.

    Proxies replay each target episode from its start pose and seed. Episodes are cached in OUT/runs, so
    an interrupted run resumes where it stopped; a recorded target costs no simulation.
    """
    from proxybench.experiments.predictivity.report import findings, write_report
    from proxybench.experiments.predictivity.run import run_predictivity

    t0 = time.perf_counter()
    res = run_study(backend, workers, lambda be, progress: run_predictivity(cfg, out / "runs", be, progress,
                                                                            quick=quick))
    wall = time.perf_counter() - t0
    files = write_report(res, out, wall)
    console.print(f"[bold]target:[/bold] {res.target.info.statement}", highlight=False)
    _print_table(res, wall)
    for line in findings(res):
        console.print(f"• {line}", highlight=False, markup=False)
    console.print(f"wrote {files['html']}, {files['fig3_3']}, {files['fig3_4']} (+ .svg), {files['csv']}",
                  highlight=False)


@app.command("score-proxy")
@experiment_options("predictivity", exclude=("search", "plan", "sweep", "pod_seconds"))
def score_proxy(
    cfg: ExperimentConfig,
    param: list[str] = typer.Option([], "--param", metavar="NAME=VALUE",
                                    help="the θ to score, on top of the nominal calibration (repeat for more "
                                         "parameters; names: proxybench params)"),
    vs_param: list[str] = typer.Option([], "--vs-param", metavar="NAME=VALUE",
                                       help="the θ to compare it with on the same episodes (default: the nominal "
                                            "calibration, i.e. changing nothing)"),
    quick: bool = typer.Option(False, "--quick", help="the live target's quick episodes (12 agents × 3 × 20 s)"),
    out: Path = typer.Option(Path("out/score"), help="score.json and the episode cache (OUT/runs)"),
    backend: BackendOption = "local",
    workers: WorkersOption = None,
) -> None:
    """Score one θ against a target (PRPV, PPV, SRCC with intervals) and compare it with another θ, paired.

    Both θ replay the same target episodes, so ΔPRPV has a paired interval; the nominal calibration, the
    no-simulator baselines and the target's noise floor are shown beside them. Split a recording with
    --episodes (e.g. fit θ with `optimize --episodes 0-4`, score it here with --episodes 5-9).
    """
    import json

    from proxybench.cli.config_options import key_values
    from proxybench.experiments.score.run import score_proxy as run_score

    theta, versus = key_values(param, "--param"), key_values(vs_param, "--vs-param")
    t0 = time.perf_counter()
    res = run_study(backend, workers, lambda be, progress: run_score(cfg, theta, out / "runs", versus=versus,
                                                                     backend=be, progress=progress, quick=quick))
    wall = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    (out / "score.json").write_text(json.dumps(res.to_dict(), indent=1, default=float))
    console.print(f"[bold]target:[/bold] {escape(res.target.info.statement)}", highlight=False)
    exp = res.experiment
    table = Table(title=escape(f"θ against the target: {len(exp.agents)} agents × {exp.episode_count} episodes × "
                               f"{exp.seconds:g} s; 95 % intervals; {wall:.0f} s"))
    for col in ("θ", "PRPV [order range]", "PPV (mean/agent)", "Pearson r", "Spearman ρ", "Kendall τ"):
        table.add_column(escape(col), justify="left" if col == "θ" else "right")
    rows = [(res.scored.label, res.scored.figures), (res.versus.label, res.versus.figures),
            *((k, u) for k, u in res.baselines.items() if k not in (res.scored.label, res.versus.label))]
    for label, u in rows:
        table.add_row(escape(label), _ci(u["prpv"], ".1f"), _ci(u["ppv"], ".2f"),
                      *(f"{u[k].value:.2f}" for k in ("pearson", "spearman", "kendall")))
    table.add_row("target noise floor", _ci(res.noise, ".1f"), "", "", "", "")
    console.print(table)
    for c in (res.comparison, res.versus_nominal):
        if c is None:
            continue
        d = c.delta
        verdict = (f"{c.a} orders the agents more like the target" if c.a_lower else
                   f"{c.b} orders the agents more like the target" if c.separated else
                   "the episodes cannot tell them apart (the interval holds 0)")
        console.print(f"• ΔPRPV ({c.a}) − ({c.b}) = {d.value:+.1f} [{d.low:+.1f}, {d.high:+.1f}] (paired, "
                      f"{exp.episode_count} episodes per agent): {verdict}", highlight=False, markup=False)
    console.print(f"wrote {out / 'score.json'}", highlight=False, markup=False)


def _ci(e, fmt: str) -> str:
    """``value [low, high]`` as a table cell (no brackets where the interval is undefined)."""
    import math

    if not (math.isfinite(e.low) and math.isfinite(e.high)):
        return f"{e.value:{fmt}}"
    return escape(f"{e.value:{fmt}} [{e.low:{fmt}}, {e.high:{fmt}}]")


def _print_table(res, wall: float) -> None:
    import numpy as np

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


@app.command()
@experiment_options("optimize", exclude=("sweep", "pod_seconds", "plan"))
def optimize(
    cfg: ExperimentConfig,
    quick: bool = typer.Option(False, "--quick", help="8 agents × 2 episodes × 12 s, at most 20 trials (plv: "
                               "PLVConfig.quick(), 4 trials)"),
    out: Path = typer.Option(Path("out/optimize"), help="folder for plots, trials table and episode cache"),
    backend: BackendOption = "local",
    workers: WorkersOption = None,
) -> None:
    """Find the simulator parameters θ* whose agent ranking best matches the target's (Optuna).

    The target's episodes run (or are read) once; every trial replays them in its proxy. A known truth
    (the reality model's, or --truth) is printed beside what was recovered; the search never sees it.
    With --objective plv: the proxy (θ, or with --family p(θ)) that saves a learning agent the most target
    samples, against the reality model; PLV settings in the experiment file's `plv:` (docs/learning.md).
    """
    from proxybench.experiments.optimize.run import optimize_proxy, write_optimization
    from proxybench.runner.backends import make_backend
    from proxybench.targets.manifest import TargetError

    if cfg.search.objective == "plv":
        _optimize_plv(cfg, out, quick)
        return
    be = make_backend(backend, workers)
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    with progress_bar(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("best {task.fields[best]}"), TimeRemainingColumn(), console=console,
                      transient=True) as bar:
        task = bar.add_task("trials", total=None, best="–")
        stages: dict[str, int] = {}
        best = [float("inf")]

        def on_target(stage: str, done: int, total: int) -> None:
            if stage not in stages:
                stages[stage] = bar.add_task(stage, total=total, best="")
            bar.update(stages[stage], completed=done, total=total)

        def progress(done: int, total: int, value: float) -> None:
            best[0] = min(best[0], value)
            bar.update(task, completed=done, total=total, best=f"{best[0]:.4f}")

        try:
            res = optimize_proxy(cfg, out / "runs", be, progress, quick=quick, target_progress=on_target)
        except (TargetError, ValueError) as exc:
            fail(exc)
        finally:
            be.close()
    wall = time.perf_counter() - t0
    paths = write_optimization(res, out, wall)
    exp = res.experiment
    assert exp is not None and res.target is not None
    console.print(f"[bold]target:[/bold] {res.target.statement}", highlight=False)
    table = Table(title=f"proxy optimisation: {len(res.trials)} trials, objective {exp.search.objective}, "
                        f"{len(exp.agents)} agents × {exp.episode_count} episodes × {exp.seconds:g} s, {wall:.0f} s "
                        f"(target: {res.target.label})")
    tied = res.tied
    recovered = "recovered (best decile)" if tied is None else f"recovered (median of {len(tied.trials)} tied)"
    for col in ("parameter", "searched", recovered, "tied set [min, max]", "known truth", "error", "single best trial"):
        table.add_column(escape(col), justify="left" if col == "parameter" else "right")  # "[…]" is not markup
    for name, v in res.recovered.items():
        t = res.truth.get(name)
        lo, hi = exp.search.space[name]
        span = "–" if tied is None else f"[{tied.spread[name][1]:.3f}, {tied.spread[name][2]:.3f}]"
        table.add_row(name, f"[{lo:g}, {hi:g}]", f"{v:.3f}", span, "–" if t is None else f"{t:g}",
                      "–" if t is None else f"{v - t:+.3f}", f"{res.best_params[name]:.3f}")
    console.print(table)
    warning = tied.warning() if tied is not None else None
    if warning:
        err_console.print(f"[yellow]warning:[/yellow] {escape(warning)}", highlight=False)
    best = next(t for t in res.trials if t["value"] == res.best_value)
    nf = res.noise_floor
    console.print(f"residual (best objective, the gap no θ in this family closed): {res.best_value:.4f}; its PRPV "
                  f"{best.get('prpv', float('nan')):.1f} against the target's noise floor "
                  f"{nf.value:.1f} [{nf.low:.1f}, {nf.high:.1f}]" if nf else "", highlight=False)
    console.print(f"wrote {', '.join(str(p) for p in paths)}", highlight=False)


def _optimize_plv(cfg: ExperimentConfig, out: Path, quick: bool) -> None:
    """`optimize --objective plv`: argmax PLV over the search space, its table, plot, trials and summary."""
    from proxybench.experiments.config import ConfigError
    from proxybench.experiments.optimize.plv_search import plv_search_settings, run_plv_search, torch_available
    from proxybench.experiments.optimize.plv_search import write_plv_search as write

    if not torch_available():
        err_console.print("[red]✗[/red] --objective plv trains a behaviour-cloning network and needs PyTorch, the "
                          "'learning' extra: pip install 'proxybench\\[learning]'", highlight=False)
        raise typer.Exit(2)
    try:
        plv_cfg, _search, ignored = plv_search_settings(cfg, quick=quick)
    except ConfigError as exc:
        fail(exc)
    if ignored:
        err_console.print(f"[yellow]![/yellow] not used by --objective plv (it trains its own agent on its own frames "
                          f"and episodes): {', '.join(ignored)}", highlight=False)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with stage_bars() as bar:
        try:
            res = run_plv_search(cfg, out, stage_progress(bar), quick=quick)
        except (ConfigError, ValueError) as exc:
            fail(exc)
    wall = time.perf_counter() - t0
    paths = write(res, out, wall)
    console.print("[bold]target:[/bold] the reality model, a SIMULATED stand-in for a real Duckiebot (PLV needs target "
                  "samples and evaluation episodes in the target as the agent trains)", highlight=False)
    what = "families p(θ)" if res.family else "instances θ"
    need = "not reached" if res.target_cost is None else f"{res.target_cost:,.0f}"
    table = Table(title=escape(f"argmax PLV over {what}: {len(res.trials)} trials; {len(plv_cfg.seeds)} seeds, "
                               f"95 % bootstrap intervals over seeds; P = {res.reference:.2f} (expert "
                               f"{res.expert:.2f}), |D_target| = {need} target samples; {wall:.0f} s"))
    names = list(res.space)
    for col in ("trial", *names, "PLV [95% CI]", "settled (share of replicates)", "zero-shot score", ""):
        table.add_column(escape(col), justify="left" if col == "trial" else "right")
    best = res.best["number"]
    for t in sorted(res.trials, key=lambda t: -t["value"]):
        mark = ""
        if t["number"] == best and res.reached:
            mark = "best" + (", stands apart" if res.search.separated else " (not separated)")
        table.add_row(str(t["number"]), *(escape(res.theta_label(t, n)) for n in names), escape(str(t["plv_ci"])),
                      f"{t['reached_share']:.0%}", f"{t['zero_shot']:.2f}", mark)
    console.print(table)
    for name, v in res.truth.items():
        console.print(f"• {name}: the target's known value {v:g} (not used by the search)", highlight=False,
                      markup=False)
    b = res.best
    theta = ", ".join(f"{n} {res.theta_label(b, n)}" for n in names)
    if not res.reached:
        console.print(f"• no proxy tried let the agent settle above P within the ladder (largest rung "
                      f"{plv_cfg.ladder[-1]:,}): PLV not reached for all {len(res.trials)} trials", highlight=False,
                      markup=False)
    elif res.search.separated:
        console.print(f"• best: trial {b['number']} ({theta}), PLV {b['plv_ci']}: its interval lies above every "
                      "other trial's", highlight=False, markup=False)
    else:
        console.print(f"• highest PLV: trial {b['number']} ({theta}), PLV {b['plv_ci']}; its interval overlaps "
                      "other trials': the seeds cannot tell them apart (more seeds: plv: {seeds: [...]})",
                      highlight=False, markup=False)
    console.print(f"wrote {', '.join(str(p) for p in paths)} (+ .svg)", highlight=False, markup=False)
