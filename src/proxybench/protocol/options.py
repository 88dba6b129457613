"""How to start a node and talk to it: the options a user writes next to an agent command.

One validated model, :class:`NodeOptions`, serves every place a node command is accepted — the CLI
(``--agent-cwd``, ``--transport``, ``--start-timeout``, ``--step-timeout``, ``--no-reflection``), benchmark
files (``agents:`` entries), agent package manifests, :class:`~proxybench.runner.jobs.AgentSpec` — so
each spells the same fields the same way and rejects the same mistakes, naming the field.

>>> NodeOptions(transport="fifo", step_timeout=2).process_kwargs()["transport"]
'fifos'
>>> NodeOptions().non_default()
{}
>>> RobotNodeOptions().process_kwargs()["init_timeout"]
120.0
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["MAX_TIMEOUT_S", "NODE_OPTION_FIELDS", "NodeOptions", "RobotNodeOptions"]

#: the longest timeout a node may be given [s]: a day (the kernel's waits take at most 2^31 ms, ~24.8 days;
#: a larger value, 1e300 say, was an OverflowError when the node started)
MAX_TIMEOUT_S = 86_400.0


class NodeOptions(BaseModel):
    """Start-up and transport options of one node process (agent or robot).

    ``cwd``: working directory of the command (relative paths are taken from where it is written: the
    benchmark file's folder, the package folder). ``transport``: ``pipe`` (stdin/stdout) or ``fifo``
    (AIDO's default: the node reads ``AIDONODE_DATA_IN`` and creates ``AIDONODE_DATA_OUT``, so what it
    prints to stdout cannot break the protocol). ``fifo_dir``: where the FIFOs are made (default: a
    private temporary folder; give a folder a container mounts). ``start_timeout`` [s]: start +
    handshake, and each setup message (seed, episode start). ``step_timeout`` [s]: each per-frame
    exchange. ``reflection``: ask the node for its protocol description (``describe_protocol``); a node
    that fails the request is started again without it, so ``false`` only saves that restart.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    cwd: str | None = Field(None, min_length=1, description="working directory of the command")
    transport: Literal["pipe", "fifo"] = Field("pipe", description="pipe (stdin/stdout) or fifo (AIDO's default)")
    fifo_dir: str | None = Field(None, min_length=1, description="folder for the FIFOs (transport fifo)")
    start_timeout: float = Field(30.0, gt=0.0, le=MAX_TIMEOUT_S, allow_inf_nan=False,
                                 description="start + handshake, setup [s]")
    step_timeout: float = Field(5.0, gt=0.0, le=MAX_TIMEOUT_S, allow_inf_nan=False,
                                description="each per-frame exchange [s]")
    reflection: bool = Field(True, description="ask describe_protocol (falls back without it on failure)")

    def process_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :class:`~proxybench.protocol.process.NodeProcess` (and its subclasses)."""
        return {"cwd": self.cwd, "transport": self.transport + "s", "fifo_dir": self.fifo_dir,
                "init_timeout": self.start_timeout, "step_timeout": self.step_timeout,
                "reflection": self.reflection}

    def non_default(self) -> dict[str, Any]:
        """The fields that differ from the defaults (what identifies these options in a job's hash)."""
        return self.model_dump(exclude_defaults=True)

    def items(self) -> tuple[tuple[str, Any], ...]:
        """:meth:`non_default` as sorted pairs: hashable, for frozen dataclasses such as ``AgentSpec``."""
        return tuple(sorted(self.non_default().items()))


class RobotNodeOptions(NodeOptions):
    """:class:`NodeOptions` of a robot node (``run --robot-cmd``, ``--target robot:CMD``, a robot domain): the
    same fields, with longer default timeouts, since a robot node may start a simulator or reach hardware
    before it answers (120 s), and a robot stepping in real time needs longer than one step (10 s)."""

    start_timeout: float = Field(120.0, gt=0.0, le=MAX_TIMEOUT_S, allow_inf_nan=False,
                                 description="start + handshake, setup [s]")
    step_timeout: float = Field(10.0, gt=0.0, le=MAX_TIMEOUT_S, allow_inf_nan=False,
                                description="each per-frame exchange [s]")


#: the option names, for error messages and manifests
NODE_OPTION_FIELDS = tuple(NodeOptions.model_fields)
