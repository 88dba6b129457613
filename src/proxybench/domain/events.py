"""Why an episode ended: :class:`Termination`, one name per ending, the same strings in every file.

The values are the strings trajectory files, job results, result tables and the server's stored reports
have always held: a member *is* its string (``Termination.TIMEOUT == "timeout"``, it serialises as
``"timeout"`` in JSON and Parquet), so files stay byte-compatible while code names endings by member.
It lives in the domain because the domain decides two of them (``episode_end``); ``tasks.trajectory``
re-exports it next to the trajectory that records it.

>>> Termination("off_road") is Termination.OFF_ROAD, f"{Termination.COLLISION}"
(True, 'collision')
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["EPISODE_TERMINATIONS", "Termination"]


class Termination(StrEnum):
    """Why an episode ended."""

    #: the episode's time is up (its frames are spent): the normal end
    TIMEOUT = "timeout"
    #: the robot's centre left the drivable area (a robot node's out-of-lane / out-of-tile, too)
    OFF_ROAD = "off_road"
    #: a recorded pose lies off the map (an imported run ends there)
    LEFT_MAP = "left_map"
    #: the robot touched a map object, a duckie, a pedestrian or a robot
    COLLISION = "collision"
    #: the agent raised, hung, died or answered anything but two finite wheel commands
    AGENT_FAILURE = "agent_failure"
    #: a job result only: the robot node failed, so no episode happened (never a trajectory's ending)
    ROBOT_FAILURE = "robot_failure"


#: the endings a trajectory may record (a failed robot leaves no trajectory)
EPISODE_TERMINATIONS = tuple(t for t in Termination if t is not Termination.ROBOT_FAILURE)
