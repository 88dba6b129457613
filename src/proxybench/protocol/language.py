"""The AIDO agent protocol's language, checked on both sides of the wire.

``(in:seed)? ; ((in:episode_start ; ((in:observations | (in:get_commands ; out:commands))*))*)``

Every input is answered before the next one is read, so the language reduces to a three-state machine
over inputs plus, per input, the outputs its answer must hold. Meta topics (``wrapper.*``) are outside the
language and allowed at any time.
"""

from __future__ import annotations

__all__ = ["AGENT_LANGUAGE", "DATA_INPUTS", "DATA_REPLIES", "META_LANGUAGE", "META_REPLIES", "AgentLanguage"]

AGENT_LANGUAGE = "(in:seed)? ; ((in:episode_start ; ((in:observations | (in:get_commands ; out:commands))*))*)"
META_LANGUAGE = (
    "((in:describe_config ; out:config_description) | (in:set_config ; (out:set_config_ack | "
    "out:set_config_error)) | (in:describe_protocol ; out:protocol_description) | (in:describe_node ; "
    "out:node_description) | (in:describe_build ; out:build_description) | (in:get_state ; out:node_state) | "
    "(in:set_state ; (out:set_state_ack | out:set_state_error)) | (in:get_logs ; out:logs) | out:aborted)*"
)
DATA_INPUTS = ("episode_start", "get_commands", "observations", "seed")
#: data input → the outputs its answer holds, in order (each exactly once)
DATA_REPLIES: dict[str, tuple[str, ...]] = {
    "seed": (), "episode_start": (), "observations": (), "get_commands": ("commands",),
}
#: meta input (without the ``wrapper.`` prefix) → the outputs of which its answer holds exactly one
META_REPLIES: dict[str, frozenset[str]] = {
    "describe_config": frozenset({"config_description"}),
    "set_config": frozenset({"set_config_ack", "set_config_error"}),
    "describe_protocol": frozenset({"protocol_description"}),
    "describe_node": frozenset({"node_description"}),
    "describe_build": frozenset({"build_description"}),
    "get_state": frozenset({"node_state"}),
    "set_state": frozenset({"set_state_ack", "set_state_error"}),
    "get_logs": frozenset({"logs"}),
}
#: every topic a node may write: the agent protocol's output, the meta outputs, and the meta ``aborted``
NODE_OUTPUTS = frozenset({"commands", "aborted"}.union(*META_REPLIES.values()))

_START, _SEEDED, _EPISODE = "start", "seeded", "episode"
_ALLOWED = {
    _START: ("seed", "episode_start"),
    _SEEDED: ("episode_start",),
    _EPISODE: ("episode_start", "observations", "get_commands"),
}


class AgentLanguage:
    """Tracks where a conversation is in the agent language; :meth:`check` says what an input breaks."""

    def __init__(self) -> None:
        self.state = _START

    @property
    def expected(self) -> tuple[str, ...]:
        """Inputs allowed now."""
        return _ALLOWED[self.state]

    def check(self, topic: str) -> str | None:
        """Why input ``topic`` is not allowed now, or None if it is."""
        if topic in _ALLOWED[self.state]:
            return None
        return f'Unexpected input "{topic}"; I expected one of {list(self.expected)} (state: {self.state}).'

    def push(self, topic: str) -> None:
        """Advance past input ``topic`` (which :meth:`check` allowed)."""
        if topic == "seed":
            self.state = _SEEDED
        elif topic == "episode_start":
            self.state = _EPISODE
