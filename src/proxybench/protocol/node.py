"""Serve any Python :class:`~proxybench.agents.base.Agent` as an AIDO agent node.

:class:`NodeLogic` is the protocol-independent part (envelopes, control messages, meta topics, error
answers) that the agent node here and the robot node (:mod:`.robot_node`) share, and :func:`serve_node`
runs any such logic on a pair of streams.

What the node writes mirrors the recorded zuper-nodes node (zuper-nodes-z6 6.2.17) message for message:
``capabilities`` → understood, capabilities, over; every topic input → understood, its outputs, over; a
failing handler (bad types, out-of-order input, an exception in the agent) → understood, aborted
(traceback), over, exit 1; an unknown topic → not-understood, over, aborted, over, exit 1; a topic
message without ``compat: ["z2"]`` → nothing. Each answer, and the answers to inputs that arrived together,
are written with one ``write`` call, which saves wake-ups per exchange without changing a byte.
"""

from __future__ import annotations

import json
import os
import stat
import sys
import time
import traceback
from collections import deque
from collections.abc import Callable
from typing import Any, BinaryIO

import numpy as np
import yaml

from proxybench.agents.base import Agent, Observation
from proxybench.protocol import jpeg, wire
from proxybench.protocol.description import decode_extras, protocol_description
from proxybench.protocol.language import META_REPLIES, AgentLanguage, Language
from proxybench.untrusted import UntrustedInputError, load_yaml

__all__ = ["AgentNode", "ExternalProtocolViolation", "NodeLogic", "serve", "serve_node"]

_TEXT_PREFIX = "| "
_UNDERSTOOD = wire.encode_control(wire.CTRL_UNDERSTOOD)
_OVER = wire.encode_control(wire.CTRL_OVER)


class ExternalProtocolViolation(Exception):
    """The caller sent something the protocol does not allow."""


def _indent(text: str) -> str:
    # zuper's indent prefixes every line, the empty last one included
    return "\n".join(_TEXT_PREFIX + line for line in text.split("\n"))


def _payload_seed(payload: str) -> int | None:
    """A per-episode seed carried in ``yaml_payload`` (``{"seed": 7}``), as RemoteAgent sends it."""
    try:
        doc = json.loads(payload)
    except ValueError:
        try:
            doc = load_yaml(payload, max_depth=16)
        except (yaml.YAMLError, UntrustedInputError):
            return None
    seed = doc.get("seed") if isinstance(doc, dict) else None
    return seed if type(seed) is int else None


class NodeLogic:
    """The protocol logic of a node, free of I/O: one decoded input map → the bytes to answer.

    A protocol is given by its ``language``, its ``description`` (the ``protocol_description`` data) and
    ``handlers`` (data input topic → handler returning the encoded outputs; a handler that raises makes the
    node answer ``aborted`` and exit 1); subclasses override :meth:`_node_description`. ``config_target``
    is the object whose ``config`` attribute ``wrapper.set_config`` edits.
    """

    def __init__(self, node_name: str, language: Language, description: dict,
                 handlers: dict[str, Callable[[Any], list[bytes]]]):
        self.name = node_name
        self.language = language
        self.logs: deque[str] = deque(maxlen=200)
        self._description = description
        self._data = handlers
        self.config_target: Any = None

    def handle(self, obj: dict) -> tuple[list[bytes], bool]:
        """(messages to write, whether the node must now exit with status 1)."""
        try:
            msg = wire.decode_message(obj)
        except wire.BadMessageError as exc:
            return self._unexpected(exc), True
        if isinstance(msg, wire.Control):
            return self._on_control(msg), False
        if not msg.z2:
            return [], False
        meta = msg.topic.startswith("wrapper.")
        topic = msg.topic[len("wrapper."):] if meta else msg.topic
        known = META_REPLIES if meta else self._data
        if topic not in known:
            text = f'Input channel "{topic}" not found in protocol. \n\nKnown channels: {sorted(known)}'
            head = [wire.encode_control(wire.CTRL_NOT_UNDERSTOOD, text), wire.encode_control(wire.CTRL_OVER)]
            return head + self._unexpected(ExternalProtocolViolation(text)), True
        return self._on_topic(topic, msg.data, meta)

    # ------------------------------------------------------------------------------------ envelopes
    def _on_control(self, msg: wire.Control) -> list[bytes]:
        if msg.code == wire.CTRL_CAPABILITIES:
            return [wire.encode_control(wire.CTRL_UNDERSTOOD),
                    wire.encode_control(wire.CTRL_CAPABILITIES, wire.CAPABILITIES),
                    wire.encode_control(wire.CTRL_OVER)]
        text = f'I expect any of {[wire.CTRL_CAPABILITIES]}, not "{msg.code}".'
        return [wire.encode_control(wire.CTRL_NOT_UNDERSTOOD, text), wire.encode_control(wire.CTRL_OVER)]

    def _on_topic(self, topic: str, data: Any, meta: bool) -> tuple[list[bytes], bool]:
        try:
            outputs = self._on_meta(topic, data, time.time_ns()) if meta else self._data[topic](data)
        except Exception:
            text = f'Exception while handling a message on topic "{topic}".\n\n' + _indent(traceback.format_exc())
            self._log(text)
            return [_UNDERSTOOD, wire.encode_control(wire.CTRL_ABORTED, text), _OVER], True
        return [_UNDERSTOOD, *outputs, _OVER], False

    def _unexpected(self, exc: Exception) -> list[bytes]:
        """Aborted + over for an error outside any handler, with a real traceback like zuper's."""
        try:
            raise exc
        except Exception:
            text = "Unexpected error:\n\n" + _indent(traceback.format_exc())
        self._log(text)
        return [wire.encode_control(wire.CTRL_ABORTED, text), wire.encode_control(wire.CTRL_OVER)]

    def _log(self, text: str) -> None:
        self.logs.append(text)
        print(f"[{self.name}] {text}", file=sys.stderr, flush=True)

    def _advance(self, topic: str) -> None:
        problem = self.language.check(topic)
        if problem is not None:
            raise ExternalProtocolViolation(problem)
        self.language.push(topic)

    def _on_seed(self, data: Any) -> list[bytes]:
        """The ``seed`` topic, which both languages open with: kept in ``self.seed``, answered with nothing."""
        seed = wire.parse_seed(data)
        self._advance("seed")
        self.seed = seed
        return []

    # ------------------------------------------------------------------------------------ meta topics
    def _on_meta(self, topic: str, data: Any, start: int) -> list[bytes]:
        out_topic, out = self._meta_answer(topic, data)
        timing = wire.node_timing(self.name + ".wrapper", start)
        return [wire.encode_topic(out_topic, wire.canonical(out), timing)]

    def _meta_answer(self, topic: str, data: Any) -> tuple[str, Any]:
        if topic == "describe_protocol":
            return "protocol_description", self._description
        if topic == "describe_node":
            return "node_description", {"description": self._node_description()}
        if topic == "describe_config":
            schema = {"$id": "http://invalid.json-schema.org/NoConfig#", "type": "object", "order": [],
                      "title": "NoConfig", "$schema": "http://json-schema.org/draft-07/schema#",
                      "__qualname__": "NoConfig"}
            return "config_description", {"config": schema, "current": {}}
        if topic == "set_config":
            return self._set_config(data)
        if topic == "describe_build":
            return "build_description", {}
        if topic == "get_state":
            return "node_state", None
        if topic == "set_state":
            return "set_state_ack", None
        return "logs", list(self.logs)

    def _set_config(self, data: Any) -> tuple[str, Any]:
        if not isinstance(data, dict) or type(data.get("key")) is not str or "value" not in data:
            raise wire.MessageTypeError("set_config: expected {key: str, value: any}")
        config = getattr(self.config_target, "config", None)
        if config is None:
            return "set_config_error", 'Node does not have the "config" attribute.'
        if not hasattr(config, data["key"]):
            return "set_config_error", f"Could not find config key {data['key']}"
        try:
            setattr(config, data["key"], data["value"])
        except Exception as exc:  # frozen dataclasses, properties
            return "set_config_error", f"Could not set config key {data['key']}: {exc}"
        return "set_config_ack", None

    def _node_description(self) -> str:
        return f"{type(self).__name__} {self.name!r}"


class AgentNode(NodeLogic):
    """The protocol logic of a served agent, free of I/O: one decoded input map → the bytes to answer."""

    def __init__(self, agent: Agent, node_name: str = "agent"):
        self.agent = agent
        self.privileged = bool(agent.privileged)
        self.seed: int | None = None
        self.obs: Observation | None = None
        super().__init__(node_name, AgentLanguage(), protocol_description(self.privileged), {
            "seed": self._on_seed, "episode_start": self._on_episode_start,
            "observations": self._on_observations, "get_commands": self._on_get_commands,
        })
        self.config_target = agent

    # ------------------------------------------------------------------------------------ data topics
    def _on_episode_start(self, data: Any) -> list[bytes]:
        name, payload = wire.parse_episode_start(data)
        self._advance("episode_start")
        seed = _payload_seed(payload)
        self.obs = None
        self.agent.reset(seed if seed is not None else (self.seed or 0), name)
        return []

    def _on_observations(self, data: Any) -> list[bytes]:
        obs = wire.parse_observations(data)
        self._advance("observations")
        camera = None
        if obs.jpg:
            camera = jpeg.decode(obs.jpg)
            camera.flags.writeable = False  # as in-process agents get it from jpeg.roundtrip
        lane_pose = decode_extras(obs.extras) if self.privileged else None
        self.obs = Observation(camera, obs.timestamp, obs.odometry, obs.resolution, lane_pose)
        return []

    def _on_get_commands(self, data: Any) -> list[bytes]:
        at_time = wire.parse_get_commands(data)
        self._advance("get_commands")
        start = time.time_ns()
        obs = self.obs if self.obs is not None else Observation(None, at_time)
        action = np.asarray(self.agent.act(obs), dtype=np.float64).reshape(-1)
        if action.shape != (2,):
            raise ValueError(f"act() must return 2 wheel commands, got shape {action.shape}")
        return [wire.encode_commands(action[0], action[1], wire.encode_node_timing(self.name, start))]

    def _node_description(self) -> str:
        doc = (type(self.agent).__doc__ or type(self.agent).__name__).strip()
        text = f"{doc}\n\nproxybench agent {self.agent.name!r} ({type(self.agent).__qualname__})."
        if self.privileged:
            text += " Privileged: reads the true lane pose from the proxybench extension of observations."
        return text


# ------------------------------------------------------------------------------------------------ I/O
class _NodeIO:
    """The node's two streams; the standard ones are moved off fds 0/1 so stray prints cannot corrupt them."""

    def __init__(self, data_in: str | int | BinaryIO | None, data_out: str | int | BinaryIO | None):
        self._restore: list[tuple[int, int]] = []
        self._close: list[int] = []
        self.in_fd, self.in_file = self._open(data_in, wire.ENV_DATA_IN, 0)
        self.out_fd, self.out_file = self._open(data_out, wire.ENV_DATA_OUT, 1)

    def _open(self, spec: str | int | BinaryIO | None, env: str, std: int) -> tuple[int, BinaryIO | None]:
        """Stream ``std`` (0: in, 1: out) as given: unset (the environment variable ``env``, else the standard
        stream, taken over), an fd, a path (out: ``fifo:PATH`` makes the FIFO if needed) or a file object."""
        name = ("/dev/stdin", "/dev/stdout")[std]
        spec = os.environ.get(env, name) if spec is None else spec
        if spec in (name, std):
            return self._steal(std, (os.O_RDONLY, os.O_WRONLY)[std]), None
        if isinstance(spec, int):
            return spec, None
        if isinstance(spec, str):
            fd = os.open(spec, os.O_RDONLY) if std == 0 else self._open_out_path(spec)
            self._close.append(fd)
            return fd, None
        return -1, spec

    @staticmethod
    def _open_out_path(spec: str) -> int:
        path = spec
        if spec.startswith("fifo:"):
            path = spec[len("fifo:"):]
            if not (os.path.exists(path) and stat.S_ISFIFO(os.stat(path).st_mode)):
                os.mkfifo(path)
        return os.open(path, os.O_WRONLY | (0 if spec.startswith("fifo:") else os.O_CREAT | os.O_TRUNC), 0o644)

    def _steal(self, fd: int, mode: int) -> int:
        """A private duplicate of standard fd ``fd``; fd itself now points to /dev/null (in) or stderr (out)."""
        if fd == 1:
            sys.stdout.flush()
        private = os.dup(fd)
        self._restore.append((private, fd))
        if fd == 1:
            os.dup2(2, 1)
        else:
            devnull = os.open(os.devnull, mode)
            os.dup2(devnull, fd)
            os.close(devnull)
        return private

    def read_into(self, stream: wire.CborStream) -> None:
        if self.in_file is None:
            stream.read_from(self.in_fd)
            return
        data = self.in_file.read(1 << 20)
        if data:
            stream.feed(data)
        else:
            stream.feed_eof()

    def write(self, data: bytes) -> None:
        if self.out_file is not None:
            self.out_file.write(data)
            self.out_file.flush()
            return
        view = memoryview(data)
        while view:
            view = view[os.write(self.out_fd, view):]

    def close(self) -> None:
        for fd in self._close:
            os.close(fd)
        for private, fd in self._restore:
            os.dup2(private, fd)
            os.close(private)


def _loop(node: NodeLogic, io: _NodeIO) -> int:
    """Answer every input; answers to inputs that arrived together (a caller's pipelined request) are
    written at once, when no further complete input is buffered, so the caller wakes up once."""
    stream = wire.CborStream()
    pending: list[bytes] = []
    while True:
        try:
            obj = stream.next()
        except wire.WireError as exc:
            io.write(b"".join(pending + node._unexpected(exc)))
            return 1
        if obj is None:
            if pending:
                io.write(b"".join(pending))
                pending.clear()
            if stream.eof:
                return 0
            io.read_into(stream)
            continue
        out, failed = node.handle(obj)
        pending += out
        if failed:
            io.write(b"".join(pending))
            return 1


def serve_node(node: NodeLogic, data_in: str | int | BinaryIO | None = None,
               data_out: str | int | BinaryIO | None = None, *, exit_on_abort: bool = True) -> int:
    """Answer on the node's streams with ``node``'s logic until its input ends; returns the exit status.

    Streams as :func:`serve`. After an ``aborted`` answer the status is 1, raised as ``SystemExit(1)``
    unless ``exit_on_abort`` is False.
    """
    io = _NodeIO(data_in, data_out)
    try:
        code = _loop(node, io)
    except BrokenPipeError:  # the caller went away: nothing left to answer
        code = 0
    finally:
        io.close()
    if code and exit_on_abort:
        raise SystemExit(code)
    return code


def serve(agent: Agent, data_in: str | int | BinaryIO | None = None, data_out: str | int | BinaryIO | None = None,
          *, node_name: str = "agent", exit_on_abort: bool = True) -> int:
    """Run ``agent`` as an AIDO agent node until its input ends; returns the exit status.

    Streams default to ``$AIDONODE_DATA_IN`` / ``$AIDONODE_DATA_OUT`` (``fifo:PATH`` creates the FIFO),
    else stdin/stdout; a path, a file descriptor or a binary file object also work. While serving on
    stdout, fd 1 points to stderr, so the agent's prints cannot corrupt the protocol. After an
    ``aborted`` answer the status is 1, raised as ``SystemExit(1)`` unless ``exit_on_abort`` is False.
    """
    return serve_node(AgentNode(agent, node_name), data_in, data_out, exit_on_abort=exit_on_abort)
