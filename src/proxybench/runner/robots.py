"""How a robot domain is reached: a robot node process (the robot protocol) or a DTPS robot.

A robot domain (:class:`~.jobs.RobotDomain`) says by its ``link`` which (a :class:`~.jobs.ProtocolLink` or a
:class:`~.jobs.DtpsLink`): :func:`open_robot` starts the node
(:class:`~proxybench.protocol.RemoteRobot`) or the DTPS bridge (:class:`~.dtps_plant.DtpsRobot`) and gives a
connection that makes a plant for each episode's map and closes once for the batch. The runner's robot jobs,
the probe and the recorder all open robots here, so every place that drives a robot drives both kinds.
"""

from __future__ import annotations

from typing import Any, Protocol

from proxybench.domain.maps import Map
from proxybench.runner.jobs import DtpsLink, LabWorldLink, ProtocolLink, RobotDomain

__all__ = ["RobotConnection", "open_robot"]


class RobotConnection(Protocol):
    """A robot reached for a batch of episodes: a plant per episode's map, closed once."""

    def plant(self, map_: Map) -> Any: ...

    def close(self) -> Any: ...


class _NodeRobot:
    """A robot node process (the robot protocol), its episodes played by a :class:`RobotPlant`."""

    def __init__(self, link: ProtocolLink, frame_rate: float):
        from proxybench.protocol import RemoteRobot

        self.robot = RemoteRobot(link.command, frame_rate=frame_rate, **link.node_options().process_kwargs())

    def plant(self, map_: Map) -> Any:
        from proxybench.runner.robot_episode import RobotPlant

        return RobotPlant(self.robot, map_)

    def close(self) -> None:
        self.robot.close()


class _LabWorldRobot:
    """A robot of a lab's shared world (:mod:`.lab_world`), its episodes played by a :class:`LabWorldPlant`."""

    def __init__(self, link: LabWorldLink):
        from proxybench.runner.lab_world import LabWorldAddress, connect

        self.link = link
        self.conn = connect(LabWorldAddress(link.path, bytes.fromhex(link.key)), link.robot)
        self.plants = 0

    def plant(self, map_: Map) -> Any:
        from proxybench.runner.lab_world import LabWorldPlant
        from proxybench.runner.outcomes import camera_filter

        plant = LabWorldPlant(self.conn, self.link.robot, map_, self.link.params, self.link.streams, camera_filter())
        plant.begun = self.plants  # each episode's streams in a folder of its own, across the batch
        self.plants += 1
        return plant

    def close(self) -> None:
        self.conn.close()


def open_robot(domain: RobotDomain, frame_rate: float | None = None) -> RobotConnection:
    """Reach the robot of ``domain`` (stepped at ``frame_rate`` [Hz], default the domain's). A robot that cannot
    be reached raises :class:`~proxybench.protocol.RobotFailure`."""
    rate = frame_rate or domain.frame_rate
    link = domain.link
    if isinstance(link, LabWorldLink):
        return _LabWorldRobot(link)
    if isinstance(link, DtpsLink):
        from proxybench.runner.dtps_plant import DtpsRobot

        return DtpsRobot(link.address, link.node_options(), rate)
    return _NodeRobot(link, rate)
