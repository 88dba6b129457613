"""What kind of domain an episode ran in: :class:`DomainKind`, one vocabulary for jobs, targets, files and reports.

The values are the strings files already hold, so a member equals and serialises as its string. Who uses
which members:

- a job's domain (``runner.jobs.DomainSpec.kind``): ``simulation`` (a proxy instance S_θ), ``reality-model``
  (the built-in stand-in target) or ``robot`` (a robot node on the robot protocol); a recording is read, not run;
- a target (``targets.base.TargetInfo.kind``): ``reality-model``, ``robot`` or ``recorded`` (a directory of
  recorded episodes);
- a trajectory's metadata: ``domain_kind`` (its job's domain kind) and ``source`` (who made the samples:
  ``simulation`` / ``reality-model`` from the runner, ``recorded`` for an imported file; on a robot node, the
  node's own word for what it is, e.g. ``simulation`` for ``proxybench robot serve``: a word from outside,
  kept as it came);
- the evaluator's report (``domain_kind``): the kind of a simulated domain, and for a robot node
  :func:`robot_node_kind` (``robot-node/<what the node says it is>``), so a simulator behind the protocol is
  never called a robot.

Where a vocabulary differs on purpose, a documented mapping keeps it: files written for people name a robot
domain ``robot-node`` (:data:`ROBOT_NODE`: a *node*, which may be a physical robot's bridge or a simulator),
and a recording's manifest (``targets.manifest``) also knows ``real``, physical robots recorded outside
proxybench, which no domain kind names because proxybench never ran them.

>>> DomainKind("reality-model") is DomainKind.REALITY_MODEL, robot_node_kind("simulation")
(True, 'robot-node/simulation')
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["ROBOT_NODE", "DomainKind", "robot_node_kind"]


class DomainKind(StrEnum):
    """What kind of domain: where an episode's samples came from."""

    #: a simulated domain instance S_θ (proxybench's simulator, or another simulator's recordings)
    SIMULATION = "simulation"
    #: proxybench's reality model: a simulated stand-in for a real Duckiebot (effects outside the family)
    REALITY_MODEL = "reality-model"
    #: a robot node reached through the robot protocol (a physical robot's bridge, or a simulator node)
    ROBOT = "robot"
    #: episodes read from files (a lab's recordings), not run by proxybench
    RECORDED = "recorded"


#: how manifests and reports name a robot domain (:attr:`DomainKind.ROBOT`): a robot *node*
ROBOT_NODE = "robot-node"


def robot_node_kind(said: str) -> str:
    """How a report names a robot node: ``robot-node/<what the node says it is>`` (``unknown`` if unsaid)."""
    return f"{ROBOT_NODE}/{said}"
