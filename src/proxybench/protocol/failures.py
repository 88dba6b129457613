"""How a remote node (agent or robot) can fail, as stable short reason codes.

A node process failing is a normal outcome of an evaluation, not a bug of the caller: every way a node
can misbehave ends in one :class:`NodeFailure` — :class:`AgentFailure` for agent nodes, :class:`RobotFailure`
for robot nodes — whose ``reason`` is one of its class's reasons (:data:`REASONS`, :data:`ROBOT_REASONS`),
so result tables can count failures by kind, and whose process has already been reaped when it is raised.
"""

from __future__ import annotations

__all__ = ["REASONS", "ROBOT_REASONS", "AgentFailure", "NodeFailure", "ProtocolUsageError", "RobotFailure"]

#: reason code → when it is raised (the table in docs/protocol.md is generated from the same words)
REASONS: dict[str, str] = {
    "start-failed": "the command could not be started (not found, not executable)",
    "exited": "the process ended (or closed its output) while an answer was expected",
    "garbage": "bytes that are not CBOR, or plain text written to the protocol stream",
    "not-a-map": "a well-formed CBOR value that is not a map",
    "truncated": "the output ended in the middle of a CBOR message",
    "bad-message": "a CBOR map that is neither a valid control nor a valid topic message",
    "unknown-topic": "a topic message whose topic is not an output of the protocol",
    "not-understood": "the node answered `not-understood`",
    "aborted": "the node answered `aborted` (its traceback is the detail)",
    "out-of-order": "a message the protocol does not allow at that point",
    "bad-commands": "commands that are not two finite numbers in [-1, 1]",
    "incompatible": "the node's protocol description lacks the agent protocol's topics",
    "init-timeout": "no complete answer within the init timeout (start, handshake, seed, episode_start)",
    "step-timeout": "no complete answer within the step timeout (observations, get_commands)",
    "stdout-flood": "more bytes or messages on the protocol stream than one answer may hold",
    "stderr-flood": "more stderr output during one request than allowed",
}


#: reason code → when a robot node's failure is raised (the table in docs/robot-protocol.md)
ROBOT_REASONS: dict[str, str] = {
    **{k: v for k, v in REASONS.items() if k not in ("bad-commands", "incompatible", "init-timeout", "step-timeout")},
    "bad-data": "an output whose data lacks a field or has the wrong type (robot_observations, robot_state, ...)",
    "incompatible": "the node's protocol description lacks the robot protocol's topics",
    "init-timeout": "no complete answer within the init timeout (start, handshake, seed, episode setup)",
    "step-timeout": "no complete answer within the step timeout (commands, step, observations, state)",
    "connection-lost": "a DTPS robot's camera or pose stopped arriving, or its command publisher lost the robot",
}


class NodeFailure(Exception):
    """A node process failed; the process is already reaped when this is raised.

    ``reason`` is a key of the class's ``REASONS``; ``detail`` is human-readable (for ``aborted``, the node's
    traceback); ``exit_code`` is the process's exit status (negative: killed by that signal; None: never
    started); ``stderr_tail`` holds its last stderr lines; ``pid`` is the reaped process's id.
    """

    REASONS: dict[str, str] = REASONS

    def __init__(self, reason: str, detail: str, exit_code: int | None = None,
                 stderr_tail: list[str] | None = None, *, pid: int | None = None):
        if reason not in self.REASONS:
            raise ValueError(f"unknown {type(self).__name__} reason {reason!r}")
        self.reason = reason
        self.detail = detail
        self.exit_code = exit_code
        self.stderr_tail = list(stderr_tail or [])
        self.pid = pid
        super().__init__(reason, detail)

    def __str__(self) -> str:
        text = f"{self.reason}: {self.detail}"
        if self.exit_code is not None:
            text += f" (exit code {self.exit_code})"
        if self.stderr_tail:
            text += "\nlast stderr lines:\n" + "\n".join("  " + line for line in self.stderr_tail[-10:])
        return text

    def __reduce__(self):  # pickle-able for multi-process runners
        return (_rebuild, (type(self), self.reason, self.detail, self.exit_code, self.stderr_tail, self.pid))


class AgentFailure(NodeFailure):
    """A remote agent failed (reasons: :data:`REASONS`); the process is already reaped."""


class RobotFailure(NodeFailure):
    """A robot node failed (reasons: :data:`ROBOT_REASONS`); the process is already reaped.

    Not an agent's fault: an episode whose robot failed has no valid trajectory, so the runner raises this
    instead of recording an ``agent_failure``.
    """

    REASONS = ROBOT_REASONS


class ProtocolUsageError(RuntimeError):
    """The *caller* asked for something the protocol does not allow (e.g. ``get_commands`` before
    ``episode_start``); nothing was sent and the node is left untouched."""


def _rebuild(cls: type[NodeFailure], reason: str, detail: str, exit_code: int | None, stderr_tail: list[str],
             pid: int | None) -> NodeFailure:
    return cls(reason, detail, exit_code, stderr_tail, pid=pid)
