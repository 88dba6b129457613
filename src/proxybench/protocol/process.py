"""The caller side: drive a node process over the AIDO protocol, failing fast and cleanly.

Each request is one write and then a read loop over ``poll`` with a deadline; replies are checked against
the language (understood, exactly the outputs the input calls for, over). Anything else ends the process
and raises a :class:`~.failures.NodeFailure` with a stable reason code, after the process group has been
killed and reaped. A failed process stays failed: later calls raise the same failure again.

:class:`NodeProcess` is that machinery for any protocol (its language, replies and failure class are class
attributes); :class:`AgentProcess` speaks the agent protocol, :class:`~.robot_process.RobotProcess` the robot
(simulator) protocol.
"""

from __future__ import annotations

import logging
import math
import os
import select
import time
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Self

import numpy as np

from proxybench.agents.base import Observation
from proxybench.protocol import jpeg as jpeg_codec
from proxybench.protocol import wire
from proxybench.protocol.description import declares_extension, encode_extras
from proxybench.protocol.failures import AgentFailure, NodeFailure, ProtocolUsageError
from proxybench.protocol.language import (
    DATA_INPUTS,
    DATA_REPLIES,
    META_REPLIES,
    NODE_OUTPUTS,
    AgentLanguage,
    Language,
)
from proxybench.protocol.transport import Launch, NotAFifo, node_argv

__all__ = ["AgentProcess", "NodeProcess"]

log = logging.getLogger("proxybench.protocol")

_IN = select.POLLIN | select.POLLPRI | select.POLLHUP | select.POLLERR
_TRANSPORTS = {"pipe": "pipes", "fifo": "fifos"}
#: how describe_protocol may fail for a node whose data path works: then start it again without reflection
_REFLECTION_FALLBACK = frozenset({"aborted", "not-understood", "exited", "out-of-order", "bad-message",
                                  "unknown-topic", "garbage", "not-a-map", "truncated"})
# let a node that is ending anyway end by itself, so its own exit status is reported (a Python node's exit
# takes ~0.5 s on a loaded machine)
_GRACE = {"aborted": 1.0, "not-understood": 1.0, "exited": 1.0, "truncated": 1.0}


@dataclass(frozen=True)
class _Plan:
    """What the answer to one input must hold: ``outputs`` in order (``any_of``: exactly one of them)."""

    request: str
    outputs: tuple[str, ...] = ()
    any_of: frozenset[str] = frozenset()
    capabilities: bool = False


class NodeProcess:
    """A node in a child process, started and handshaken on construction; the protocol-independent part.

    ``cmd`` is an argv list, or a string: run through ``/bin/sh -c`` when it uses shell syntax (``cd dir &&
    exec node``; ``shell`` forces either way), else split like a shell would. ``cwd``: its working
    directory. ``transport``: ``"pipes"`` (stdin/stdout) or ``"fifos"`` (AIDO's way:
    ``AIDONODE_DATA_IN`` / ``AIDONODE_DATA_OUT=fifo:``, so the node's stdout stays free for its prints;
    ``fifo_dir``: where the FIFOs are made, e.g. a folder a container mounts); ``"pipe"`` / ``"fifo"`` are
    accepted too. ``env`` is added to the inherited environment. ``init_timeout`` bounds start + handshake
    and each setup or meta request; ``step_timeout`` bounds each per-frame request. ``reflection=False``
    skips ``describe_protocol``; with True, a node that fails that request (the zuper-nodes wrapper on
    Python ≥ 3.11 aborts on it) is started again once without it, and :attr:`reflection_note` says why.
    ``on_stderr(line)`` is called from the stderr drain thread for each line the node writes there.

    Subclasses set the protocol: ``language_class``, ``data_replies`` (input → outputs of its answer),
    ``node_outputs`` (every topic the node may write), ``required_inputs`` / ``required_outputs`` (what its
    protocol description must declare) and ``failure_class``.
    """

    language_class: type[Language] = AgentLanguage
    data_replies: dict[str, tuple[str, ...]] = DATA_REPLIES
    node_outputs: frozenset[str] = NODE_OUTPUTS
    required_inputs: tuple[str, ...] = DATA_INPUTS
    required_outputs: tuple[str, ...] = ("commands",)
    failure_class: type[NodeFailure] = AgentFailure

    def __init__(self, cmd: str | Sequence[str], *, init_timeout: float = 30.0, step_timeout: float = 5.0,
                 transport: str = "pipes", env: dict[str, str] | None = None, cwd: str | None = None,
                 reflection: bool = True, shell: bool | None = None, fifo_dir: str | None = None,
                 max_reply_bytes: int = 8 << 20, max_reply_messages: int = 1000,
                 max_stderr_bytes: int = 4 << 20, stderr_lines: int = 50, close_timeout: float = 5.0,
                 on_stderr: Callable[[str], None] | None = None):
        transport = _TRANSPORTS.get(transport, transport)
        if transport not in ("pipes", "fifos"):
            raise ValueError(f"transport must be 'pipe' or 'fifo', not {transport!r}")
        for name, value in (("init_timeout", init_timeout), ("step_timeout", step_timeout)):
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number of seconds, not {value!r}")
        self.cmd = cmd
        try:
            self.argv = node_argv(cmd, shell)
        except ValueError as exc:
            raise self.failure_class("start-failed", f"cannot start {cmd!r}: {exc}") from None
        self.init_timeout, self.step_timeout, self.close_timeout = init_timeout, step_timeout, close_timeout
        self.max_reply_bytes, self.max_reply_messages = max_reply_bytes, max_reply_messages
        self.max_stderr_bytes = max_stderr_bytes
        self.reflection = reflection
        #: why the protocol description is missing although reflection was asked for (None: it is not)
        self.reflection_note: str | None = None
        self._launch_args = {"transport": transport, "env": env, "cwd": cwd, "stderr_lines": stderr_lines,
                             "on_stderr": on_stderr, "fifo_dir": fifo_dir}
        self._start(reflection)

    def _start(self, reflect: bool) -> None:
        """Launch the command and handshake (with ``describe_protocol`` when ``reflect`` and offered)."""
        self.language = self.language_class()
        self.failure: NodeFailure | None = None
        self.capabilities: dict = {}
        self.description: dict | None = None
        self._closed = False
        self._stream = wire.CborStream()
        self._req_bytes = self._req_msgs = 0
        self._stderr_tail: list[str] | None = None
        deadline = time.monotonic() + self.init_timeout
        cwd = self._launch_args["cwd"]
        if cwd is not None and not os.path.isdir(cwd):
            raise self.failure_class("start-failed", f"cannot start {self.cmd!r}: working directory {cwd!r} "
                                                     f"does not exist")
        try:
            self._os = Launch(self.argv, **self._launch_args)
        except OSError as exc:
            raise self.failure_class("start-failed", f"cannot start {self.argv!r}: {exc}") from exc
        self._finalizer = weakref.finalize(self, self._os.kill_quietly)
        self._poll = select.poll()
        self._await_output(deadline)
        self._handshake(deadline, reflect)

    # --------------------------------------------------------------------------------- public API
    @property
    def pid(self) -> int:
        return self._os.pid

    @property
    def returncode(self) -> int | None:
        return self._os.returncode

    def poll(self) -> int | None:
        """The exit status once the process has been reaped (after a failure or :meth:`close`), else None."""
        return self._os.returncode

    @property
    def alive(self) -> bool:
        return not self._closed and self.failure is None

    def meta(self, name: str, data: Any = None) -> tuple[str, Any]:
        """Ask meta topic ``wrapper.<name>`` (describe_node, get_logs, ...): (output topic, its data)."""
        if name not in META_REPLIES:
            raise ProtocolUsageError(f"unknown meta topic {name!r}; known: {sorted(META_REPLIES)}")
        self._usable()
        plan = _Plan("wrapper." + name, any_of=META_REPLIES[name])
        (reply,) = self._request(wire.encode_topic("wrapper." + name, data), [plan],
                                 time.monotonic() + self.init_timeout, "init-timeout")
        return reply[0].topic, reply[0].data

    def close(self) -> int | None:
        """End the node (EOF on its input, then TERM, then KILL to its group) and reap it; its exit status."""
        if not self._closed and self.failure is None:
            self._closed = True
            self._os.close_input()
            self._os.terminate(self.close_timeout, term_first=True)
            self._finish_stderr()
        self._closed = True
        return self._os.returncode

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------------------- handshake
    def _await_output(self, deadline: float) -> None:
        while not self._ready():
            if self._os.exited():
                self._fail("exited", "the node ended before creating its output FIFO")
            if time.monotonic() >= deadline:
                self._fail("init-timeout", "the node did not create its output FIFO within the init timeout")
            self._os.wait_exit(0.002)
        for fd in (self._os.out_fd, self._os.pidfd, self._os.stderr.wake_fd):
            if fd is not None:
                self._poll.register(fd, _IN)

    def _ready(self) -> bool:
        try:
            return self._os.output_ready()
        except NotAFifo as exc:
            self._fail("garbage", str(exc))
            raise  # unreachable: _fail raises

    def _handshake(self, deadline: float, reflect: bool) -> None:
        plan = _Plan("capabilities", capabilities=True)
        self._request(wire.encode_control(wire.CTRL_CAPABILITIES, wire.CAPABILITIES), [plan], deadline,
                      "init-timeout")
        if not reflect or not (self.capabilities.get("z2") or {}).get("protocol-reflection"):
            self._described()
            return
        plan = _Plan("wrapper.describe_protocol", any_of=META_REPLIES["describe_protocol"])
        try:
            (reply,) = self._request(wire.encode_topic("wrapper.describe_protocol", None), [plan], deadline,
                                     "init-timeout")
        except NodeFailure as exc:
            if exc.reason not in _REFLECTION_FALLBACK:
                raise
            self._reflection_failed(exc)
            return
        self.description = reply[0].data
        self._check_compatible()
        self._described()

    def _reflection_failed(self, exc: NodeFailure) -> None:
        """The node could not describe its protocol (and is gone): start it again and do without."""
        first = next((line for line in exc.detail.splitlines() if line.strip()), exc.detail)
        self.reflection_note = (f"describe_protocol failed ({exc.reason}: {first.strip()[:200]}); the node was "
                                f"started again without protocol reflection")
        log.warning("node %r: %s", self.cmd, self.reflection_note)
        self._start(reflect=False)

    def _described(self) -> None:
        """Hook after the handshake: :attr:`description` is the node's protocol description (None without
        protocol reflection)."""

    def _check_compatible(self) -> None:
        try:
            inputs, outputs = self.description["data"]["inputs"], self.description["data"]["outputs"]
            missing = [t for t in self.required_inputs if t not in inputs] + \
                [t for t in self.required_outputs if t not in outputs]
        except (KeyError, TypeError):
            missing = ["data.inputs", "data.outputs"]
        if missing:
            self._fail("incompatible", f"the node's protocol description lacks {missing}")

    # ------------------------------------------------------------------------------- requests
    def _usable(self) -> None:
        if self.failure is not None:
            f = self.failure
            raise self.failure_class(f.reason, f.detail, f.exit_code, f.stderr_tail, pid=f.pid)
        if self._closed:
            raise ProtocolUsageError("the node process is closed")

    def _check_order(self, *topics: str) -> None:
        probe = self.language_class()
        probe.state = self.language.state
        for topic in topics:
            problem = probe.check(topic)
            if problem is not None:
                raise ProtocolUsageError(f"caller protocol violation, nothing sent: {problem}")
            probe.push(topic)

    def _data_plan(self, topic: str) -> _Plan:
        return _Plan(topic, outputs=self.data_replies[topic])

    def _data(self, topic: str, payload: bytes, timeout: float, reason: str) -> list[list[wire.Topic]]:
        self._usable()
        self._check_order(topic)
        return self._request(payload, [self._data_plan(topic)], time.monotonic() + timeout, reason)

    def _request(self, payload: bytes, plans: list[_Plan], deadline: float, reason: str) -> list[list[wire.Topic]]:
        for plan in plans:
            if plan.request in self.data_replies:
                self.language.push(plan.request)
        self._req_bytes, self._req_msgs = self._stream.bytes_read, 0
        self._os.stderr.arm(self.max_stderr_bytes)
        try:
            self._send(payload, deadline, reason)
            return [self._collect(plan, deadline, reason) for plan in plans]
        except NodeFailure:
            raise
        except BaseException:  # e.g. KeyboardInterrupt mid-answer: the stream is out of step, end the node
            self._closed = True
            self._os.terminate()
            self._finish_stderr()
            raise

    # ------------------------------------------------------------------------------- reading replies
    def _collect(self, plan: _Plan, deadline: float, reason: str) -> list[wire.Topic]:
        first = self._next(deadline, reason)
        if not (isinstance(first, wire.Control) and first.code == wire.CTRL_UNDERSTOOD):
            self._unexpected(first, plan, "expected `understood` first")
        outputs: list[wire.Topic] = []
        while True:
            msg = self._next(deadline, reason)
            if isinstance(msg, wire.Control):
                if msg.code == wire.CTRL_OVER:
                    break
                if msg.code == wire.CTRL_CAPABILITIES and plan.capabilities:
                    self.capabilities = msg.data if isinstance(msg.data, dict) else {}
                    continue
                self._unexpected(msg, plan, "unexpected control message")
            else:
                self._check_output(msg, plan, outputs)
                outputs.append(msg)
        expected = plan.outputs or (sorted(plan.any_of)[:1] if plan.any_of else [])
        if len(outputs) < len(expected):
            self._fail("out-of-order", f"answer to {plan.request!r} ended (over) without {expected[len(outputs)]!r}")
        return outputs

    def _check_output(self, msg: wire.Topic, plan: _Plan, outputs: list[wire.Topic]) -> None:
        if msg.topic == "aborted":
            self._fail("aborted", str(msg.data))
        if msg.topic not in self.node_outputs:
            self._fail("unknown-topic", f"topic {msg.topic!r} in the answer to {plan.request!r} is not a node "
                                        f"output of the protocol")
        k = len(outputs)
        ok = (k < len(plan.outputs) and msg.topic == plan.outputs[k]) or (k == 0 and msg.topic in plan.any_of)
        if not ok:
            self._fail("out-of-order", f"output {msg.topic!r} (#{k + 1}) not allowed in the answer to "
                                       f"{plan.request!r}")

    def _unexpected(self, msg: wire.Control | wire.Topic, plan: _Plan, what: str) -> None:
        if isinstance(msg, wire.Control):
            if msg.code == wire.CTRL_ABORTED:
                self._fail("aborted", str(msg.data))
            if msg.code == wire.CTRL_NOT_UNDERSTOOD:
                self._fail("not-understood", str(msg.data))
            if msg.code not in wire.CONTROL_CODES:
                self._fail("bad-message", f"unknown control code {msg.code!r}")
            self._fail("out-of-order", f"{what} in the answer to {plan.request!r}, got control {msg.code!r}")
        if msg.topic == "aborted":
            self._fail("aborted", str(msg.data))
        if msg.topic not in self.node_outputs:
            self._fail("unknown-topic", f"topic {msg.topic!r} is not a node output of the protocol")
        self._fail("out-of-order", f"{what} in the answer to {plan.request!r}, got topic {msg.topic!r}")

    def _next(self, deadline: float, reason: str) -> wire.Control | wire.Topic:
        """The next message, skipping topic messages without ``z2`` compat (they still count as a flood)."""
        while True:
            try:
                obj = self._stream.next()
            except wire.WireError as exc:
                hint = ""
                if str(exc).startswith("text where") and self._os.transport == "pipes":
                    hint = (" (the node prints to stdout, which is the protocol stream over pipes: start it with "
                            "transport 'fifo', AIDO's default, or print to stderr)")
                self._fail(exc.reason, str(exc) + hint)
            if obj is not None:
                self._req_msgs += 1
                if self._req_msgs > self.max_reply_messages:
                    self._fail("stdout-flood", f"more than {self.max_reply_messages} messages in one answer")
                try:
                    msg = wire.decode_message(obj)
                except wire.BadMessageError as exc:
                    self._fail("bad-message", str(exc))
                if isinstance(msg, wire.Control) or msg.z2:
                    return msg
                continue
            if self._stream.eof:
                self._fail("exited", "the node closed its output while an answer was expected")
            self._wait(deadline, reason)

    def _wait(self, deadline: float, reason: str, write_fd: int | None = None) -> bool:
        """Wait for output (read it into the stream) or, with ``write_fd``, for room to write; True: writable."""
        left = deadline - time.monotonic()
        if left <= 0:
            self._fail(reason, f"no complete answer within {self._timeout_of(reason)} s")
        if write_fd is not None:
            self._poll.register(write_fd, select.POLLOUT)
        ms = math.ceil(left * 1000)
        try:
            events = self._poll.poll(ms if self._os.pidfd is not None else min(20, ms))  # no pidfd: poll the exit
        finally:
            if write_fd is not None:
                self._poll.unregister(write_fd)
        writable = False
        for fd, _event in events:
            if fd == self._os.out_fd:
                self._read_output()
            elif fd == self._os.stderr.wake_fd:
                self._fail("stderr-flood", f"more than {self.max_stderr_bytes} bytes of stderr during one request")
            elif fd == write_fd:
                writable = True
        if (self._os.pidfd is not None and any(fd == self._os.pidfd for fd, _ in events)) or \
                (self._os.pidfd is None and self._os.exited()):
            self._drain_after_exit()
        return writable

    def _timeout_of(self, reason: str) -> float:
        return self.init_timeout if reason == "init-timeout" else self.step_timeout

    def _read_output(self) -> None:
        n = self._stream.read_from(self._os.out_fd)
        if n:
            self._os.got_output()
            if self._stream.bytes_read - self._req_bytes > self.max_reply_bytes:
                self._fail("stdout-flood", f"more than {self.max_reply_bytes} bytes in one answer")

    def _drain_after_exit(self) -> None:
        """The process ended: take what it wrote, then the stream is over (grandchildren do not count)."""
        while not self._stream.eof and self._stream.read_from(self._os.out_fd):
            if self._stream.bytes_read - self._req_bytes > self.max_reply_bytes:
                self._fail("stdout-flood", f"more than {self.max_reply_bytes} bytes in one answer")
        self._stream.feed_eof()

    def _send(self, payload: bytes, deadline: float, reason: str) -> None:
        def wait() -> None:
            self._wait(deadline, reason, write_fd=self._os.in_fd)
            if self._stream.eof:
                self._fail("exited", "the node ended while a request was being written")

        def closed() -> None:
            self._drain_after_exit()
            self._fail("exited", "the node closed its input")

        self._os.write(payload, wait, closed)

    # ------------------------------------------------------------------------------- failing
    def _finish_stderr(self) -> list[str]:
        if self._stderr_tail is None:
            self._stderr_tail = self._os.stderr.finish()
        return self._stderr_tail

    def _fail(self, reason: str, detail: str) -> None:
        """Kill and reap the process, then raise the failure class (this function never returns)."""
        grace = max(_GRACE.get(reason, 0.0), 1.0 if self._stream.eof else 0.0)
        code = self._os.terminate(grace)
        self.failure = self.failure_class(reason, detail, code, self._finish_stderr(), pid=self._os.pid)
        self._finalizer.detach()
        raise self.failure


class AgentProcess(NodeProcess):
    """An AIDO agent node in a child process, started and handshaken on construction.

    Options as :class:`NodeProcess`; ``init_timeout`` bounds start + handshake and each seed /
    episode_start / meta request, ``step_timeout`` each observations / get_commands exchange.
    ``privileged``: None learns from the node's protocol description whether to send the proxybench
    extension; True/False force it.
    """

    def __init__(self, cmd: str | Sequence[str], *, privileged: bool | None = None, **kwargs: Any):
        self._privileged_request = privileged
        self.privileged = bool(privileged)
        super().__init__(cmd, **kwargs)

    def _described(self) -> None:
        if self.description is None or self._privileged_request is not None:
            self.privileged = bool(self._privileged_request)
        else:
            self.privileged = declares_extension(self.description)

    def seed(self, seed: int) -> None:
        self._data("seed", wire.encode_seed(seed), self.init_timeout, "init-timeout")

    def episode_start(self, name: str, yaml_payload: str = "{}") -> None:
        self._data("episode_start", wire.encode_episode_start(name, yaml_payload), self.init_timeout,
                   "init-timeout")

    def observe(self, obs: Observation, jpeg: bytes | None = None) -> None:
        """Send one ``observations`` message; ``jpeg``: the camera frame already encoded."""
        self._data("observations", self._observations(obs, jpeg), self.step_timeout, "step-timeout")

    def get_commands(self, at_time: float) -> np.ndarray:
        """Wheel PWM (left, right) the node commands at ``at_time``."""
        (reply,) = self._data("get_commands", wire.encode_get_commands(at_time), self.step_timeout,
                              "step-timeout")
        return self._commands(reply[0])

    def step(self, obs: Observation, jpeg: bytes | None = None) -> np.ndarray:
        """``observe(obs)`` then ``get_commands(obs.time)``, both written at once (one round trip less)."""
        self._usable()
        self._check_order("observations", "get_commands")
        payload = self._observations(obs, jpeg) + wire.encode_get_commands(obs.time)
        plans = [self._data_plan("observations"), self._data_plan("get_commands")]
        replies = self._request(payload, plans, time.monotonic() + self.step_timeout, "step-timeout")
        return self._commands(replies[1][0])

    def _observations(self, obs: Observation, jpg: bytes | None) -> bytes:
        if jpg is None and obs.camera is not None:
            jpg = jpeg_codec.jpeg_of(obs.camera) or jpeg_codec.encode(obs.camera)
        extras = encode_extras(obs.lane_pose) if self.privileged else None
        return wire.encode_observations(jpg or b"", obs.time, obs.odometry, obs.odometry_resolution, extras)

    def _commands(self, reply: wire.Topic) -> np.ndarray:
        try:
            return wire.parse_commands(reply.data)
        except wire.MessageTypeError as exc:
            self._fail("bad-commands", str(exc))
            raise  # unreachable: _fail raises
