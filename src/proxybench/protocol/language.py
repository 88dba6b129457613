"""The AIDO agent and simulator (robot) protocols' languages, checked on both sides of the wire.

Agent: ``(in:seed)? ; ((in:episode_start ; ((in:observations | (in:get_commands ; out:commands))*))*)``

Robot: AIDO's ``protocol_simulator`` (see :data:`ROBOT_LANGUAGE`).

Every input is answered before the next one is read, so each language reduces to a small state machine
over inputs plus, per input, the outputs its answer must hold. Meta topics (``wrapper.*``) are outside the
languages and allowed at any time.
"""

from __future__ import annotations

from typing import ClassVar

__all__ = [
    "AGENT_LANGUAGE", "DATA_INPUTS", "DATA_REPLIES", "META_LANGUAGE", "META_REPLIES", "ROBOT_INPUTS", "ROBOT_LANGUAGE",
    "ROBOT_OUTPUTS", "ROBOT_REPLIES", "AgentLanguage", "Language", "RobotLanguage",
]

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

#: AIDO's protocol_simulator language (as zuper writes it), which the robot node speaks whole
ROBOT_LANGUAGE = (
    "(in:seed)? ; ((in:clear ; in:set_map ; ((in:spawn_robot | in:spawn_duckie)*) ; "
    "((in:get_robot_interface_description ; out:robot_interface_description)*) ; in:episode_start ; "
    "((in:step | in:set_robot_commands | (in:get_robot_observations ; out:robot_observations) | "
    "(in:get_robot_performance ; out:robot_performance) | (in:get_robot_state ; out:robot_state) | "
    "(in:get_duckie_state ; out:duckie_state) | (in:get_sim_state ; out:sim_state) | (in:dump_state ; "
    "out:state_dump) | (in:get_ui_image ; out:ui_image))*))*)"
)
#: robot input → the outputs its answer holds, in order (each exactly once)
ROBOT_REPLIES: dict[str, tuple[str, ...]] = {
    "seed": (), "clear": (), "set_map": (), "spawn_robot": (), "spawn_duckie": (), "episode_start": (), "step": (),
    "set_robot_commands": (), "get_robot_interface_description": ("robot_interface_description",),
    "get_robot_observations": ("robot_observations",), "get_robot_performance": ("robot_performance",),
    "get_robot_state": ("robot_state",), "get_duckie_state": ("duckie_state",), "get_sim_state": ("sim_state",),
    "dump_state": ("state_dump",), "get_ui_image": ("ui_image",),
}
ROBOT_INPUTS = tuple(sorted(ROBOT_REPLIES))
#: every topic a robot node may write: its data outputs, the meta outputs, and the meta ``aborted``
ROBOT_OUTPUTS = frozenset({"aborted"}.union(*ROBOT_REPLIES.values(), *META_REPLIES.values()))


class Language:
    """Tracks where a conversation is in a language; :meth:`check` says what an input breaks.

    Subclasses give ``ALLOWED`` (state → inputs allowed there) and ``NEXT`` (input → state after it; inputs
    not listed keep the state).
    """

    START = "start"
    ALLOWED: ClassVar[dict[str, tuple[str, ...]]] = {}
    NEXT: ClassVar[dict[str, str]] = {}

    def __init__(self) -> None:
        self.state = self.START

    @property
    def expected(self) -> tuple[str, ...]:
        """Inputs allowed now."""
        return self.ALLOWED[self.state]

    def check(self, topic: str) -> str | None:
        """Why input ``topic`` is not allowed now, or None if it is."""
        if topic in self.ALLOWED[self.state]:
            return None
        return f'Unexpected input "{topic}"; I expected one of {list(self.expected)} (state: {self.state}).'

    def push(self, topic: str) -> None:
        """Advance past input ``topic`` (which :meth:`check` allowed)."""
        self.state = self.NEXT.get(topic, self.state)


class AgentLanguage(Language):
    """The agent language: start → (seed) → episode_start → observations / get_commands."""

    ALLOWED: ClassVar[dict[str, tuple[str, ...]]] = {
        "start": ("seed", "episode_start"),
        "seeded": ("episode_start",),
        "episode": ("episode_start", "observations", "get_commands"),
    }
    NEXT: ClassVar[dict[str, str]] = {"seed": "seeded", "episode_start": "episode"}


class RobotLanguage(Language):
    """The robot language: (seed) → per episode clear, set_map, spawn_robot / spawn_duckie*, describe*,
    episode_start, then commands, steps and queries until the next clear."""

    _EPISODE = ("clear", "step", "set_robot_commands", "get_robot_observations", "get_robot_performance",
                "get_robot_state", "get_duckie_state", "get_sim_state", "dump_state", "get_ui_image")
    ALLOWED: ClassVar[dict[str, tuple[str, ...]]] = {
        "start": ("seed", "clear"),
        "seeded": ("clear",),
        "cleared": ("set_map",),
        "mapped": ("spawn_robot", "spawn_duckie", "get_robot_interface_description", "episode_start"),
        "described": ("get_robot_interface_description", "episode_start"),
        "episode": _EPISODE,
    }
    NEXT: ClassVar[dict[str, str]] = {
        "seed": "seeded", "clear": "cleared", "set_map": "mapped", "spawn_robot": "mapped", "spawn_duckie": "mapped",
        "get_robot_interface_description": "described", "episode_start": "episode",
    }
