"""The AIDO agent wire protocol: serve proxybench agents as nodes, and drive any node as an agent.

- :func:`serve` turns a Python :class:`~proxybench.agents.base.Agent` into a node that speaks what an
  unmodified AIDO (zuper-nodes) agent node speaks.
- :class:`AgentProcess` runs a node command and talks to it; :class:`RemoteAgent` wraps it as an
  ``Agent`` for the runner. Every misbehaviour ends in :class:`AgentFailure` with a stable reason code.
- :mod:`.wire` (bytes and messages) and :mod:`.jpeg` (the camera codec) are the shared layers.

See docs/protocol.md for the specification, the privileged extension and the failure table.
"""

from proxybench.protocol import jpeg, wire
from proxybench.protocol.failures import REASONS, AgentFailure, ProtocolUsageError
from proxybench.protocol.node import serve
from proxybench.protocol.process import AgentProcess
from proxybench.protocol.remote import RemoteAgent

__all__ = ["REASONS", "AgentFailure", "AgentProcess", "ProtocolUsageError", "RemoteAgent", "jpeg", "serve", "wire"]
