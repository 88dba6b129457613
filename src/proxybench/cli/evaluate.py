"""`proxybench score` and `proxybench repeatability`: scoring recorded runs, and run-to-run spread."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.markup import escape
from rich.table import Table

from proxybench.cli.app import app, console, err_console, fail
from proxybench.cli.node_options import AGENT_CWD_HELP, with_agent_node_options
from proxybench.cli.options import positive
from proxybench.cli.progress import progress_bar, status

if TYPE_CHECKING:
    from proxybench.protocol.options import NodeOptions

_SCORE_METRICS = ("survival_time", "driven_lanedir_consec", "driven_any", "deviation_center_line",
                  "deviation_heading", "in_drivable_lane", "lane_score")


@app.command()
def score(
    files: list[Path] = typer.Argument(..., help="trajectory files: proxybench Parquet, or recorded CSV/Parquet"),
    map_name: str = typer.Option("loop_3x3", "--map", help="map of recorded runs (t, x, y, theta in its frame)"),
    episode_seconds: float | None = typer.Option(None, callback=positive,
                                                 help="cap survival_time at this episode length [s]"),
    out: Path | None = typer.Option(None, "--out", help="also save the table: FILE.csv or FILE.parquet"),
) -> None:
    """Score trajectories with the task metrics: imported real runs and simulated ones alike.

    Recorded runs need columns t [s], x [m], y [m], theta [rad] in the map frame (as a localisation
    system such as the Autolab's watchtowers produces); the lane pose is recomputed from the map.
    """
    from proxybench.tasks.metrics import METRICS
    from proxybench.tasks.trajectory import Trajectory, TrajectoryError

    if out is not None and out.suffix.lower() not in (".csv", ".parquet"):
        raise typer.BadParameter(f"{out}: the table is saved as .csv or .parquet", param_hint="--out")
    rows: list[dict] = []
    table = Table(title="scores")
    for col in ("file", "source", "end", *_SCORE_METRICS):
        table.add_column(col, justify="left" if col in ("file", "source", "end") else "right")
    bad = 0
    for f in files:
        try:
            traj = Trajectory.read(f, map_name)
        except (TrajectoryError, FileNotFoundError) as exc:
            err_console.print(f"[red]✗[/red] {escape(str(exc))}", highlight=False)
            bad += 1
            continue
        if episode_seconds:
            traj.meta["episode_seconds"] = episode_seconds
        scores = {m: METRICS[m](traj) for m in _SCORE_METRICS}
        rows.append({"file": str(f), "source": str(traj.meta.get("source", "?")), "agent": traj.meta.get("agent"),
                     "episode": traj.meta.get("episode"), "termination": traj.termination, **scores})
        table.add_row(f.name, rows[-1]["source"], traj.termination, *(f"{v:.3f}" for v in scores.values()))
    console.print(table)
    if out is not None:
        _save_table(rows, out)
        console.print(f"wrote {out} ({len(rows)} row(s))", highlight=False)
    if bad:
        raise typer.Exit(1)


def _save_table(rows: list[dict], out: Path) -> None:
    """The scores as CSV or Parquet (by suffix), written atomically."""
    import pandas as pd

    df = pd.DataFrame(rows, columns=["file", "source", "agent", "episode", "termination", *_SCORE_METRICS])
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    if out.suffix.lower() == ".csv":
        df.to_csv(tmp, index=False)
    else:
        df.to_parquet(tmp, index=False)
    tmp.replace(out)


def _agent_specs(names: list[str], commands: list[str], options, bench) -> list:
    """--agent and --agent-cmd, else the benchmark file's ``agents:``, else every zoo agent."""
    from proxybench.agents import ZOO
    from proxybench.experiments.agent_args import AgentArgError, is_image, parse_agent
    from proxybench.runner.jobs import AgentSpec

    if not names and not commands:
        if bench.agents:
            return [parse_agent(e) for e in bench.agents]
        names = list(ZOO)
    specs = []
    for n in names:
        if "=sdk" in n or is_image(n):  # NAME=sdk:COMMAND, a duckietown-sdk program; NAME=image:PATH, an image
            try:
                specs.append(parse_agent(n))
            except AgentArgError as exc:
                raise typer.BadParameter(str(exc), param_hint="--agent") from None
            continue
        if n not in ZOO:
            raise typer.BadParameter(f"unknown agent {n!r}; known: {', '.join(ZOO)} (or NAME=sdk:COMMAND, "
                                     "NAME=image:PATH)", param_hint="--agent")
        specs.append(AgentSpec(n))
    for item in commands:
        name, sep, cmd = item.partition("=")
        if not sep or not name.strip() or not cmd.strip():
            raise typer.BadParameter(f"{item!r}: expected NAME=COMMAND", param_hint="--agent-cmd")
        specs.append(AgentSpec.node(name.strip(), cmd.strip(), options))
    return specs


@app.command()
@with_agent_node_options(AGENT_CWD_HELP + " (of every --agent-cmd)")
def evaluate(
    benchmark: str = typer.Argument(..., help="benchmark YAML file or built-in name (aido_lf, aido_lfi, thesis_loop)"),
    agent: list[str] = typer.Option([], "--agent", help="zoo agent or NAME=sdk:COMMAND (repeat); default: every "
                                    "admitted one"),
    agent_cmd: list[str] = typer.Option([], "--agent-cmd", help="NAME=COMMAND of an external agent node (repeat)"),
    domain: str | None = typer.Option(None, help="run in this named domain instead (default, reality)"),
    backend: str = typer.Option("local", help="inline | local (process pool) | ray"),
    workers: int | None = typer.Option(None, min=1, help="parallel workers (default: one per core)"),
    run_dir: Path | None = typer.Option(None, help="run directory (default: out/evaluate/<benchmark>)"),
    video: bool = typer.Option(False, "--video", help="also record episode 0 of every agent (MP4 + PNG strip)"),
    quick: bool = typer.Option(False, "--quick", help="smoke test: the first 2 episodes, at most 15 s each"),
    options: NodeOptions = None,  # the agent node options: with_agent_node_options
    watchtowers: str | None = typer.Option(None, "--watchtowers", help="also record a lab's watchtowers in every "
                                           "episode into RUN_DIR/logs/<agent>/<episode> (for `proxybench localize`): "
                                           "auto or a layout file (docs/autolab.md)"),
) -> None:
    """Run agents on a benchmark and print the leaderboard in the benchmark's lexicographic semiorder.

    Without --agent / --agent-cmd the agents are the benchmark file's `agents:` list, else the whole zoo.
    --agent-cmd takes NAME=COMMAND, the command as you would type it (shell syntax works); --agent-cwd,
    --transport, the timeouts and --no-reflection apply to every --agent-cmd. Episodes are cached in the
    run directory: run again to resume an interrupted evaluation. The table counts the episodes that
    ended in a collision (with a map object, a duckie, a pedestrian or a robot).
    """
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn

    from proxybench.runner.backends import make_backend
    from proxybench.runner.evaluate import evaluate_benchmark
    from proxybench.runner.jobs import is_privileged
    from proxybench.tasks.benchmark import Benchmark, BenchmarkError

    try:
        bench = Benchmark.load(benchmark)
    except BenchmarkError as exc:
        raise fail(exc) from exc
    if quick:
        bench = _quick(bench)
    specs = _agent_specs(agent, agent_cmd, options, bench)
    run_dir = run_dir or Path("out/evaluate") / bench.name
    layout = streams = None
    if watchtowers is not None:
        from proxybench.autolab.cli_support import layout_streams
        from proxybench.autolab.watchtowers import LayoutError
        from proxybench.domain.maps import MapError, load_map

        try:
            layout, streams, _ = layout_streams(watchtowers, load_map(bench.map))
        except (LayoutError, MapError) as exc:
            raise fail(exc, 2) from exc
    be = make_backend(backend, workers)
    with progress_bar(TextColumn(f"[bold]{bench.name}[/bold] episodes"), BarColumn(), MofNCompleteColumn(),
                  TimeRemainingColumn(), console=console, transient=True) as bar:
        task = bar.add_task("episodes", total=None)
        try:
            ev = evaluate_benchmark(bench, specs, run_dir, be, domain=domain,
                                    privileged=is_privileged,
                                    progress=lambda d, t: bar.update(task, completed=d, total=t), streams=streams)
        except BenchmarkError as exc:
            raise fail(exc, 2) from exc
        finally:
            be.close()
    _print_leaderboard(ev, run_dir)
    if layout is not None:
        from proxybench.autolab.cli_support import logs_from_results

        logs = logs_from_results(ev.sweep.results, layout, bench.map, run_dir / "logs", bench.duration)
        console.print(f"watchtower logs of {logs} episode(s) in {run_dir / 'logs'} (proxybench localize "
                      f"{run_dir / 'logs'} --map {bench.map} --out TARGET)", highlight=False)
    if video:
        _videos(ev, specs, run_dir)


def _quick(bench, episodes: int = 2, seconds: float = 15.0):
    """The benchmark cut to its first ``episodes`` episodes of at most ``seconds`` (renamed ``<name>-quick``)."""
    ep = bench.episodes
    cut = {k: getattr(ep, k)[:episodes] for k in ("poses", "seeds", "routes") if getattr(ep, k, None) is not None}
    if ep.count is not None:
        cut["count"] = min(ep.count, episodes)
    return bench.model_copy(update={"name": f"{bench.name}-quick", "duration": min(bench.duration, seconds),
                                    "episodes": ep.model_copy(update=cut)})


def _videos(ev, specs, run_dir: Path) -> None:
    """Episode 0 of each admitted agent, recorded in the benchmark's domain."""
    from proxybench.runner.evaluate import benchmark_domain
    from proxybench.runner.outcomes import make_agent_for
    from proxybench.runner.record import record_run

    bench = ev.benchmark
    ep = bench.episode_specs()[0]
    domain = benchmark_domain(bench)
    written = []
    for spec in specs:
        if spec.label in ev.refused:
            continue
        agent = make_agent_for(spec)
        try:
            with status(f"recording {spec.label}"):
                rec = record_run(domain, agent, bench.map, ep.seed, bench.duration, run_dir / "videos",
                                 stem=spec.label, pose=ep.pose, route=ep.route, npcs=bench.traffic())
        finally:
            getattr(agent, "close", lambda: None)()
        written += rec.files
    console.print(f"wrote {', '.join(str(f) for f in written)}")


def _collisions(results) -> dict[str, tuple[int, int, dict[str, int]]]:
    """Per agent: (episodes ended by a collision, episodes, {what was hit: count}) from the stored runs."""
    from proxybench.tasks.trajectory import Termination, Trajectory, TrajectoryError

    out: dict[str, tuple[int, int, dict[str, int]]] = {}
    for r in results:
        hit, total, what = out.get(r.agent, (0, 0, {}))
        if r.termination is Termination.COLLISION:
            hit += 1
            try:
                end = Trajectory.load(r.trajectory).event(Termination.COLLISION) if r.trajectory else None
            except (TrajectoryError, OSError):
                end = None
            kind = (end.with_ if end is not None else None) or "object"
            what[kind] = what.get(kind, 0) + 1
        out[r.agent] = (hit, total + 1, what)
    return out


def _bradley_terry(ev):
    """Bradley–Terry scores of the evaluated agents: compared episode by episode (same start and seed) on the
    benchmark's criteria in order, with their tolerances (the semiorder per episode); NaN episodes skipped."""
    import math

    from proxybench.usefulness.bradley_terry import EpisodeScores, bradley_terry_lexicographic, episode_metric

    per = []
    for c in ev.benchmark.criteria():
        metric = episode_metric(c.metric)
        values: dict = {}
        for r in ev.sweep.results:
            values.setdefault(r.agent, {})[(r.episode, r.seed)] = r.scores.get(metric, math.nan)
        per.append(EpisodeScores(values, c.higher_is_better, c.tolerance))
    return bradley_terry_lexicographic(per)


def _bt_lines(bt) -> str:
    """What the Bradley–Terry scores say about first place, in words, under the table."""
    text = (f"BT score: Bradley–Terry from the {bt.episodes} paired episodes ({bt.level:.0%} intervals, "
            f"{bt.resamples} bootstrap resamples of episodes).")
    if bt.leader is not None:
        text += (" First place is provisional: the leader's interval overlaps the runner-up's." if bt.provisional
                 else " First place is settled: the leader's interval clears the runner-up's.")
    f = bt.fragility
    if f is not None and f.removals is None:
        text += f" Fragility {f}: first place survives the removal of {f.cap} episode{'' if f.cap == 1 else 's'}."
    elif f is not None:
        text += f" Fragility {f}: removing {f} episode{'' if f.removals == 1 else 's'} changes first place (greedy)."
    return " ".join([text, *(f"{n}." for n in bt.notes)])


def _print_leaderboard(ev, run_dir: Path) -> None:

    from proxybench.tasks.trajectory import Termination

    bench = ev.benchmark
    agg = ev.aggregates.set_index("agent")
    cols = [c.metric for c in bench.criteria()]
    bt = _bradley_terry(ev)
    scores = bt.by_agent()
    table = Table(title=f"{bench.name}: {len(bench.episode_specs())} episodes × {bench.duration:g} s "
                        f"(simulated; {ev.sweep.ran} run, {ev.sweep.cached} cached)")
    table.add_column("rank", justify="right")
    table.add_column("agent")
    for c in bench.criteria():
        table.add_column(f"{c.metric} {'↑' if c.higher_is_better else '↓'} ±{c.tolerance:g}", justify="right")
    table.add_column("W/L/T", justify="right")
    table.add_column(f"BT score [{bt.level:.0%}]", justify="right")
    table.add_column("collisions", justify="right")
    crashes = _collisions(ev.sweep.results)
    rows = []
    prev = None
    for r in ev.ranks:
        shown = "=" if r.rank == prev else str(r.rank)
        prev = r.rank
        vals = [float(agg.loc[r.agent, c]) for c in cols]
        hit, total, what = crashes.get(str(r.agent), (0, 0, {}))
        with_ = ", ".join(f"{k} {n}" for k, n in sorted(what.items()))
        s = scores.get(r.agent)
        cell = "—" if s is None else s.text() + (" provisional" if bt.provisional and r.agent == bt.leader else "")
        table.add_row(shown, str(r.agent), *(f"{v:.3f}" for v in vals), f"{r.wins}/{r.losses}/{r.ties}", cell,
                      f"{hit}/{total}" + (f" ({with_})" if with_ else ""))
        rows.append({"rank": r.rank, "agent": r.agent, **dict(zip(cols, vals, strict=True)),
                     "wins": r.wins, "losses": r.losses, "ties": r.ties,
                     "bt": None if s is None or s.score is None else
                     {"score": s.score, "lo": s.lo, "hi": s.hi, "contender": s.contender},
                     "collisions": hit, "collided_with": what})
    console.print(table)
    console.print(_bt_lines(bt), highlight=False)
    for name, why in ev.refused.items():
        console.print(f"[yellow]not admitted:[/yellow] {escape(str(name))}: {escape(str(why))}", highlight=False)
    failures = [r for r in ev.sweep.results if r.termination is Termination.AGENT_FAILURE]
    for r in failures[:5]:
        console.print(f"[red]agent failure[/red] {r.agent} episode {r.episode}: {escape(str(r.message))}",
                      highlight=False)
    (run_dir / "leaderboard.json").write_text(json.dumps(rows, indent=1, default=str))
    (run_dir / "bradley_terry.json").write_text(json.dumps(bt.to_json(), indent=1, default=str))
    ev.aggregates.to_csv(run_dir / "aggregates.csv", index=False)
    console.print(f"wrote {run_dir / 'leaderboard.json'}, {run_dir / 'bradley_terry.json'}, "
                  f"{run_dir / 'aggregates.csv'}, {run_dir / 'results.parquet'}")
