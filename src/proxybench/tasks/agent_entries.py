"""The ``agents:`` entries of a benchmark file: the agents ``proxybench evaluate`` runs when none are named.

An entry is a zoo agent's name, or a mapping naming an agent *node* — any program speaking the AIDO agent
protocol — with how to start it (the fields of :class:`~proxybench.protocol.options.NodeOptions`). A
``cwd`` is a folder inside the file's folder, named relative to it (no ``..``, no absolute path or ``~``,
no link on the way), which is also the default; whether it exists is checked when the agent starts, so a
file naming agents of another machine still loads. (To run a node elsewhere, give it on the command line:
``--agent NAME=COMMAND`` with ``--agent-cwd``.)::

    agents:
      - pid                                   # a built-in agent
      - name: my-lf                           # a label for the leaderboard
        command: cd solution && exec python3 solution.py   # as typed in a shell (shell syntax allowed)
        cwd: submissions/my-lf                # inside this file's folder (default: the folder itself)
        transport: fifo                       # pipe | fifo (AIDO's default)
        start_timeout: 60                     # s: start + handshake, and each setup message
        step_timeout: 2                       # s: each observations + get_commands exchange
        reflection: false                     # skip describe_protocol
      - name: my-sdk                          # a duckietown-sdk program (docs/dtps.md)
        sdk: python3 agent.py                 # instead of command:
        timing: lockstep                      # realtime (default) | lockstep
        privileged: false                     # true: the true pose on state/pose

Unknown keys are errors naming the entry (``agents.1.transprot: unknown key (did you mean transport?)``).
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from proxybench.protocol.options import NodeOptions
from proxybench.untrusted import UntrustedInputError, inside

__all__ = ["AgentEntry", "agent_entry_issues", "as_entry", "resolve_agent_cwd"]


class AgentEntry(NodeOptions):
    """One agent of a benchmark: a zoo agent (``name`` only; a bare string in the file), or a node: ``name``
    (its label), ``command`` (a string, run through a shell when it uses shell syntax, or an argv list) and
    the start-up options of :class:`NodeOptions`."""

    name: str = Field(min_length=1, max_length=64, description="zoo agent, or the label of an agent node")
    command: str | list[str] | None = Field(None, description="the node command: as typed in a shell, or argv")
    sdk: str | list[str] | None = Field(None, description="a duckietown-sdk program's command (instead of command)")
    timing: Literal["realtime", "lockstep"] | None = Field(None, description="sdk: realtime (default) | lockstep")
    privileged: bool | None = Field(None, description="sdk: publish the true pose on state/pose")

    @field_validator("command", "sdk")
    @classmethod
    def _not_empty(cls, cmd: str | list[str] | None) -> str | list[str] | None:
        if (isinstance(cmd, str) and not cmd.strip()) or (isinstance(cmd, list) and (not cmd or not cmd[0])):
            raise ValueError("empty command")
        return cmd

    @model_validator(mode="after")
    def _options_need_command(self) -> AgentEntry:
        options = [k for k in NodeOptions.model_fields if k in self.model_fields_set]
        if self.command is not None and self.sdk is not None:
            raise ValueError("give command (an AIDO agent node) or sdk (a duckietown-sdk program), not both")
        if self.sdk is not None:
            wrong = [k for k in ("transport", "fifo_dir", "reflection") if k in options]
            if wrong:
                raise ValueError(f"{', '.join(wrong)}: not options of an sdk agent (it talks DTPS, not over pipes)")
            return self
        sdk_only = [k for k in ("timing", "privileged") if k in self.model_fields_set]
        if sdk_only:
            raise ValueError(f"{', '.join(sdk_only)}: options of an sdk agent (give sdk: instead of command:)")
        if self.command is None and options:
            raise ValueError(f"{', '.join(options)}: start-up options need a command (a zoo agent runs in-process)")
        return self

    @property
    def is_node(self) -> bool:
        return self.command is not None or self.sdk is not None

    @property
    def is_sdk(self) -> bool:
        return self.sdk is not None

    @property
    def sdk_line(self) -> str | None:
        """The sdk command as one string (an argv list is quoted)."""
        return self.sdk if self.sdk is None or isinstance(self.sdk, str) else shlex.join(self.sdk)

    def sdk_options(self):
        """The ``SdkOptions`` of an sdk entry (fields not written take SdkOptions' defaults)."""
        from proxybench.dtps.options import SdkOptions

        given = {k: getattr(self, k) for k in ("cwd", "start_timeout", "step_timeout", "timing", "privileged")
                 if k in self.model_fields_set or (k == "cwd" and self.cwd is not None)}
        return SdkOptions(**given)

    @property
    def command_line(self) -> str | None:
        """The command as one string (an argv list is quoted, so it still runs without a shell)."""
        if self.command is None or isinstance(self.command, str):
            return self.command
        return shlex.join(self.command)

    def node_options(self) -> NodeOptions:
        return NodeOptions(**{k: getattr(self, k) for k in NodeOptions.model_fields})


def as_entry(value: Any) -> Any:
    """A bare string in the file is a zoo agent's name."""
    return {"name": value} if isinstance(value, str) else value


def resolve_agent_cwd(entry: AgentEntry, base_dir: Path | None) -> AgentEntry:
    """A node's ``cwd`` as an absolute folder inside the file's folder ``base_dir`` (that folder when not given).
    Raises ValueError (``cwd: …``) for a path that leaves it (:func:`proxybench.untrusted.inside`)."""
    if base_dir is None or not entry.is_node:
        return entry
    try:
        resolved = inside(base_dir, entry.cwd, field="cwd") if entry.cwd is not None else Path(base_dir).resolve()
    except UntrustedInputError as exc:
        raise ValueError(str(exc)) from None
    return entry.model_copy(update={"cwd": str(resolved)})


def agent_entry_issues(entries: list[AgentEntry], zoo: dict[str, Any]) -> list[tuple[str, str]]:
    """(field path, problem) for unknown zoo names and labels used twice."""
    issues, seen = [], set()
    for i, e in enumerate(entries):
        if not e.is_node and e.name not in zoo:
            issues.append((f"agents.{i}.name", f"unknown agent {e.name!r} (built-in: {', '.join(zoo)}; for an agent "
                                               f"node give name and command)"))
        if e.name in seen:
            issues.append((f"agents.{i}.name", f"agent {e.name!r} is listed twice"))
        seen.add(e.name)
    return issues
