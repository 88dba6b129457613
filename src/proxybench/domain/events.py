"""What an episode's record says happened: why it ended (:class:`Termination`) and its events (:class:`Event`).

Termination values are the strings trajectory files, job results, result tables and the server's stored reports
have always held: a member *is* its string (``Termination.TIMEOUT == "timeout"``, it serialises as
``"timeout"`` in JSON and Parquet), so files stay byte-compatible while code names endings by member.
An :class:`Event` is one thing that happened at a time of the episode (the ending, an NPC robot that
stopped, a recording's own notes); it is a typed record in code and the same JSON object in a trajectory
file as before (:meth:`Event.to_dict` / :meth:`Event.from_dict`), so files stay as they were.
Both live in the domain because the domain decides two endings (``episode_end``); ``tasks.trajectory``
re-exports them next to the trajectory that records them.

>>> Termination("off_road") is Termination.OFF_ROAD, f"{Termination.COLLISION}"
(True, 'collision')
>>> e = Event.from_dict({"t": 2.5, "kind": "collision", "with": "duckie", "message": "too close"})
>>> e.kind is Termination.COLLISION, e.with_, e.to_dict()
(True, 'duckie', {'t': 2.5, 'kind': 'collision', 'message': 'too close', 'with': 'duckie'})
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

__all__ = ["EPISODE_TERMINATIONS", "Event", "Termination"]


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
    #: the agent asked for a reset (``state/reset`` of a served DTPS robot, docs/dtps.md)
    RESET = "reset"
    #: a recorded run whose samples stop before the episode's length, on the road, for a reason its file does not
    #: say
    ENDED_EARLY = "ended_early"
    #: a job result only: the robot node failed, so no episode happened (never a trajectory's ending)
    ROBOT_FAILURE = "robot_failure"


#: the endings a trajectory may record (a failed robot leaves no trajectory)
EPISODE_TERMINATIONS = tuple(t for t in Termination if t is not Termination.ROBOT_FAILURE)
_ENDINGS = frozenset(Termination)


#: the optional fields of an event, by their names in files (``with`` is a Python keyword: ``with_``)
_OPTIONAL = {"reason": "reason", "with": "with_", "exit_code": "exit_code", "stderr_tail": "stderr_tail",
             "npc": "npc"}


@dataclass(frozen=True)
class Event:
    """Something that happened in an episode at time ``t`` [s].

    ``kind``: a :class:`Termination` for the event that ended the episode, else another word
    (``npc_stopped``; a recording's ``tracking_lost``, ...); ``message``: what happened, in words.
    ``reason`` (agent_failure: why, e.g. ``exited``, ``timeout``), ``exit_code`` and ``stderr_tail`` (a node's
    exit status and last stderr lines), ``with_`` (collision: what was hit; ``with`` in files), ``npc``
    (npc_stopped: which NPC robot of the world). ``extra``: fields another writer added, kept as they are.
    """

    t: float
    kind: str
    message: str = ""
    reason: str | None = None
    with_: str | None = None
    exit_code: int | None = None
    stderr_tail: tuple[str, ...] = ()
    npc: int | None = None
    extra: Mapping[str, Any] = field(default_factory=dict, hash=False)

    def to_dict(self) -> dict[str, Any]:
        """The event as a trajectory file holds it: ``t``, ``kind``, ``message``, then the fields that are set."""
        out: dict[str, Any] = {"t": self.t, "kind": str(self.kind), "message": self.message}
        for key, attr in _OPTIONAL.items():
            value = getattr(self, attr)
            if value is not None and value != ():
                out[key] = list(value) if attr == "stderr_tail" else value
        return {**out, **self.extra}

    @classmethod
    def from_dict(cls, data: Any) -> Event:
        """An event from its file form; a malformed one raises ``ValueError`` naming the field."""
        if not isinstance(data, Mapping):
            raise ValueError(f"an event must be a mapping, got {type(data).__name__}")
        t, kind, message = data.get("t"), data.get("kind"), data.get("message", "")
        if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t):
            raise ValueError(f"event field 't' must be a finite number [s], got {t!r}")
        if not (isinstance(kind, str) and kind):
            raise ValueError(f"event field 'kind' must be a non-empty string, got {kind!r}")
        if not isinstance(message, str):
            raise ValueError(f"event field 'message' must be a string, got {message!r}")
        fields: dict[str, Any] = {}
        for key, attr in _OPTIONAL.items():
            value = data.get(key)
            if value is None:
                continue
            fields[attr] = _checked(key, value)
        extra = {k: v for k, v in data.items() if k not in ("t", "kind", "message", *_OPTIONAL)}
        kind = Termination(kind) if kind in _ENDINGS else kind
        return cls(float(t), kind, message, **fields, extra=extra)


def _checked(key: str, value: Any) -> Any:
    """An optional field's value in its type (``stderr_tail``: lines; ``exit_code``, ``npc``: integers)."""
    if key == "stderr_tail":
        if not (isinstance(value, list | tuple) and all(isinstance(line, str) for line in value)):
            raise ValueError(f"event field 'stderr_tail' must be a list of strings, got {value!r}")
        return tuple(value)
    if key in ("exit_code", "npc"):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"event field {key!r} must be an integer, got {value!r}")
        return value
    if not isinstance(value, str):
        raise ValueError(f"event field {key!r} must be a string, got {value!r}")
    return value
