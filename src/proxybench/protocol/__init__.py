"""The AIDO wire protocols: agents and robots as nodes, served by proxybench or driven by it.

- :func:`serve` turns a Python :class:`~proxybench.agents.base.Agent` into a node that speaks what an
  unmodified AIDO (zuper-nodes) agent node speaks.
- :class:`AgentProcess` runs a node command and talks to it; :class:`RemoteAgent` wraps it as an
  ``Agent`` for the runner. Every misbehaviour ends in :class:`AgentFailure` with a stable reason code.
- Robots (AIDO's simulator protocol, one robot): :class:`~.robot_node.RobotNode` serves the proxybench
  simulator as a robot node; :class:`RobotProcess` / :class:`RemoteRobot` drive any robot node (a simulator
  or a physical robot's bridge), failing with :class:`RobotFailure`.
- :mod:`.wire`, :mod:`.robot_wire` (bytes and messages) and :mod:`.jpeg` (the camera codec) are the shared
  layers.

See docs/protocol.md (agents) and docs/robot-protocol.md (robots). The names below load on first use
(:mod:`proxybench.lazy`), so :mod:`.options` alone is light.
"""

from proxybench.lazy import lazy_exports

_FROM = {"failures": ("REASONS", "ROBOT_REASONS", "AgentFailure", "NodeFailure", "ProtocolUsageError", "RobotFailure"),
         "node": ("serve",), "process": ("AgentProcess",), "remote": ("RemoteAgent",),
         "robot_process": ("RemoteRobot", "RobotProcess")}
__getattr__ = lazy_exports(__name__, {n: f"{__name__}.{m}" for m, names in _FROM.items() for n in names})

__all__ = [
    "REASONS", "ROBOT_REASONS", "AgentFailure", "AgentProcess", "NodeFailure", "ProtocolUsageError", "RemoteAgent",
    "RemoteRobot", "RobotFailure", "RobotProcess", "jpeg", "serve", "wire",
]
