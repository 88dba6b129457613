"""When an episode ends: the one rule every plant built on the simulator applies.

A robot's episode ends at the first frame after which it has **collided** (touched a map object, a
duckie, a pedestrian or a robot of its own world: ``Simulator.collided``) or is **off the road** (its
centre left the drivable area: ``Simulator.off_road``); a collision wins when both happen in one frame.
The episode's length (a **timeout**) and a failing agent (**agent_failure**) end it too; those are
counted by whoever runs the loop (``runner.rollout``, the robot node's frame limit, a Gymnasium
``truncated``). The in-process runner, the robot node (``protocol.robot_node``, which reports the end to its
caller), the Gymnasium envs and the learning data collector all ask this module, so they end episodes
at the same tick with the same words.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from proxybench.domain.events import Event, Termination
from proxybench.domain.worlds import HIT_KINDS

if TYPE_CHECKING:
    from proxybench.domain.simulator import Simulator

__all__ = ["END_KINDS", "end_event", "ended"]

#: the ends a plant decides, in the order they win when several happen in one frame
END_KINDS = (Termination.COLLISION, Termination.OFF_ROAD)


def ended(sim: Simulator) -> np.ndarray:
    """(N,) bool: the episode of each ego robot has ended now (a collision, or off the road)."""
    return sim.collided | sim.off_road


def end_event(sim: Simulator, i: int) -> Event:
    """Robot ``i``'s end as a trajectory event: ``t``, ``kind`` (``END_KINDS``), ``message`` and, for a
    collision, ``with_`` (what was hit). Raises if its episode has not ended."""
    t = float(sim.time[i])
    if sim.collided[i]:
        what = HIT_KINDS[int(sim.hit_kind[i])] or "map object"
        return Event(t, Termination.COLLISION, f"the robot came too close to a {what}", with_=what)
    if sim.off_road[i]:
        return Event(t, Termination.OFF_ROAD, "the robot centre left the drivable area")
    raise ValueError(f"robot {i}'s episode has not ended")
