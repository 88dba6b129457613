"""A DTPS robot as the target: ``--target "dtps:HOST[:PORT]/PATH"`` (a real Duckiebot, or a Duckiematrix robot).

Its episodes run through the runner as a robot domain (``DomainSpec.dtps``: jobs, cache, resume, one
episode at a time on the one robot), driven by :class:`~proxybench.runner.dtps_plant.DtpsPlant` through the
SDK environment's bridge. Each episode starts by the options' reset mode (an operator prompt, ``state/reset``,
or a start pose recorded beforehand); the proxies replay it from where the robot actually stood at t = 0.
proxybench cannot tell a Duckiematrix robot from a real one over DTPS: the report says what the user told it
(``DtpsRobotOptions.kind``), or that it was not told.
"""

from __future__ import annotations

from typing import Any

from proxybench.dtps.robot_options import DtpsAddress, DtpsRobotOptions, load_start_poses, parse_address
from proxybench.runner.jobs import DEFAULT_FRAME_RATE, DomainSpec, Job
from proxybench.targets.base import TargetInfo
from proxybench.targets.manifest import TargetError
from proxybench.targets.robot import RobotTarget

__all__ = ["DtpsTarget", "describe_robot"]


def describe_robot(address: DtpsAddress | str, options: DtpsRobotOptions) -> tuple[bool | None, str]:
    """(simulated: True / False / None when not told, one sentence on what the robot is) for reports."""
    said = {"real": (False, "you said it is a REAL robot"),
            "simulated": (True, "you said it is a SIMULATED robot (e.g. the Duckiematrix)")}
    simulated, words = said.get(options.kind or "", (None, "proxybench was not told whether it is real: over DTPS "
                                                           "it cannot tell a Duckiematrix robot from a real "
                                                           "Duckiebot (say so with --dtps-kind real|simulated)"))
    pose = options.pose if not options.pose_url else f"{options.pose} on {options.pose_url}"
    reset = {"prompt": "an operator placed it at each start", "teleport": "state/reset put it back at its own start",
             "pose-file": f"it started from the poses in {options.start_poses}"}[options.reset]
    return simulated, (f"the DTPS robot at http://{address} (pose from {pose}; commands on {options.pwm}; {reset}): "
                       f"{words}")


class DtpsTarget(RobotTarget):
    """The DTPS robot at ``address`` (a :class:`DtpsAddress` or its text), driven with ``options`` at ``frame_rate``
    [Hz] (the proxies' rate)."""

    what = "DTPS robot"

    def __init__(self, address: DtpsAddress | str, options: DtpsRobotOptions | None = None,
                 frame_rate: float = DEFAULT_FRAME_RATE):
        try:
            self.address = parse_address(address) if isinstance(address, str) else address
        except ValueError as exc:
            raise TargetError(f"target: {exc}") from None
        super().__init__(f"dtps:{self.address}", 1, None, frame_rate)
        self.options = options or DtpsRobotOptions()

    def domain(self, image_size: tuple[int, int] | None = None) -> DomainSpec:
        return DomainSpec.dtps(self.address, frame_rate=self.frame_rate, options=self.options)

    def planned_poses(self, map_name: str, episodes: list[int], seeds: list[int]) -> list[Any]:
        """prompt: the pose each seed draws (the operator is asked to place the robot there); teleport: none
        (the robot goes where ``state/reset`` puts it); pose-file: the file's."""
        if self.options.reset == "teleport":
            return [None] * len(seeds)
        if self.options.reset == "pose-file":
            try:
                table = load_start_poses(self.options.start_poses, episodes)  # type: ignore[arg-type]
            except ValueError as exc:
                raise TargetError(f"dtps start_poses: {exc}") from None
            return [table[e] for e in episodes]
        return super().planned_poses(map_name, episodes, seeds)

    def started_at(self, job: Job, result) -> tuple[float, float, float] | None:
        """Where the robot stood at t = 0 (its pose source said so): the proxies start there too."""
        from proxybench.tasks.trajectory import Trajectory

        if result.trajectory:
            try:
                t = Trajectory.load(result.trajectory)
                return (float(t["x"][0]), float(t["y"][0]), float(t["theta"][0]))
            except (ValueError, OSError, KeyError):
                pass
        return job.pose

    def info(self) -> TargetInfo:
        simulated, sentence = describe_robot(self.address, self.options)
        return TargetInfo(
            "robot", simulated, f"DTPS robot: {self.address}",
            f"The target is {sentence}. Treat results as real only if this address is a physical robot.",
            {"address": str(self.address), "link": "dtps", "options": self.options.non_default()})
