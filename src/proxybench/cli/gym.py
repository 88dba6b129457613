"""`proxybench gym setup | check | params | serve`: gym-duckietown as a robot node (docs/targets.md)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from proxybench.cli.app import console, fail, gym_app

if TYPE_CHECKING:
    from proxybench.gym.environment import GymEnvironment

_PATH = typer.Option(None, "--path", help="gym's environment folder (default: $PROXYBENCH_GYM_VENV, else the "
                     "user cache: ~/.cache/proxybench/gym-duckietown-6.1.34)")


def _report(env: GymEnvironment) -> None:
    versions = ", ".join(f"{k} {v}" for k, v in env.versions.items())
    if env.ok:
        console.print(f"✓ gym-duckietown ready at {env.path}" + (f" ({versions})" if versions else ""),
                      highlight=False)
        return
    raise fail("\n".join(env.problems), mark="✗")


@gym_app.command("setup")
def gym_setup(path: Path | None = _PATH) -> None:
    """Create gym-duckietown's own environment (pinned versions) and install the Debian packages it needs
    (as root; otherwise the command to run is printed). Says each step, pip's progress and the time taken
    (minutes, more on a busy machine); run again, it says what is in place and only checks (seconds)."""
    import subprocess

    from rich.markup import escape

    from proxybench.gym.environment import GymPythonError, setup_environment
    from proxybench.venv import PipError

    try:
        env = setup_environment(path, say=lambda s: console.print(escape(s), highlight=False))
    except GymPythonError as exc:
        raise fail(exc, 2, mark="✗") from None
    except subprocess.CalledProcessError as exc:
        raise fail(f"{' '.join(map(str, exc.cmd))} failed (exit status {exc.returncode})", mark="✗") from None
    except PipError as exc:
        raise fail(exc, mark="✗") from None
    _report(env)


@gym_app.command("check")
def gym_check(path: Path | None = _PATH) -> None:
    """Say what gym-duckietown's environment lacks (exit 1), or that it renders a frame (exit 0)."""
    from proxybench.gym.environment import check_environment

    _report(check_environment(path))


@gym_app.command("params")
def gym_params_cmd(
    param: list[str] = typer.Option([], "--param", help="NAME=VALUE (gym's names), repeatable"),
    param_file: Path | None = typer.Option(None, "--param-file", help="YAML file NAME: VALUE (and a nonce)"),
) -> None:
    """List gym's parameters with their defaults; with --param / --param-file, check them and print θ and
    its hash (the reveal step of a hidden target: compare with the hash its recording kept)."""
    import json

    from proxybench.gym.params import GymParamError, describe_params, gym_params

    if not param and param_file is None:
        console.print(describe_params(), highlight=False, markup=False)
        return
    try:
        p = gym_params(param, param_file)
    except GymParamError as exc:
        raise fail(exc, 2) from None
    changed = {k: list(v) if isinstance(v, tuple) else v for k, v in p.changed.items()}
    console.print(json.dumps({"changed": changed, "sha256": p.sha256}, indent=2), highlight=False, markup=False)


@gym_app.command("serve")
def gym_serve(
    map_name: str = typer.Option("loop_3x3", "--map", help="map to prepare: proxybench name, duckietown-world map "
                                 "name (gym's) or YAML file; set_map may choose another"),
    param: list[str] = typer.Option([], "--param", help="gym parameter NAME=VALUE (gym's names; repeatable), "
                                    "e.g. trim=0.1; `proxybench gym params` lists them"),
    param_file: Path | None = typer.Option(None, "--param-file", help="YAML file of NAME: VALUE"),
    secret: bool = typer.Option(False, "--secret", help="hide θ (from --param-file): the node reports only its hash"),
    seed: int = typer.Option(0, min=0, help="episode seed when neither `seed` nor episode_start gives one"),
    name: str = typer.Option("gym", help="node name in timing information"),
    cpus: str | None = typer.Option(None, "--cpus", help="run gym's process on these CPUs (e.g. 1 or 2-3) and "
                                    "this node on the others: keeps most of gym's speed beside busy work; "
                                    "give each node its own, or say auto (a CPU no other auto node holds)"),
    path: Path | None = _PATH,
) -> None:
    """Serve gym-duckietown as a robot node on stdin/stdout (or $AIDONODE_DATA_IN/_OUT).

    A SIMULATED robot of another simulator: gym-duckietown's renderer and DB18 dynamics, in its own
    environment (`proxybench gym setup`), behind proxybench's robot protocol (docs/robot-protocol.md).
    """
    from proxybench.domain.maps import MapError
    from proxybench.gym.backend import GymBridgeError, GymRobot
    from proxybench.gym.cpus import CpuError, choose_cpus, cpu_list, pin_node
    from proxybench.gym.params import GymParamError, gym_params
    from proxybench.protocol.robot_node import RobotNode, serve_robot

    try:
        params = gym_params(param, param_file, secret)
        gym_cpus, _claim = choose_cpus(cpus)  # a claim is held while this function runs: the node's life
        if cpus is not None and gym_cpus is None:
            print(f"[{name}] --cpus auto: no CPU free (one CPU here, or each held by another node): gym's "
                  "process runs where the scheduler puts it", file=sys.stderr, flush=True)
        backend = GymRobot(params, map_name, path)
        if gym_cpus is not None:
            try:
                pin_node(backend.proc.pid, gym_cpus)
            except CpuError:
                backend.close()
                raise
    except (GymParamError, CpuError, GymBridgeError, MapError, ValueError) as exc:
        raise fail(exc, 2 if isinstance(exc, GymParamError | CpuError) else 1) from None
    print(f"[{name}] serving a SIMULATED robot (gym-duckietown {backend.version}, {backend.width}x{backend.height} "
          f"at {1 / backend.frame_dt:g} Hz{', parameters hidden' if secret else ''}"
          f"{f', its process on CPU {cpu_list(gym_cpus)}' if gym_cpus else ''}) on the robot protocol",
          file=sys.stderr, flush=True)
    try:
        code = serve_robot(RobotNode(backend, seed=seed, node_name=name), exit_on_abort=False)
    finally:
        backend.close()
    raise typer.Exit(code)
