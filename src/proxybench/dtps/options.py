"""How an SDK agent is started and timed: :class:`SdkOptions`, and the ``sdk:`` form of an agent argument.

``NAME=sdk:COMMAND`` runs COMMAND (as typed in a shell) against a virtual DB21J in real time;
``NAME=sdk[lockstep]:COMMAND`` steps it frame by frame (reproducible, see docs/dtps.md), and
``sdk[privileged]:`` also publishes the true pose on ``state/pose`` (ground truth: such an agent is ranked
as privileged). Modifiers combine: ``sdk[lockstep,privileged]:``.

>>> parse_sdk("sdk[lockstep]:python3 agent.py")
('python3 agent.py', {'timing': 'lockstep'})
>>> parse_sdk("python3 agent.py") is None
True
"""

from __future__ import annotations

import re
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["SDK_PREFIX", "SdkOptions", "parse_sdk"]

SDK_PREFIX = "sdk"
_FORM = re.compile(r"^sdk(?:\[([a-z,\s-]*)\])?:(.*)$", re.DOTALL)
_MODIFIERS = {"lockstep": ("timing", "lockstep"), "realtime": ("timing", "realtime"),
              "privileged": ("privileged", True)}


class SdkOptions(BaseModel):
    """Start-up and timing of one SDK agent program.

    ``cwd``: its working directory. ``start_timeout`` [s]: from its start until its first wheel command
    (importing the SDK and connecting take a few seconds). ``step_timeout`` [s]: real time: the longest
    silence between two commands; lock-step: the longest wait for one frame's command. ``timing``:
    ``realtime`` (the simulation runs at the camera's rate in wall time, as on a robot) or ``lockstep``
    (each frame waits for its command). ``privileged``: publish the true pose on ``state/pose``. ``own_netns``
    (set by the evaluator for agent packages, needs root): the virtual robot serves in a network namespace
    of its own, whose path the program is given in ``$PROXYBENCH_DTPS_NETNS`` for its sandbox to join.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    cwd: str | None = Field(None, min_length=1, description="working directory of the command")
    start_timeout: float = Field(60.0, gt=0.0, allow_inf_nan=False, description="start until the first command [s]")
    step_timeout: float = Field(5.0, gt=0.0, allow_inf_nan=False, description="longest wait for a command [s]")
    timing: Literal["realtime", "lockstep"] = Field("realtime", description="realtime | lockstep")
    privileged: bool = Field(False, description="publish the true pose on state/pose")
    own_netns: bool = Field(False, description="the virtual robot in a network namespace of its own, which the "
                                              "agent's sandbox joins (the evaluator's packages; needs root)")

    def non_default(self) -> dict[str, Any]:
        return self.model_dump(exclude_defaults=True)

    def items(self) -> tuple[tuple[str, Any], ...]:
        """The non-default fields as sorted pairs (hashable, for ``AgentSpec``)."""
        return tuple(sorted(self.non_default().items()))


def parse_sdk(text: str) -> tuple[str, dict[str, Any]] | None:
    """``sdk[mods]:COMMAND`` → (COMMAND, option fields the modifiers set); None when ``text`` is not that form.
    An unknown modifier or an empty command is a ``ValueError`` naming it."""
    m = _FORM.match(text.strip())
    if m is None:
        return None
    fields: dict[str, Any] = {}
    for mod in filter(None, (w.strip() for w in (m.group(1) or "").split(","))):
        if mod not in _MODIFIERS:
            raise ValueError(f"unknown sdk modifier {mod!r} (known: {', '.join(_MODIFIERS)})")
        key, value = _MODIFIERS[mod]
        fields[key] = value
    command = m.group(2).strip()
    if not command:
        raise ValueError(f"{text!r}: no command after 'sdk:'")
    return command, fields
