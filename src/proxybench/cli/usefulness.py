"""`proxybench predictivity` and `proxybench optimize`: how well simulators predict a target, and the best θ.

Both take the same experiment options (``--config FILE`` for all of them at once; a command-line option
beats the file, the file beats the command's default) and any target: ``--target reality`` (default),
``--target DIR`` (a recorded target) or ``--target "robot:CMD"`` (a robot node).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
from rich.table import Table

from proxybench.cli.app import app, console, err_console
from proxybench.cli.node_options import (
    RobotCwd,
    RobotNoReflection,
    RobotStartTimeout,
    RobotStepTimeout,
    RobotTransport,
    robot_option_values,
)
from proxybench.cli.options import non_negative, positive
from proxybench.cli.progress import progress_bar

_TARGET_HELP = "reality (the simulated reality model) | DIR (recorded target) | robot:CMD (a robot node)"
_AGENT_HELP = ("zoo name, NAME=COMMAND (node), NAME=sdk:COMMAND (duckietown-sdk program), checkpoint X.pt, or agent "
               "package .zip/.tar.gz (repeat)")


def _kv(items: list[str], option: str) -> dict[str, Any]:
    """``k=v`` items, values read as YAML (numbers, booleans, lists)."""
    import yaml

    out = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise typer.BadParameter(f"{item!r} is not NAME=VALUE", param_hint=option)
        out[key.strip()] = yaml.safe_load(raw)
    return out


def _sweep(items: list[str]) -> dict[str, list[float]]:
    out = {}
    for item in items:
        name, sep, raw = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[name.strip()] = [float(v) for v in raw.split(",") if v.strip()]
        except ValueError:
            raise typer.BadParameter(f"{item!r}: expected NAME=V1,V2,…, e.g. trim=-0.2,0,0.2",
                                     param_hint="--sweep") from None
    return out


def _space(items: list[str]) -> dict[str, tuple[float, float]]:
    space = {}
    for item in items:
        try:
            name, rng = item.split("=", 1)
            lo, hi = (float(v) for v in rng.split(":"))
        except ValueError as exc:
            raise typer.BadParameter(f"{item!r}: expected NAME=LOW:HIGH, e.g. trim=-0.3:0.3",
                                     param_hint="--param") from exc
        space[name.strip()] = (lo, hi)
    return space


def _image_size(text: str | None) -> list[int] | None:
    if text is None:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise typer.BadParameter(f"{text!r}: expected WIDTHxHEIGHT, e.g. 160x120", param_hint="--image-size") from None
    return [w, h]


def _overrides(**given: Any) -> dict[str, Any]:
    """The options given on the command line (None and empty lists: not given)."""
    return {k: v for k, v in given.items() if v is not None and v != [] and v != {}}


def _load(config: Path | None, overrides: dict[str, Any]):
    from proxybench.experiments.config import ConfigError, load_config

    try:
        return load_config(config, overrides)
    except ConfigError as exc:
        _fail(exc)


def _fail(exc: Exception) -> None:
    from rich.markup import escape

    for line in str(exc).splitlines():
        err_console.print(f"[red]✗[/red] {escape(line)}", highlight=False)
    raise typer.Exit(2)


def _bars():
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
    return progress_bar(*columns, console=console, transient=True)


def _stage_progress(bar):
    tasks: dict[str, int] = {}

    def progress(stage: str, done: int, total: int) -> None:
        if stage not in tasks:
            tasks[stage] = bar.add_task(stage, total=total)
        bar.update(tasks[stage], completed=done, total=total)

    return progress


@app.command()
def predictivity(
    quick: bool = typer.Option(False, "--quick", help="12 agents × 3 episodes × 20 s (a minute or two)"),
    config: Path | None = typer.Option(None, "--config", help="experiment file (YAML; see docs/targets.md)"),
    target: str | None = typer.Option(None, help=f"{_TARGET_HELP} (default: reality)"),
    target_param: list[str] = typer.Option([], "--target-param", help="reality model θ, k=v (repeat)"),
    robot_nodes: int | None = typer.Option(None, min=1, help="robot node processes at once (default: 1)"),
    robot_cwd: RobotCwd = None,
    robot_transport: RobotTransport = None,
    robot_start_timeout: RobotStartTimeout = None,
    robot_step_timeout: RobotStepTimeout = None,
    robot_no_reflection: RobotNoReflection = False,
    agent: list[str] = typer.Option([], "--agent", help=f"{_AGENT_HELP} (default: the target's, else the zoo set)"),
    map_name: str | None = typer.Option(None, "--map", help="map (default: the target's, else loop_3x3)"),
    episodes: int | None = typer.Option(None, min=1, help="episodes per agent (default: 10; --quick 3)"),
    seconds: float | None = typer.Option(None, callback=positive, help="episode length in s (default: 60; --quick 20)"),
    metric: list[str] = typer.Option([], "--metric", help="task metric (repeat) (default: driven_lanedir_consec, "
                                     "survival_time)"),
    image_size: str | None = typer.Option(None, help="camera WIDTHxHEIGHT (default: 160x120)"),
    proxy_param: list[str] = typer.Option([], "--proxy-param", help="θ every proxy has, k=v (repeat)"),
    sweep: list[str] = typer.Option([], "--sweep", help="NAME=V1,V2,… (repeat) (default: trim ±0.3 in 7 steps, "
                                    "delay, blur, pitch around the nominal calibration)"),
    n_boot: int | None = typer.Option(None, min=10, help="bootstrap resamples (default: 300; --quick 100)"),
    pod_seconds: float | None = typer.Option(None, callback=non_negative,
                                             help="POD rollout in s, 0: none (default: 10; --quick 4)"),
    seed: int | None = typer.Option(None, min=0, help="experiment seed (default: 0)"),
    truth: list[str] = typer.Option([], "--truth", help="target's known θ k=v, only marked on plots (repeat)"),
    out: Path = typer.Option(Path("out/predictivity"), help="report folder (figures, tables, report.html)"),
    backend: str = typer.Option("local", help="inline | local (process pool) | ray"),
    workers: int | None = typer.Option(None, min=1, help="parallel workers (default: one per core)"),
) -> None:
    """Rank agents on a target and on swept simulator instances; PRPV, PPV, SRCC, POD beside the target's noise floor.

    Proxies replay each target episode from its start pose and seed. Episodes are cached in OUT/runs, so
    an interrupted run resumes where it stopped; a recorded target costs no simulation.
    """
    from proxybench.experiments.predictivity import run_predictivity
    from proxybench.experiments.reports.predictivity import findings, write_report
    from proxybench.runner.backends import make_backend
    from proxybench.targets.manifest import TargetError

    over = _overrides(target=target, target_params=_kv(target_param, "--target-param"), robot_nodes=robot_nodes,
                      robot_options=robot_option_values(robot_cwd, robot_transport, robot_start_timeout,
                                                        robot_step_timeout, robot_no_reflection),
                      agents=agent, map=map_name,
                      episodes=episodes, seconds=seconds, metrics=metric, image_size=_image_size(image_size),
                      proxy=_kv(proxy_param, "--proxy-param"), sweep=_sweep(sweep), n_boot=n_boot,
                      pod_seconds=pod_seconds, seed=seed, truth=_kv(truth, "--truth"))
    cfg = _load(config, over)
    be = make_backend(backend, workers)
    t0 = time.perf_counter()
    with _bars() as bar:
        try:
            res = run_predictivity(cfg, out / "runs", be, _stage_progress(bar), quick=quick)
        except (TargetError, ValueError) as exc:
            _fail(exc)
        finally:
            be.close()
    wall = time.perf_counter() - t0
    files = write_report(res, out, wall)
    console.print(f"[bold]target:[/bold] {res.target.info.statement}", highlight=False)
    _print_table(res, wall)
    for line in findings(res):
        console.print(f"• {line}", highlight=False, markup=False)
    console.print(f"wrote {files['html']}, {files['fig3_3']}, {files['fig3_4']} (+ .svg), {files['csv']}",
                  highlight=False)


def _print_table(res, wall: float) -> None:
    import numpy as np

    exp = res.experiment
    title = (f"usefulness of proxy instances — target: {res.target.info.label}; {len(exp.agents)} agents × "
             f"{exp.episodes} episodes × {exp.seconds:g} s; {wall:.0f} s")
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
def optimize(
    quick: bool = typer.Option(False, "--quick", help="8 agents × 2 episodes × 12 s, at most 20 trials (plv: "
                               "PLVConfig.quick(), 4 trials)"),
    config: Path | None = typer.Option(None, "--config", help="experiment file (YAML; see docs/targets.md)"),
    target: str | None = typer.Option(None, help=f"{_TARGET_HELP} (default: reality)"),
    target_param: list[str] = typer.Option([], "--target-param", help="reality model θ, k=v (repeat)"),
    robot_nodes: int | None = typer.Option(None, min=1, help="robot node processes at once (default: 1)"),
    robot_cwd: RobotCwd = None,
    robot_transport: RobotTransport = None,
    robot_start_timeout: RobotStartTimeout = None,
    robot_step_timeout: RobotStepTimeout = None,
    robot_no_reflection: RobotNoReflection = False,
    agent: list[str] = typer.Option([], "--agent", help=f"{_AGENT_HELP} (default: the target's, else 12 zoo agents)"),
    map_name: str | None = typer.Option(None, "--map", help="map (default: the target's, else loop_3x3)"),
    episodes: int | None = typer.Option(None, min=1, help="episodes per agent (default: 4; --quick 2)"),
    seconds: float | None = typer.Option(None, callback=positive, help="episode length in s (default: 20; --quick 12)"),
    metric: list[str] = typer.Option([], "--metric", help="task metric (repeat) (default: driven_lanedir_consec, "
                                     "survival_time)"),
    image_size: str | None = typer.Option(None, help="camera WIDTHxHEIGHT (default: 160x120)"),
    proxy_param: list[str] = typer.Option([], "--proxy-param", help="θ every proxy has, k=v (repeat)"),
    param: list[str] = typer.Option([], "--param", help="a parameter to search, NAME=LOW:HIGH (repeat) "
                                    "(default: trim=-0.3:0.3, camera_pitch=12:26)"),
    objective: str | None = typer.Option(None, help="prpv (the thesis' θ* = argmin PRPV) | ppv | mix "
                                         "(PRPV/K(K−1) + PPV/m) | plv (argmax PLV, eq. 3.6.2: trains a "
                                         "behaviour-cloning agent per trial; needs the learning extra) "
                                         "(default: prpv)"),
    family: bool = typer.Option(False, "--family", help="objective plv: search families p(θ) (a uniform range "
                                "per parameter) instead of instances θ"),
    trials: int | None = typer.Option(None, min=1, help="(default: 60; --quick 20; plv: 12, --quick 4)"),
    sampler: str | None = typer.Option(None, help="tpe | gp | random (default: tpe)"),
    storage: str | None = typer.Option(None, help="SQLite file or SQLAlchemy URL (PostgreSQL to share a study)"),
    study_name: str | None = typer.Option(None, help="(default: proxybench-proxy)"),
    n_boot: int | None = typer.Option(None, min=10, help="resamples for the noise floor (default: 300)"),
    seed: int | None = typer.Option(None, min=0, help="experiment and sampler seed (default: 0)"),
    truth: list[str] = typer.Option([], "--truth", help="target's known θ k=v, printed beside the result only"),
    out: Path = typer.Option(Path("out/optimize"), help="folder for plots, trials table and episode cache"),
    backend: str = typer.Option("local", help="inline | local | ray"),
    workers: int | None = typer.Option(None, min=1),
) -> None:
    """Find the simulator parameters θ* whose agent ranking best matches the target's (Optuna).

    The target's episodes run (or are read) once; every trial replays them in its proxy. A known truth
    (the reality model's, or --truth) is printed beside what was recovered; the search never sees it.
    With --objective plv: the proxy (θ, or with --family p(θ)) that saves a learning agent the most target
    samples, against the reality model; PLV settings in the experiment file's `plv:` (docs/learning.md).
    """
    import json

    from proxybench.experiments.optimize import optimize_proxy, plot_optimization
    from proxybench.runner.backends import make_backend
    from proxybench.targets.manifest import TargetError

    search = _overrides(space=_space(param) or None, objective=objective, trials=trials, sampler=sampler,
                        storage=storage, study_name=study_name, family=family or None)
    over = _overrides(target=target, target_params=_kv(target_param, "--target-param"), robot_nodes=robot_nodes,
                      robot_options=robot_option_values(robot_cwd, robot_transport, robot_start_timeout,
                                                        robot_step_timeout, robot_no_reflection),
                      agents=agent, map=map_name,
                      episodes=episodes, seconds=seconds, metrics=metric, image_size=_image_size(image_size),
                      proxy=_kv(proxy_param, "--proxy-param"), search=search or None, n_boot=n_boot, seed=seed,
                      truth=_kv(truth, "--truth"))
    cfg = _load(config, over)
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
            _fail(exc)
        finally:
            be.close()
    wall = time.perf_counter() - t0
    paths = plot_optimization(res, out)
    summary = {"target": res.target.statement if res.target else None, "recovered": res.recovered,
               "best_params": res.best_params, "best_value": res.best_value, "truth": res.truth,
               "noise_floor_prpv": [res.noise_floor.value, res.noise_floor.low, res.noise_floor.high]
               if res.noise_floor else None, "wall_s": round(wall, 1),
               "tied": None if res.tied is None else {"trials": list(res.tied.trials), "separated": res.tied.separated,
                                                      "spread": {k: dict(zip(("median", "min", "max"), v, strict=True))
                                                                 for k, v in res.tied.spread.items()}},
               "experiment": res.experiment.to_dict() if res.experiment else None}
    (out / "trials.json").write_text(json.dumps(res.trials, indent=1))
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    exp = res.experiment
    assert exp is not None and res.target is not None
    console.print(f"[bold]target:[/bold] {res.target.statement}", highlight=False)
    table = Table(title=f"proxy optimisation: {len(res.trials)} trials, objective {exp.search.objective}, "
                        f"{len(exp.agents)} agents × {exp.episodes} episodes × {exp.seconds:g} s, {wall:.0f} s "
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
    console.print(f"wrote {', '.join(str(p) for p in paths)}, {out / 'trials.json'}, {out / 'summary.json'}",
                  highlight=False)


def _optimize_plv(cfg, out: Path, quick: bool) -> None:
    """`optimize --objective plv`: argmax PLV over the search space, its table, plot, trials and summary."""
    import json

    from proxybench.experiments.config import ConfigError
    from proxybench.experiments.optimize_plv import (
        plot_plv_search,
        plv_search_settings,
        run_plv_search,
        torch_available,
    )

    if not torch_available():
        err_console.print("[red]✗[/red] --objective plv trains a behaviour-cloning network and needs PyTorch, the "
                          "'learning' extra: pip install 'proxybench\\[learning]'", highlight=False)
        raise typer.Exit(2)
    try:
        plv_cfg, _search, ignored = plv_search_settings(cfg, quick=quick)
    except ConfigError as exc:
        _fail(exc)
    if ignored:
        err_console.print(f"[yellow]![/yellow] not used by --objective plv (it trains its own agent on its own frames "
                          f"and episodes): {', '.join(ignored)}", highlight=False)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with _bars() as bar:
        try:
            res = run_plv_search(cfg, out, _stage_progress(bar), quick=quick)
        except (ConfigError, ValueError) as exc:
            _fail(exc)
    wall = time.perf_counter() - t0
    paths = plot_plv_search(res, out)
    (out / "trials.json").write_text(json.dumps(res.trials, indent=1, default=str))
    (out / "summary.json").write_text(json.dumps({**res.summary(), "wall_s": round(wall, 1)}, indent=1, default=str))
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
    console.print(f"wrote {', '.join(str(p) for p in paths)} (+ .svg), {out / 'trials.json'}, {out / 'summary.json'}",
                  highlight=False, markup=False)
