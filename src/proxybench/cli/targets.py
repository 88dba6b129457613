"""`proxybench target record` and `proxybench target check`: targets as data (docs/targets.md)."""

from __future__ import annotations

import shlex
import time
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.table import Table

from proxybench.cli.app import app, console, fail, problem
from proxybench.cli.dtps_options import DtpsKind, DtpsOption, DtpsReset, dtps_option_values
from proxybench.cli.help import HelpTyper
from proxybench.cli.node_options import with_robot_node_options
from proxybench.cli.options import positive
from proxybench.cli.progress import status

if TYPE_CHECKING:
    from proxybench.protocol.options import RobotNodeOptions

target_app = HelpTyper(no_args_is_help=True, help="Record a target once (reality model, robot node or DTPS robot), "
                                                    "check recorded targets (your lab's runs).")
app.add_typer(target_app, name="target")


def counted(n: int, word: str) -> str:
    """``1 agent``, ``2 agents``: a count and its noun, in the number the count asks for."""
    return f"{n} {word}{'' if n == 1 else 's'}"


@target_app.command("record")
@with_robot_node_options(command="target", command_option="--target robot:CMD")
def record(
    out: Path = typer.Option(..., "--out", help="directory of the recorded target (created; resumed if it exists)"),
    agent: list[str] = typer.Option(..., "--agent", help="zoo name, NAME=COMMAND, checkpoint or package (repeat)"),
    target: str | None = typer.Option(None, "--target", help="what to record, named as every study names its target: "
                                      "reality (the simulated reality model; the default) | robot:CMD (a robot node) "
                                      "| dtps:HOST[:PORT]/PATH (a DTPS robot: a Duckiebot dtps:mybot.local/mybot, the "
                                      "Duckiematrix dtps:127.0.0.1:7501/robot/map_0/vehicle_0)"),
    reality: bool = typer.Option(False, "--reality", hidden=True, help="deprecated: --target reality"),
    robot_cmd: str | None = typer.Option(None, "--robot-cmd", hidden=True, help="deprecated: --target robot:CMD"),
    dtps: str | None = typer.Option(None, "--dtps", hidden=True, help="deprecated: --target dtps:HOST[:PORT]/PATH"),
    robot_nodes: int = typer.Option(1, min=1, help="robot node processes at once (1 for a physical robot)"),
    robot_options: RobotNodeOptions = None,  # the --robot-* options: with_robot_node_options
    dtps_reset: DtpsReset = None,
    dtps_kind: DtpsKind = None,
    dtps_option: DtpsOption = [],  # noqa: B006 (typer reads the default, never mutates it)
    target_param: list[str] = typer.Option([], "--target-param", help="reality model θ, k=v (repeat)"),
    episodes: int = typer.Option(10, min=1, help="episodes per agent"),
    seconds: float = typer.Option(60.0, callback=positive, max=3600.0, help="episode length in s"),
    map_name: str = typer.Option("loop_3x3", "--map", help="built-in map or map file"),
    seed: int = typer.Option(0, min=0, help="episode seeds are seed·10000 + episode"),
    image_size: str = typer.Option("160x120", help="camera WIDTHxHEIGHT (reality model)"),
    description: str = typer.Option("", help="free text for the manifest"),
    who: str = typer.Option("", help="who recorded it"),
    where: str = typer.Option("", help="where"),
    when: str = typer.Option("", help="when (default: today)"),
    backend: str = typer.Option("local", help="inline | local (process pool) | ray"),
    workers: int | None = typer.Option(None, min=1),
    watchtowers: str | None = typer.Option(None, "--watchtowers", help="also record a lab's watchtowers (reality "
                                           "model only) into DIR/logs/<agent>/<episode>, for `proxybench localize`: "
                                           "auto or a layout file (docs/autolab.md)"),
) -> None:
    """Record agents on a live target (--target: reality, robot:CMD or dtps:HOST[:PORT]/PATH) into DIR: one
    trajectory per (agent, episode) plus target.yaml.

    Every finished episode is written at once; run the same command again after an interruption and only
    the missing episodes are recorded. Robot episodes run one after another (a DTPS robot's in real time,
    each started by --dtps-reset: an operator prompt by default).
    """
    from proxybench.cli.config_options import image_size as parse_size
    from proxybench.cli.config_options import key_values
    from proxybench.experiments.agent_args import AgentArgError, parse_agents
    from proxybench.runner.backends import make_backend
    from proxybench.targets.manifest import TargetError
    from proxybench.targets.record import record_target
    from proxybench.targets.spec import open_target

    text = _target_text(target, reality, robot_cmd, dtps)
    dtps_given = dtps_option_values(dtps_reset, dtps_kind, dtps_option)
    if dtps_given and not text.startswith("dtps:"):
        raise fail("--dtps-reset, --dtps-kind, --dtps-option: only with --target dtps:… (they say how to drive a "
                   "DTPS robot)", 2, mark="✗")
    try:
        from proxybench.dtps.robot_options import DtpsRobotOptions

        live = open_target(text, params=key_values(target_param, "--target-param") or None, robot_nodes=robot_nodes,
                           robot_options=robot_options, dtps_options=DtpsRobotOptions(**dtps_given))
        specs = parse_agents(agent, out / ".agents")
    except (TargetError, AgentArgError, ValueError) as exc:
        raise fail(exc, 2, mark="✗") from None
    size = parse_size(image_size)
    assert size is not None
    streams = on_streams = None
    if watchtowers is not None:
        from proxybench.autolab.cli_support import layout_streams, result_log
        from proxybench.autolab.watchtowers import LayoutError
        from proxybench.domain.maps import MapError, load_map

        try:
            layout, streams, _ = layout_streams(watchtowers, load_map(map_name))
        except (LayoutError, MapError) as exc:
            raise fail(exc, 2, mark="✗") from None

        def on_streams(res, folder):
            result_log(res, folder, layout, map_name, seconds, "reality-model")
    robot = text.startswith("robot:")
    be = make_backend(backend, min(workers or robot_nodes, robot_nodes) if robot else 1 if text.startswith("dtps:")
                      else workers)
    t0 = time.perf_counter()
    with status("recording") as spinner:
        try:
            summary = record_target(out, live, specs, map_name=map_name, seconds=seconds, episodes=episodes,
                                    seed=seed, image_size=(size[0], size[1]), description=description, who=who,
                                    where=where, when=when or time.strftime("%Y-%m-%d"), backend=be,
                                    progress=lambda d, t: spinner.update(f"recording: episode {d}/{t}"),
                                    streams=streams, on_streams=on_streams)
        except TargetError as exc:
            raise fail(exc, 2, mark="✗") from None
        finally:
            be.close()
    m = summary.manifest
    console.print(f"recorded {summary.recorded} episode(s), kept {summary.kept} already recorded, in "
                  f"{time.perf_counter() - t0:.0f} s: {counted(len(m.agents), 'agent')} × "
                  f"{counted(len(m.episodes), 'episode')} × "
                  f"{m.seconds:g} s on {m.map} (source: {m.source}) → {out}", highlight=False)
    for line in summary.failed:
        problem(line, mark="agent failure recorded:", style="yellow")
    console.print(f"check it with: proxybench target check {out}", highlight=False)


def _target_text(target: str | None, reality: bool, robot_cmd: str | None, dtps: str | None) -> str:
    """The target's text, ``reality`` by default; the flags it replaced (--reality, --robot-cmd, --dtps) still
    name one, with a notice."""
    old = [(flag, text) for flag, text in (("--reality", "reality" if reality else None),
                                           ("--robot-cmd", robot_cmd and f"robot:{robot_cmd}"),
                                           ("--dtps", dtps and f"dtps:{dtps.removeprefix('dtps:')}")) if text]
    if not old:
        return target or "reality"
    if target is not None or len(old) > 1:
        raise fail("give one target: --target reality | robot:CMD | dtps:HOST[:PORT]/PATH", 2, mark="✗")
    (flag, text), = old
    problem(f"{flag} is deprecated: say --target {shlex.quote(text)}", mark="note:", style="yellow")
    return text


@target_app.command("check")
def check(
    root: Path = typer.Argument(..., help="directory of a recorded target (or its target.yaml)"),
    metric: list[str] = typer.Option([], "--metric", metavar="NAME[,NAME…]", help="metrics to score and show "
                                     "(repeat, or a,b) "
                                     "(default: survival_time, driven_lanedir_consec, or the table's)"),
) -> None:
    """Validate a recorded target and print a summary; every problem names its file, row and column."""
    import numpy as np

    from proxybench.targets.recorded import check_recording
    from proxybench.targets.spec import RecordedTarget
    from proxybench.tasks.trajectory import Termination

    report = check_recording(root, tuple(n.strip() for item in metric for n in item.split(",") if n.strip()) or None)
    if not report.ok:
        raise fail("\n".join([f"{root}: {len(report.problems)} problem(s)", *report.problems]), mark="✗")
    m = report.manifest
    assert m is not None
    console.print(f"[green]✓[/green] {report.root}: {RecordedTarget(report.root).info().statement}", highlight=False)
    console.print(f"map {m.map}, {m.seconds:g} s episodes, {counted(len(m.agents), 'agent')} × "
                  f"{counted(len(m.episodes), 'episode')} "
                  f"({m.kind}: {m.metrics_table or m.pattern})", highlight=False)
    if m.robot is not None and m.robot.dtps is not None:
        console.print(f"DTPS robot: {m.robot.describe()}", highlight=False, markup=False)
    elif m.robot is not None:
        said = f", which described itself as a {m.robot.kind}" if m.robot.kind else ""
        console.print(f"robot node: {m.robot.describe()}{said}", highlight=False, markup=False)
        if m.robot.simulator is not None:
            console.print(f"simulator: {m.robot.simulator.describe()}", highlight=False, markup=False)
    if m.recorded_with:
        console.print(f"recorded with {m.recorded_with}", highlight=False, markup=False)
    metrics = list(report.episodes[0].scores) if report.episodes else []
    table = Table(title="mean over episodes [min … max]")
    for col in ("agent", "episodes", *metrics, "ended early"):
        table.add_column(col, justify="left" if col == "agent" else "right")
    for a in m.agents:
        eps = [e for e in report.episodes if e.agent == a]
        cells = []
        for k in metrics:
            v = np.array([e.scores[k] for e in eps], dtype=float)
            cells.append(f"{np.nanmean(v):.2f} [{np.nanmin(v):.2f} … {np.nanmax(v):.2f}]")
        early = sum(e.termination is not Termination.TIMEOUT for e in eps) if m.kind == "trajectories" else "–"
        table.add_row(a, str(len(eps)), *cells, str(early))
    console.print(table)
    for note in report.notes:
        console.print(f"note: {note}", highlight=False, markup=False)
