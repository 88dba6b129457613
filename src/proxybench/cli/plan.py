"""`proxybench plan`: how many target episodes per agent, and which agents need them (sample-size planning).

Runs (or reads) a pilot on any target, optionally replays it in candidate proxies (``--sweep``), and
prints what n episodes per agent would give: PRPV's order-range width, the chance of picking the right θ,
the near-tied pairs and the agents to run next. ``--sequential`` spends a budget of target episodes on a
live target where they settle most (docs/usefulness.md, "How many episodes?").
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import typer
from rich.table import Table

from proxybench.cli.app import app, console
from proxybench.cli.dtps_options import DtpsKind, DtpsOption, DtpsReset, dtps_option_values
from proxybench.cli.options import non_negative, positive, probability
from proxybench.cli.usefulness import (
    _AGENT_HELP,
    _TARGET_HELP,
    _bars,
    _fail,
    _image_size,
    _kv,
    _load,
    _overrides,
    _stage_progress,
    _sweep,
)


@app.command()
def plan(
    quick: bool = typer.Option(False, "--quick", help="6 agents × 3 pilot episodes × 8 s; --sequential: budget 4"),
    config: Path | None = typer.Option(None, "--config", help="experiment file (YAML; see docs/targets.md)"),
    target: str | None = typer.Option(None, help=f"{_TARGET_HELP} (default: reality)"),
    target_param: list[str] = typer.Option([], "--target-param", help="reality model θ, k=v (repeat)"),
    robot_nodes: int | None = typer.Option(None, min=1, help="robot node processes at once (default: 1)"),
    dtps_reset: DtpsReset = None,
    dtps_kind: DtpsKind = None,
    dtps_option: DtpsOption = [],  # noqa: B006 (typer reads the default, never mutates it)
    agent: list[str] = typer.Option([], "--agent", help=f"{_AGENT_HELP} (default: the target's, else 12 zoo agents)"),
    map_name: str | None = typer.Option(None, "--map", help="map (default: the target's, else loop_3x3)"),
    episodes: int | None = typer.Option(None, min=2, help="pilot episodes per agent (default: 3; a recorded target: "
                                        "all it has)"),
    seconds: float | None = typer.Option(None, callback=positive, help="episode length in s (default: 20; --quick 8)"),
    metric: list[str] = typer.Option([], "--metric", help="task metric (repeat) (default: driven_lanedir_consec, "
                                     "survival_time)"),
    image_size: str | None = typer.Option(None, help="camera WIDTHxHEIGHT (default: 160x120)"),
    proxy_param: list[str] = typer.Option([], "--proxy-param", help="θ every candidate proxy has, k=v (repeat)"),
    sweep: list[str] = typer.Option([], "--sweep", help="candidate θ, NAME=V1,V2,… (repeat): plan for picking the "
                                    "right one (default: none)"),
    width: float | None = typer.Option(None, callback=non_negative, help="PRPV order-range width to reach"),
    p_correct: float | None = typer.Option(None, callback=probability,
                                           help="probability of picking the pilot's best candidate to reach"),
    confidence: float = typer.Option(0.8, callback=probability, help="probability of reaching --width"),
    power: float = typer.Option(0.8, callback=probability, help="probability of settling a pair (per-pair needs)"),
    tolerance: list[str] = typer.Option([], "--tolerance", help="ε of a metric, NAME=VALUE (repeat): pairs within it "
                                        "are ties (default: AIDO's semiorder tolerances scaled to the episode "
                                        "length; NAME=0: strict order)"),
    range_level: float = typer.Option(0.8, "--range", callback=probability, help="central share of the pilot's "
                                      "posterior that the episode ranges span"),
    pilot_as_truth: bool = typer.Option(False, "--pilot-as-truth", help="take the pilot's means and spreads as the "
                                        "truth (the former planner; ranges then collapse to points)"),
    max_episodes: int = typer.Option(320, min=2, max=100_000, help="largest n per agent considered"),
    reps: int | None = typer.Option(None, min=20, max=100_000, help="simulated experiments per n (default: 400; "
                                    "--quick 150)"),
    sequential: bool = typer.Option(False, "--sequential", help="then run --budget more target episodes where they "
                                    "settle most (live targets)"),
    budget: int | None = typer.Option(None, min=1, max=100_000, help="target episodes --sequential may run (default: "
                                      "20; --quick 4)"),
    batch: int = typer.Option(2, min=1, max=1000, help="episodes per round of --sequential (e.g. the workers)"),
    seed: int | None = typer.Option(None, min=0, help="experiment seed (default: 0)"),
    out: Path = typer.Option(Path("out/plan"), help="folder for plan.json, tables, plan.png and the episode cache"),
    backend: str = typer.Option("local", help="inline | local (process pool) | ray"),
    workers: int | None = typer.Option(None, min=1, help="parallel workers (default: one per core)"),
) -> None:
    """Plan target episodes: n per agent to settle every pair of agents, for a PRPV interval of a given width, or
    for a given chance of the right θ.

    Pairs within the task's tolerance ε count as ties, so every pair settles with finitely many episodes; the
    pilot is not taken as the truth: every count is a range over its posterior, and experiments with n episodes
    per agent are simulated in worlds drawn from it (docs/usefulness.md). Episodes are cached in OUT/runs:
    `predictivity --out OUT` re-uses them.
    """
    from proxybench.experiments.config import resolve
    from proxybench.experiments.predictivity import proxy_domains, proxy_jobs
    from proxybench.runner.backends import make_backend
    from proxybench.runner.sweep import run_jobs
    from proxybench.targets.base import by_agent
    from proxybench.targets.manifest import TargetError
    from proxybench.tasks.metrics import METRICS
    from proxybench.usefulness.plan import DEFAULT_GRID
    from proxybench.usefulness.plan import plan as make_plan

    over = _overrides(target=target, target_params=_kv(target_param, "--target-param"), robot_nodes=robot_nodes,
                      dtps_options=dtps_option_values(dtps_reset, dtps_kind, dtps_option),
                      agents=agent, map=map_name, episodes=episodes, seconds=seconds, metrics=metric,
                      image_size=_image_size(image_size), proxy=_kv(proxy_param, "--proxy-param"),
                      sweep=_sweep(sweep), seed=seed)
    cfg = _load(config, over)
    candidates = "sweep" in cfg.model_fields_set
    eps_over = _kv(tolerance, "--tolerance")
    be = make_backend(backend, workers)
    t0 = time.perf_counter()
    seq = None
    with _bars() as bar:
        try:
            exp, tgt_obj = resolve(cfg, "plan", quick=quick, work_dir=out / "agents")
            tol = _tolerances(exp.metrics, exp.seconds, eps_over)
            run_kw = dict(map_name=exp.map, seconds=exp.seconds, seed=exp.seed, metrics=exp.metrics,
                          image_size=exp.image_size, run_dir=out / "runs", backend=be, progress=_stage_progress(bar))
            if sequential:
                from proxybench.experiments.sequential import run_sequential

                seq = run_sequential(tgt_obj, exp.agents, pilot=exp.episodes, budget=budget or (4 if quick else 20),
                                     batch=batch, tolerances=tol, **run_kw)
                tgt = seq.run
            else:
                tgt = tgt_obj.run(exp.agents, episodes=exp.episodes, **run_kw)
            proxies = {}
            if candidates:
                for _, _, dom in proxy_domains(exp):
                    jobs = proxy_jobs(exp, tgt, dom)
                    proxies[dom.name] = by_agent(jobs, run_jobs(jobs, out / "runs", be).results, exp.metrics)
        except (TargetError, ValueError) as exc:
            _fail(exc)
        finally:
            be.close()
    higher = tuple(METRICS[m].higher_is_better for m in exp.metrics)
    grid = [n for n in DEFAULT_GRID if n <= max_episodes] + ([max_episodes] if max_episodes not in DEFAULT_GRID else [])
    try:
        p = make_plan(tgt.results, higher, exp.metrics, proxies=proxies, width=width, p_correct=p_correct,
                      confidence=confidence, grid=grid, reps=reps or (150 if quick else 400), power=power,
                      batch=batch, seed=exp.seed, tolerances=tol, range_level=range_level,
                      uncertain=not pilot_as_truth)
    except ValueError as exc:
        _fail(exc)
    wall = time.perf_counter() - t0
    _print_plan(p, tgt, seq, wall)
    _write(p, tgt, seq, out, wall)


def _tolerances(metrics: tuple[str, ...], seconds: float, over: dict) -> tuple[float, ...]:
    """ε per metric: AIDO's semiorder tolerances at this episode length, with the command line's overrides."""
    from proxybench.usefulness.indifference import semiorder_tolerances

    def number(v) -> float:
        try:
            return float(v)
        except (TypeError, ValueError):
            return math.nan

    over = {k: number(v) for k, v in over.items()}
    unknown = sorted(set(over) - set(metrics))
    if unknown:
        raise typer.BadParameter(f"{', '.join(unknown)}: not a metric of this plan ({', '.join(metrics)})",
                                 param_hint="--tolerance")
    bad = [k for k, v in over.items() if not (math.isfinite(v) and v >= 0)]
    if bad:
        raise typer.BadParameter(f"{', '.join(bad)}: a tolerance is a number >= 0", param_hint="--tolerance")
    return semiorder_tolerances(metrics, seconds, overrides=over)


def _n(x: float) -> str:
    return f"{x:,.0f}" if math.isfinite(x) else "> 100,000"


def _print_plan(p, tgt, seq, wall: float) -> None:
    console.print(f"[bold]target:[/bold] {tgt.info.statement}", highlight=False)
    pilot = ", ".join(f"{a} {n}" for a, n in p.pilot_episodes.items())
    what = "pilot episodes" if seq is None else "target episodes (pilot + sequential)"
    console.print(f"{what} per agent: {pilot}; {len(p.agents)} agents, PRPV in [0, "
                  f"{len(p.agents) * (len(p.agents) - 1)}]; {wall:.0f} s", highlight=False)
    eps = ", ".join(f"{m} {e:g}" for m, e in zip(p.metrics, p.tolerances, strict=True))
    console.print(f"tolerances ε (pairs within them are ties): {eps}", highlight=False)
    if seq is not None:
        rounds = ", ".join(f"{'+'.join(h['agents'])}" + (f" → {h['open_pairs']}" if h.get("look") else "")
                           for h in seq.history)
        console.print(f"sequential: {sum(len(h['agents']) for h in seq.history)} more episodes "
                      f"({'every pair settled' if seq.stopped == 'settled' else 'budget spent'}; the level split "
                      f"over {seq.looks} looks); open pairs: {seq.open_after_pilot} after the pilot"
                      + (f", then {rounds}" if rounds else ""), highlight=False)
    how = "worlds drawn from the pilot's posterior" if p.uncertain else "the pilot taken as the truth"
    table = Table(title=f"what n target episodes per agent give (simulated experiments in {how})")
    cols = ["n per agent", "order range width: mean", f"{p.confidence:.0%} of runs ≤", "open pairs",
            "P(all settled)"]
    if p.width is not None:
        cols.append(f"P(width ≤ {p.width:g})")
    if p.candidates:
        cols.append("P(right θ)")
    for c in cols:
        table.add_column(c, justify="right")
    for r in p.rows:
        cells = [str(r.n), f"{r.width_mean:.1f}", f"{r.width_q:.1f}", f"{r.open_pairs:.1f}", f"{r.p_settled:.2f}"]
        if p.width is not None:
            cells.append(f"{r.p_width:.2f}")
        if p.candidates:
            cells.append(f"{r.p_correct:.2f}")
        table.add_row(*cells)
    console.print(table)
    if p.width is not None:
        console.print(_answer(p.n_for_width, f"an order range at most {p.width:g} wide in {p.confidence:.0%} of runs",
                              p.rows[-1].n), highlight=False)
    if p.candidates:
        best = ", ".join(p.best)
        console.print(f"candidates (PRPV on the pilot): {', '.join(f'{k} {v:g}' for k, v in p.pilot_prpv.items())}; "
                      f"the pilot's best: {best}", highlight=False)
        if p.p_correct_goal is not None:
            console.print(_answer(p.n_for_p_correct, f"picking {best} with probability {p.p_correct_goal:.0%}",
                                  p.rows[-1].n), highlight=False)
    lo, mid, hi = p.settle_all[1], p.settle_all[0], p.settle_all[2]
    console.print(f"→ every pair settled (ordered, or tied within ε) with probability {p.power:.0%} each: {_n(mid)} "
                  f"episodes per agent [{_n(lo)}, {_n(hi)}] ({p.range_level:.0%} of the pilot's posterior)",
                  highlight=False)
    pairs = Table(title=f"pairs on the target still open: episodes per agent to settle each, median "
                        f"[{p.range_level:.0%} range] over the pilot's posterior")
    for c in ("pair", "metric", "difference", "se (pilot)", "ε", "episodes per agent", "pilot as truth"):
        pairs.add_column(c, justify="left" if c in ("pair", "metric") else "right")
    open_ = [q for q in p.pairs if not q.settled]
    for q in open_[:12]:
        pairs.add_row(f"{q.a} – {q.b}", q.metric, f"{q.difference:+.3g}", f"{q.se:.3g}", f"{q.tolerance:g}",
                      f"{_n(q.episodes)} [{_n(q.episodes_low)}, {_n(q.episodes_high)}]", _n(q.plug_in))
    if open_:
        console.print(pairs)
        if len(open_) > 12:
            console.print(f"… and {len(open_) - 12} more (pairs.csv)")
    else:
        console.print("every pair of agents is settled on the target with the pilot's episodes")
    if p.next_agents:
        console.print(f"run next (most pairs settled per episode): {', '.join(p.next_agents)}", highlight=False)


def _answer(n: int | None, what: str, largest: int) -> str:
    if n is None:
        return f"→ {what}: not reached with up to {largest} episodes per agent (near ties: see the pairs)"
    return f"→ {what}: {n} episodes per agent"


def _write(p, tgt, seq, out: Path, wall: float) -> None:
    import pandas as pd

    from proxybench.experiments.reports.predictivity import plot_plan

    out.mkdir(parents=True, exist_ok=True)
    data = {"target": tgt.info.statement, "wall_s": round(wall, 1), **p.to_dict()}
    if seq is not None:
        data["sequential"] = {"episodes": seq.episodes, "stopped": seq.stopped, "looks": seq.looks,
                              "open_after_pilot": seq.open_after_pilot, "rounds": seq.history,
                              "decisions": [{"a": a, "b": b, "decision": d} for (a, b), d in seq.decisions.items()]}
    (out / "plan.json").write_text(json.dumps(data, indent=1, default=str))
    pd.DataFrame([r.__dict__ for r in p.rows]).to_csv(out / "plan.csv", index=False)
    pd.DataFrame([q.__dict__ for q in p.pairs]).to_csv(out / "pairs.csv", index=False)
    png = plot_plan(p, out / "plan.png", tgt.info.label)
    console.print(f"wrote {out / 'plan.json'}, {out / 'plan.csv'}, {out / 'pairs.csv'}, {png} (+ .svg)",
                  highlight=False)
