"""``proxybench optimize``, registered: the θ whose ranking of agents best matches the target's (or, with
``--objective plv``, the proxy that saves a learning agent the most target samples)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from proxybench.experiments.config import ConfigError, ExperimentConfig, ExperimentStudy
from proxybench.experiments.study import Progress, register

if TYPE_CHECKING:
    from proxybench.experiments.optimize.plv_search import PLVOptimizeResult
    from proxybench.experiments.optimize.run import OptimizeResult

__all__ = ["OptimizeStudy"]


@register
class OptimizeStudy(ExperimentStudy):
    """Find the simulator parameters θ* whose agent ranking best matches the target's (Optuna).

    The target's episodes run (or are read) once; every trial replays them in its proxy. A known truth
    (the reality model's, or --truth) is printed beside what was recovered; the search never sees it.
    With --objective plv: the proxy (θ, or with --family p(θ)) that saves a learning agent the most target
    samples, against the reality model; PLV settings in the experiment file's `plv:` (docs/learning.md).
    """

    name = "optimize"
    quick_help = "8 agents × 2 episodes × 12 s, at most 20 trials (plv: PLVConfig.quick(), 4 trials)"
    out_help = "folder for plots, trials table and episode cache"
    exclude = ("sweep", "pod_seconds", "plan")

    def run(self, config: ExperimentConfig, out: Path, backend: Any, progress: Progress, *,
            quick: bool = False) -> OptimizeResult | PLVOptimizeResult:
        out.mkdir(parents=True, exist_ok=True)
        if config.search.objective == "plv":
            from proxybench.experiments.optimize.plv_search import run_plv_search, torch_available

            if not torch_available():
                raise ConfigError("search.objective: plv trains a behaviour-cloning network and needs PyTorch, the "
                                  "'learning' extra: pip install 'proxybench[learning]'")
            return run_plv_search(config, out, progress, quick=quick)
        from proxybench.experiments.optimize.run import optimize_proxy

        def trials(done: int, total: int, _value: float) -> None:
            progress("trials", done, total)

        return optimize_proxy(config, out / "runs", backend, trials, quick=quick, target_progress=progress)

    def write_report(self, result: OptimizeResult | PLVOptimizeResult, out: Path, *, wall: float = 0.0) -> list[Path]:
        from proxybench.experiments.optimize.plv_search import PLVOptimizeResult, write_plv_search
        from proxybench.experiments.optimize.run import write_optimization

        if isinstance(result, PLVOptimizeResult):
            return write_plv_search(result, out, wall)
        return write_optimization(result, out, wall)

    def example(self) -> OptimizeResult:
        """A canned result: eight trials over trim on made-up tables, their tied set (nothing runs)."""
        import optuna

        from proxybench.experiments.examples import canned_experiment, canned_proxies, canned_target
        from proxybench.experiments.optimize.run import OptimizeResult, Trial, best_decile, tied_set
        from proxybench.tasks.metrics import METRICS
        from proxybench.usefulness.noise import noise_floor

        exp = canned_experiment()
        tgt = canned_target(exp)
        higher = tuple(METRICS[m].higher_is_better for m in exp.metrics)
        values = [round(-0.3 + 0.075 * k, 3) for k in range(9)]
        tables = canned_proxies(tgt, [f"trim={v}" for v in values])
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        study = optuna.create_study(direction="minimize")
        dist = {"trim": optuna.distributions.FloatDistribution(-0.3, 0.3)}
        trials, proxies = [], {}
        for k, v in enumerate(values):
            prpv = float(abs(v - 0.05) * 40)
            study.add_trial(optuna.trial.create_trial(params={"trim": v}, distributions=dist, value=prpv))
            trials.append(Trial(k, prpv, {"trim": v}, prpv=prpv, ppv=0.1 * prpv))
            proxies[k] = tables[f"trim={v}"]
        tied = tied_set(trials, proxies, tgt.results, higher, ["trim"], n_boot=exp.n_boot, seed=0)
        best = min(trials, key=lambda tr: tr.value)
        return OptimizeResult(dict(best.theta), best.value, {}, study, trials, best_decile(trials, ["trim"]),
                              tgt.info, exp, noise_floor(tgt.results, higher, n_boot=exp.n_boot, seed=0), 0, tied)

    def show(self, result: OptimizeResult | PLVOptimizeResult, console: Any, *, wall: float = 0.0) -> None:
        from proxybench.experiments.optimize.plv_search import PLVOptimizeResult

        if isinstance(result, PLVOptimizeResult):
            _show_plv(result, console, wall)
        else:
            _show_prpv(result, console, wall)


def _show_prpv(res: OptimizeResult, console: Any, wall: float) -> None:
    from rich.markup import escape
    from rich.table import Table

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
        console.print(f"[yellow]warning:[/yellow] {escape(warning)}", highlight=False)
    best = next(t for t in res.trials if t.value == res.best_value)
    nf = res.noise_floor
    prpv = float("nan") if best.prpv is None else best.prpv
    console.print(f"residual (best objective, the gap no θ in this family closed): {res.best_value:.4f}; its PRPV "
                  f"{prpv:.1f} against the target's noise floor "
                  f"{nf.value:.1f} [{nf.low:.1f}, {nf.high:.1f}]" if nf else "", highlight=False)


def _show_plv(res: PLVOptimizeResult, console: Any, wall: float) -> None:
    from rich.markup import escape
    from rich.table import Table

    plv_cfg = res.config
    if res.ignored:
        console.print(f"[yellow]![/yellow] not used by --objective plv (it trains its own agent on its own frames "
                      f"and episodes): {', '.join(res.ignored)}", highlight=False)
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
    best = res.best.number
    for t in sorted(res.trials, key=lambda t: -t.value):
        mark = ""
        if t.number == best and res.reached:
            mark = "best" + (", stands apart" if res.search.separated else " (not separated)")
        table.add_row(str(t.number), *(escape(res.theta_label(t, n)) for n in names), escape(t.plv_ci),
                      f"{t.reached_share:.0%}", f"{t.zero_shot:.2f}", mark)
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
        console.print(f"• best: trial {b.number} ({theta}), PLV {b.plv_ci}: its interval lies above every "
                      "other trial's", highlight=False, markup=False)
    else:
        console.print(f"• highest PLV: trial {b.number} ({theta}), PLV {b.plv_ci}; its interval overlaps "
                      "other trials': the seeds cannot tell them apart (more seeds: plv: {seeds: [...]})",
                      highlight=False, markup=False)
