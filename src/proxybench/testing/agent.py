"""The agent contract: what every agent (zoo, node, checkpoint, yours) must do for its episodes to mean anything.

Checks (each a :class:`~proxybench.testing.results.CheckResult`):

- ``commands``: every answer is two finite numbers in [-1, 1] (wheel PWM), and no observation makes it raise;
- ``determinism``: two fresh agents, reset with the same seed and given the same observations, send the same
  commands (the runner caches episodes by their inputs: an agent that is not a function of them breaks it);
- ``privileged``: the flag is honest. A camera-only agent runs on observations without the true lane pose
  (as camera-only benchmarks and robots give it) and sends the same commands when one is added; a privileged
  agent's commands change when the lane pose moves (else it should say camera-only);
- ``isolation``: no state crosses a reset: episode 2 after episode 1 is episode 2 of a fresh agent;
- ``failure``: ``close()`` may be called twice; a node that dies mid-episode is a named failure
  (:class:`~proxybench.protocol.AgentFailure` with its reason), and the next episode starts a fresh node.

The agent plays recorded streams (:mod:`proxybench.testing.streams`): its commands move nothing, so any
difference between two plays is the agent's. Every play is memoised, so ``run()`` plays 5 episodes on 4
fresh agents (3 for a camera-only node, which is never sent the lane pose; the failure check kills the first
and restarts it), whatever the order the checks are asked in.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from proxybench.agents.base import Agent
from proxybench.protocol.process import AgentProcess, NodeProcess
from proxybench.testing.results import CheckFailed, Contract, describe_error, expect_node_failure, kill_node, release
from proxybench.testing.streams import LANE_POSE_SHIFT, StreamSpec, as_seen

__all__ = ["AgentContract", "Play"]

#: fresh-agent sessions: name → the episodes (index into the stream's seeds, how the lane pose is given) played
_SESSIONS: dict[str, tuple[tuple[int, str], ...]] = {
    "first": ((0, "as-run"), (1, "as-run")),  # episode 1 then episode 2 on one agent
    "fresh-1": ((0, "as-run"),),  # episode 1 on a fresh agent: determinism
    "fresh-2": ((1, "as-run"),),  # episode 2 on a fresh agent: isolation
    "truth": ((0, "truth"),),  # episode 1 with the lane pose added (camera-only) or moved (privileged)
}


@dataclass
class Play:
    """One episode as an agent played it: its answers (each converted to float64 where it could be) and the
    exception that ended it early, at ``failed_at`` (-1: in ``reset``)."""

    seed: int
    commands: list[Any]
    error: BaseException | None = None
    failed_at: int | None = None

    def first_difference(self, other: Play, atol: float = 0.0) -> str | None:
        """Where ``other`` first differs from this play, in words (None: the same answers and the same ending)."""
        for k, (a, b) in enumerate(zip(self.commands, other.commands, strict=False)):
            if not _same(a, b, atol):
                return f"frame {k}: {_fmt(a)}, then {_fmt(b)}"
        if len(self.commands) != len(other.commands) or self.failed_at != other.failed_at:
            return f"one play ended after {len(self.commands)} commands ({self.ending()}), the other after " \
                   f"{len(other.commands)} ({other.ending()})"
        if self.error is not None and describe_error(self.error) != describe_error(other.error):  # type: ignore[arg-type]
            return f"they failed differently: {self.ending()}; then {other.ending()}"
        return None

    def ending(self) -> str:
        if self.error is None:
            return "no error"
        where = "in reset" if self.failed_at == -1 else f"at frame {self.failed_at}"
        return f"raised {where}: {describe_error(self.error)}"


def _as_command(x: Any) -> Any:
    try:
        return np.array(x, dtype=np.float64)
    except (TypeError, ValueError):
        return x


def _same(a: Any, b: Any, atol: float) -> bool:
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        if a.shape != b.shape:
            return False
        return bool(np.array_equal(a, b, equal_nan=True) if atol == 0 else np.allclose(a, b, rtol=0, atol=atol,
                                                                                      equal_nan=True))
    return type(a) is type(b) and repr(a) == repr(b)


def _fmt(c: Any) -> str:
    if isinstance(c, np.ndarray):
        return np.array2string(c, precision=4, separator=", ")
    return repr(c)[:80]


def _bad_command(c: Any) -> str | None:
    """Why ``c`` is not a wheel command, or None."""
    if not isinstance(c, np.ndarray):
        return f"returned {_fmt(c)}, not numbers"
    if c.shape != (2,):
        return f"returned shape {c.shape}, not (2,)"
    if not np.all(np.isfinite(c)):
        return f"returned {_fmt(c)}, not finite"
    if np.any(np.abs(c) > 1.0):
        return f"returned {_fmt(c)}, outside [-1, 1]"
    return None


class AgentContract(Contract):
    """The agent contract over the agents ``factory`` makes (each call: a fresh agent, as a new episode set gets).

    ``stream``: the recorded episodes it is fed (map, image size, frame rate, length, seeds); ``atol``: how far
    two plays' commands may differ and still count as the same (0: bit for bit). Build one with
    :meth:`for_agent` (zoo name or checkpoint path), :meth:`for_command` (a node) or :meth:`for_spec`.
    """

    CHECKS = ("commands", "determinism", "privileged", "isolation", "failure")
    title = "agent contract"

    def __init__(self, factory: Callable[[], Agent], *, name: str | None = None, stream: StreamSpec | None = None,
                 atol: float = 0.0):
        super().__init__()
        self.factory = factory
        self.subject = name or f"agent {getattr(factory, '__name__', 'factory')!r}"
        self.stream = stream or StreamSpec()
        self.atol = float(atol)
        self._flags: dict[str, bool] = {}
        self._agents: dict[str, Agent] = {}

    # -- constructors -------------------------------------------------------------------------------
    @classmethod
    def for_agent(cls, name: str, **kwargs: Any) -> AgentContract:
        """A zoo agent by name, or a behaviour-cloning checkpoint by path (what ``--agent`` accepts)."""
        from proxybench.agents.zoo import make_agent

        make_agent(name)  # an unknown name is the caller's error: raise it here, not as a failed check
        return cls(lambda: make_agent(name), name=f"agent {name!r}", **kwargs)

    @classmethod
    def for_command(cls, command: str | Sequence[str], options: Any = None, **kwargs: Any) -> AgentContract:
        """An agent node started with ``command`` (a shell string or argv) and ``options``
        (:class:`~proxybench.protocol.options.NodeOptions`; default: its defaults)."""
        from proxybench.protocol import RemoteAgent
        from proxybench.protocol.options import NodeOptions

        process_kwargs = (options or NodeOptions()).process_kwargs()

        def start() -> Agent:
            agent = RemoteAgent(command, **process_kwargs)
            if agent.process.reflection_note is not None:  # it failed describe_protocol once: never ask again
                process_kwargs["reflection"] = False
            return agent

        label = command if isinstance(command, str) else " ".join(map(str, command))
        return cls(start, name=f"agent node {label!r}", **kwargs)

    @classmethod
    def for_spec(cls, spec: Any, **kwargs: Any) -> AgentContract:
        """The agent a runner :class:`~proxybench.runner.jobs.AgentSpec` names (zoo, checkpoint, node or SDK
        program)."""
        from proxybench.runner.outcomes import make_agent_for

        what = f"agent {spec.name!r}" if spec.command is None else f"agent node {spec.name!r}"
        return cls(lambda: make_agent_for(spec), name=what, **kwargs)

    # -- playing ------------------------------------------------------------------------------------
    def _fresh(self, session: str) -> Agent:
        try:
            agent = self.factory()
        except Exception as exc:  # a node that cannot start, a checkpoint that cannot load
            raise CheckFailed(f"could not make the agent: {describe_error(exc)}", exc) from None
        self._flags[session] = bool(agent.privileged)
        return agent

    def _play(self, agent: Agent, episode: int, lane_pose: str) -> Play:
        seed = self.stream.seeds[episode]
        play = Play(seed, [])
        privileged = bool(agent.privileged)
        how = "as-run" if lane_pose == "as-run" else ("shifted" if privileged else "given")
        try:
            agent.reset(seed)
        except Exception as exc:
            play.error, play.failed_at = exc, -1
            return play
        for k, obs in enumerate(self.stream.stream(episode)):
            try:
                play.commands.append(_as_command(agent.act(as_seen(obs, privileged, how))))
            except Exception as exc:  # the agent's fault, recorded: the checks say what it means
                play.error, play.failed_at = exc, k
                break
        return play

    def _session(self, name: str) -> list[Play]:
        """A fresh agent plays the session's episodes; the first session's agent is kept for the failure check."""
        def run() -> list[Play]:
            if name == "truth" and _camera_node(self._first()):
                return []  # a camera-only node is never sent the lane pose: nothing to compare
            agent = self._fresh(name)
            keep = name == "first"
            if keep:
                self._agents[name] = agent
                self._on_close(lambda: release(agent))
            try:
                return [self._play(agent, episode, how) for episode, how in _SESSIONS[name]]
            finally:
                if not keep:
                    release(agent)
        return self._memoised(("session", name), run)

    def _first(self) -> Agent:
        """The first session's agent (done with its episodes)."""
        self._session("first")
        return self._agents["first"]

    def _privileged(self) -> bool:
        return bool(self._first().privileged)

    def _deterministic(self) -> str | None:
        """None if episode 1 on two fresh agents was the same; else where it differed."""
        return self._session("first")[0].first_difference(self._session("fresh-1")[0], self.atol)

    # -- the checks ---------------------------------------------------------------------------------
    def check_commands(self) -> tuple[bool, str]:
        plays = self._session("first")
        n = 0
        for i, play in enumerate(plays):
            for k, c in enumerate(play.commands):
                bad = _bad_command(c)
                if bad is not None:
                    return False, f"episode {i + 1} (seed {play.seed}), frame {k}: {bad}"
                n += 1
            if play.error is not None:
                raise CheckFailed(f"episode {i + 1} (seed {play.seed}): {play.ending()}", play.error)
        cmd = np.array([c for p in plays for c in p.commands]).reshape(-1, 2)
        span = "" if not n else (f" (left {cmd[:, 0].min():+.2f}…{cmd[:, 0].max():+.2f}, right "
                                 f"{cmd[:, 1].min():+.2f}…{cmd[:, 1].max():+.2f})")
        return True, f"{n} commands over {len(plays)} episodes: two finite numbers in [-1, 1] each{span}"

    def check_determinism(self) -> tuple[bool, str]:
        diff = self._deterministic()
        seed, frames = self.stream.seeds[0], len(self._session("first")[0].commands)
        if diff is not None:
            return False, (f"two fresh agents reset with seed {seed} and given the same observations answered "
                           f"differently: {diff} (seed every random draw in reset; no clocks, no global state)")
        return True, f"two fresh agents reset with seed {seed}: the same {frames} commands"

    def check_isolation(self) -> tuple[bool, str]:
        second, fresh = self._session("first")[1], self._session("fresh-2")[0]
        diff = second.first_difference(fresh, self.atol)
        if diff is not None:
            if self._deterministic() is not None:
                raise CheckFailed("not verifiable: the agent is not deterministic (see 'determinism')")
            return False, (f"episode 2 (seed {second.seed}) after episode 1 differs from episode 2 of a fresh "
                           f"agent: {diff} (reset must clear what the last episode left)")
        return True, f"episode 2 (seed {second.seed}) after a reset equals episode 2 of a fresh agent " \
                     f"({len(fresh.commands)} commands)"

    def check_privileged(self) -> tuple[bool, str]:
        privileged = self._privileged()
        plain, truth = self._session("first")[0], self._session("truth")
        if self._flags.get("truth", privileged) != privileged:
            return False, "the privileged flag differs from one instance of the agent to the next"
        if not privileged:
            if plain.error is not None:
                raise CheckFailed(f"says camera-only, but given no true lane pose (as camera-only runs give none) "
                                  f"it {plain.ending()}", plain.error)
            if not truth:
                return True, "camera-only node: runs without the true lane pose (which is never sent to it)"
            diff = plain.first_difference(truth[0], self.atol)
            if diff is None:
                return True, "camera-only: runs without the true lane pose, and ignores it when given"
            if self._deterministic() is not None:
                raise CheckFailed("camera-only and runs without the true lane pose; whether it ignores one is not "
                                  "verifiable: the agent is not deterministic (see 'determinism')")
            return False, f"says camera-only, but its commands change when the true lane pose is given ({diff}): " \
                          "it reads it, so declare privileged = True"
        if plain.error is not None:
            raise CheckFailed(f"privileged, given the true lane pose: {plain.ending()}", plain.error)
        if plain.first_difference(truth[0], self.atol) is not None:
            if self._deterministic() is not None:
                raise CheckFailed("privileged; whether it reads the lane pose is not verifiable: the agent is not "
                                  "deterministic (see 'determinism')")
            return True, "privileged: its commands follow the true lane pose"
        lateral, heading = LANE_POSE_SHIFT
        return False, (f"says privileged, but its {len(plain.commands)} commands did not change when the lane pose "
                       f"moved {lateral:g} m and {heading:g} rad: it does not read it, so declare privileged = False "
                       "(camera-only benchmarks and robots then take it)")

    def check_failure(self) -> tuple[bool, str]:
        agent = self._first()  # done with its episodes: this check may kill it
        said = []
        process = getattr(agent, "process", None)
        if isinstance(process, NodeProcess):
            said.append(self._node_dies(agent))
        close = getattr(agent, "close", None)
        if close is None:
            said.append("no close(): nothing to release")
        else:
            try:
                close()
                close()
            except Exception as exc:
                raise CheckFailed(f"close() raised when called a second time: {describe_error(exc)}", exc) from None
            said.append("close() twice: fine")
        return True, "; ".join(said)

    def _node_dies(self, agent: Any) -> str:
        """Kill the node after two frames: the next answer must be a named failure, the next episode a fresh node."""
        frames = self.stream.stream(0)
        privileged = bool(agent.privileged)
        agent.reset(self.stream.seeds[0])
        for obs in frames[:2]:
            agent.act(as_seen(obs, privileged))
        kill_node(agent.process)
        died = expect_node_failure("node", lambda: agent.act(as_seen(frames[min(2, len(frames) - 1)], privileged)))
        restarts = getattr(agent, "restarts", 0)
        play = self._play(agent, 0, "as-run")
        if play.error is not None or getattr(agent, "restarts", 0) != restarts + 1:
            raise CheckFailed(f"{died}; the next episode did not start a fresh node: {play.ending()}", play.error)
        return f"{died}; the next episode started a fresh node ({len(play.commands)} commands)"


def _camera_node(agent: Any) -> bool:
    """A camera-only agent behind the protocol (the caller sends it no ground truth whatever it is given)."""
    return isinstance(getattr(agent, "process", None), AgentProcess) and not agent.privileged
