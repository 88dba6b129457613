"""`proxybench robot serve` (the simulator as a robot node) and `proxybench run --robot-cmd` (drive one)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.markup import escape

from proxybench.cli.app import console, err_console, robot_app

if TYPE_CHECKING:
    import numpy as np

    from proxybench.agents.base import Agent
    from proxybench.domain.params import DomainParams
    from proxybench.protocol.options import RobotNodeOptions


def parse_params(items: list[str]) -> DomainParams:
    """``k=v`` items (values read as YAML: numbers, booleans, lists) → DomainParams; a bad key or value is
    a usage error naming it."""
    import yaml
    from pydantic import ValidationError

    from proxybench.domain.params import DomainParams

    values = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise typer.BadParameter(f"{item!r} is not k=v", param_hint="--param")
        values[key.strip()] = yaml.safe_load(raw)
    try:
        return DomainParams.model_validate(values)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
        raise typer.BadParameter(problems, param_hint="--param") from exc


@robot_app.command("serve")
def robot_serve(
    map_name: str | None = typer.Option("loop_3x3", "--map", help="map to prepare (built-in name or YAML file); "
                                        "set_map may choose another"),
    param: list[str] = typer.Option([], "--param", help="domain parameter k=v (repeatable), e.g. image_width=160"),
    seed: int = typer.Option(0, min=0, help="episode seed when neither `seed` nor episode_start gives one"),
    name: str = typer.Option("robot", help="node name in timing information"),
) -> None:
    """Serve the proxybench simulator as a robot node on stdin/stdout (or $AIDONODE_DATA_IN/_OUT).

    This is a SIMULATED robot: one proxybench Simulator behind AIDO's simulator protocol
    (docs/robot-protocol.md), the reference for a physical robot's bridge. Messages go to stderr only.
    """
    from proxybench.domain.maps import MapError
    from proxybench.protocol.robot_node import RobotNode, serve_robot
    from proxybench.runner.sim_robot import SimRobot

    params = parse_params(param)
    try:
        node = RobotNode(SimRobot(params, map_name), seed=seed, node_name=name)
    except (MapError, ValueError) as exc:
        err_console.print(f"[red]error:[/red] {escape(str(exc))}", highlight=False)
        raise typer.Exit(1) from exc
    print(f"[{name}] serving a SIMULATED robot (proxybench simulator, {params.image_width}x{params.image_height} "
          f"at {params.frame_rate:g} Hz) on the robot protocol", file=sys.stderr, flush=True)
    raise typer.Exit(serve_robot(node, exit_on_abort=False))


def run_on_robot(robot_cmd: str, agent: Agent, map_name: str, seconds: float, seed: int, out: Path,
                 options: RobotNodeOptions | None = None) -> None:
    """The `proxybench run --robot-cmd` path: one episode of ``agent`` on a robot node started with ``options``
    (default: :class:`~proxybench.protocol.options.RobotNodeOptions`' own), recorded to ``out``."""
    from proxybench.domain.maps import MapError, load_map
    from proxybench.media import write_strip
    from proxybench.protocol import RemoteRobot, RobotFailure
    from proxybench.protocol.options import RobotNodeOptions
    from proxybench.runner.robot_episode import run_episode_on_robot
    from proxybench.tasks.metrics import METRICS

    try:
        m = load_map(map_name)
    except (MapError, FileNotFoundError) as exc:
        err_console.print(f"[red]error:[/red] {escape(str(exc))}")
        raise typer.Exit(1) from exc
    frames: list[np.ndarray] = []
    labels: list[str] = []

    def keep(k: int, image: np.ndarray | None) -> None:
        if image is not None and k % 15 == 0 and len(frames) < 12:
            frames.append(image)
            labels.append(f"frame {k}")

    t0 = time.perf_counter()
    try:
        with RemoteRobot(robot_cmd, **(options or RobotNodeOptions()).process_kwargs()) as robot:
            traj = run_episode_on_robot(robot, agent, seed, seconds, map_=m, camera=not agent.privileged,
                                        on_frame=keep, meta={"map": m.name})
    except RobotFailure as exc:
        err_console.print(f"[red]robot failure:[/red] {exc.reason}: {exc.detail}", highlight=False, markup=False)
        for line in exc.stderr_tail[-10:]:
            err_console.print(f"    {line}", highlight=False, markup=False)
        raise typer.Exit(1) from exc
    except ValueError as exc:  # e.g. a privileged agent on a robot without ground truth
        err_console.print(f"[red]error:[/red] {escape(str(exc))}", highlight=False)
        raise typer.Exit(1) from exc
    finally:
        getattr(agent, "close", lambda: None)()
    elapsed = time.perf_counter() - t0
    out.mkdir(parents=True, exist_ok=True)
    names = [out / "trajectory.parquet", out / "metrics.json"]
    traj.save(names[0])
    if frames:
        names.append(write_strip(frames, out / "drive_strip.png", labels))
    scores = {k: METRICS[k](traj) for k in ("survival_time", "driven_lanedir_consec", "deviation_center_line",
                                            "in_drivable_lane", "lane_score")}
    source = traj.meta["source"]
    record = {"map": m.name, "agent": agent.name, "privileged": agent.privileged, "seed": seed, "source": source,
              "robot": robot_cmd, **({"robot_options": options.non_default()} if options and options.non_default()
                                     else {}),
              "termination": traj.termination, **scores, "wall_s": round(elapsed, 2)}
    names[1].write_text(json.dumps(record, indent=2))
    console.print(f"wrote {', '.join(str(f) for f in names)}")
    for e in traj.events:
        if e["kind"] == "agent_failure":
            err_console.print(f"[red]agent failure:[/red] {escape(str(e['message']))}", highlight=False)
    console.print(f"metrics: map={m.name} agent={agent.name} robot={source} "
                  + " ".join(f"{k}={v:.2f}" for k, v in scores.items()) + f" end={traj.termination} "
                  f"wall={elapsed:.1f}s", highlight=False)
