"""A robot node as the target: ``--target "robot:CMD"``.

CMD starts a process that speaks the robot protocol (docs/robot-protocol.md): a physical Duckiebot's
bridge, another simulator, or ``proxybench robot serve``. Its episodes run through the runner as a robot
domain (``DomainSpec.robot``), one after another on one node process, cached in the experiment's
run directory like every other episode: a sweep or an optimisation runs the target's episodes once and
re-uses them for every θ, and an interrupted run resumes. proxybench cannot see a robot's θ nor tell a
real robot from a simulator except by what the node says of itself, and reports it that way.
"""

from __future__ import annotations

from pathlib import Path

from proxybench.domain.events import Termination
from proxybench.domain.kinds import DomainKind
from proxybench.protocol.options import RobotNodeOptions
from proxybench.runner.jobs import DEFAULT_FRAME_RATE, DomainSpec
from proxybench.targets.base import Target, TargetInfo, TargetRun, live_run
from proxybench.targets.manifest import SimulatorInfo, TargetError

__all__ = ["RobotTarget", "robot_said"]


class RobotTarget(Target):
    """A robot node started with ``command``; ``nodes``: how many of its processes may run at once (keep 1 for
    a bridge to one physical robot; a simulator node can take one per worker); ``options``: how to start and
    talk to it (:class:`~proxybench.protocol.options.RobotNodeOptions`: working directory, transport,
    timeouts, reflection; None: the defaults); ``frame_rate`` [Hz]: what the node is asked to step at, the
    proxies' rate, so that target and proxy episodes see and decide alike (a node that says its own rate is
    stepped at that)."""

    kind = DomainKind.ROBOT
    what = "robot node"

    def __init__(self, command: str, nodes: int = 1, options: RobotNodeOptions | None = None,
                 frame_rate: float = DEFAULT_FRAME_RATE):
        self.command = command
        self.nodes = nodes
        self.options = options or RobotNodeOptions()
        self.frame_rate = frame_rate
        self._said: str = ""
        self._simulator: SimulatorInfo | None = None

    def domain(self, image_size: tuple[int, int] | None = None) -> DomainSpec:
        return DomainSpec.robot(self.command, frame_rate=self.frame_rate, nodes=self.nodes, options=self.options)

    def info(self) -> TargetInfo:
        simulated = True if self._said == DomainKind.SIMULATION else None  # a node's word; "robot" may be either
        said = f"; it described itself as a {self._said}" if self._said else ""
        sim = self._simulator
        if sim is not None and self._said == "simulation":
            said += f": {sim.describe()} (SIMULATED, another simulator than proxybench's)"
        label = (f"robot node: {self.command}" if sim is None
                 else f"{sim.name} {sim.version} (simulated): {self.command}")
        return TargetInfo(
            DomainKind.ROBOT, simulated, label,
            f"The target is a robot node started with `{self.command}`{said}. proxybench cannot tell a real robot "
            "from a simulator behind the robot protocol: treat results as real only if you know the node drives "
            "a physical robot.", {"command": self.command, "kind": self._said, "nodes": self.nodes,
                                  **({"options": self.options.non_default()} if self.options.non_default() else {}),
                                  **({"simulator": sim.model_dump()} if sim is not None else {})})

    def run(self, agents, *, map_name, seconds, episodes, seed, metrics, image_size, run_dir, backend=None,
            progress=None) -> TargetRun:
        run, sweep = live_run(self, self.domain(), agents, map_name=map_name, seconds=seconds, episodes=episodes,
                              seed=seed, metrics=metrics, run_dir=run_dir, backend=backend, progress=progress,
                              stage="target episodes (robot)")
        failed = [r for r in sweep.results if r.termination is Termination.ROBOT_FAILURE]
        if failed:
            shown = "\n  ".join(f"{r.agent} episode {r.episode}: {r.message}" for r in failed[:5])
            raise TargetError(f"target: the {self.what} `{self.command}` failed on {len(failed)} of "
                              f"{len(sweep.results)} episode(s); finished episodes are cached, run again to retry the "
                              f"rest:\n  {shown}")
        made = next((r.trajectory for r in sweep.results if r.trajectory), None)
        self._said, self._simulator = robot_said(made) if made else ("", None)
        run.info = self.info()
        return run


def robot_said(path: str | Path) -> tuple[str, SimulatorInfo | None]:
    """What the robot node said it is (``simulation`` | ``robot``) and, for a simulator that names itself,
    which (a hidden θ only as its hash), from a trajectory it produced."""
    from pydantic import ValidationError

    from proxybench.tasks.trajectory import Trajectory

    try:
        said = Trajectory.load(path).meta.get("robot", {})
    except (ValueError, OSError):
        return "", None
    sim = said.get("simulator")
    try:
        simulator = SimulatorInfo.model_validate(sim) if isinstance(sim, dict) else None
    except ValidationError:
        simulator = None  # a node's free-form self-description: kept out of the strict manifest
    return str(said.get("kind", "")), simulator
