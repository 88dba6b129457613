"""How a robot domain is reached: a robot node process (the robot protocol) or a DTPS robot.

A robot domain (``DomainSpec(kind="robot")``) says by its ``link`` which: :func:`open_robot` starts the node
(:class:`~proxybench.protocol.RemoteRobot`) or the DTPS bridge (:class:`~.dtps_plant.DtpsRobot`) and gives a
connection that makes a plant for each episode's map and closes once for the batch. The runner's robot jobs,
the probe and the recorder all open robots here, so every place that drives a robot drives both kinds.
"""

from __future__ import annotations

from typing import Any, Protocol

from proxybench.domain.maps import Map
from proxybench.runner.jobs import DomainSpec

__all__ = ["RobotConnection", "open_robot"]


class RobotConnection(Protocol):
    """A robot reached for a batch of episodes: a plant per episode's map, closed once."""

    def plant(self, map_: Map) -> Any: ...

    def close(self) -> Any: ...


class _NodeRobot:
    """A robot node process (the robot protocol), its episodes played by a :class:`RobotPlant`."""

    def __init__(self, domain: DomainSpec, frame_rate: float):
        from proxybench.protocol import RemoteRobot

        self.robot = RemoteRobot(domain.command, frame_rate=frame_rate, **domain.node_options().process_kwargs())

    def plant(self, map_: Map) -> Any:
        from proxybench.runner.robot_episode import RobotPlant

        return RobotPlant(self.robot, map_)

    def close(self) -> None:
        self.robot.close()


def open_robot(domain: DomainSpec, frame_rate: float | None = None) -> RobotConnection:
    """Reach the robot of ``domain`` (stepped at ``frame_rate`` [Hz], default the domain's). A robot that cannot
    be reached raises :class:`~proxybench.protocol.RobotFailure`."""
    rate = frame_rate or domain.frame_rate
    if domain.link == "dtps":
        from proxybench.dtps.robot_options import parse_address
        from proxybench.runner.dtps_plant import DtpsRobot

        return DtpsRobot(parse_address(domain.command), domain.node_options(), rate)
    return _NodeRobot(domain, rate)
