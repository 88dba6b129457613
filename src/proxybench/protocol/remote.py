"""A node process behind the in-process :class:`~proxybench.agents.base.Agent` interface.

The runner drives agents through ``reset`` and ``act`` only; :class:`RemoteAgent` maps them onto the AIDO
protocol so that any node, proxybench-served or a real AIDO submission, runs wherever a built-in agent
does. Failures surface as :class:`~.failures.AgentFailure` from ``reset``/``act``, which the runner already
turns into a failed episode; the next ``reset`` starts a fresh process (``restart=True``).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.protocol.process import AgentProcess
from proxybench.protocol.session import NodeSession

__all__ = ["RemoteAgent"]


def _name_of(cmd: str | Sequence[str]) -> str:
    argv = cmd.split() if isinstance(cmd, str) else list(cmd)
    script = next((a for a in reversed(argv) if not a.startswith("-")), "remote")
    return "remote:" + os.path.splitext(os.path.basename(str(script)))[0]


class RemoteAgent(Agent, NodeSession):
    """An agent node in a child process, used exactly like an in-process agent.

    ``reset(seed, episode)`` sends ``seed`` on the first episode of each process (the language allows one)
    and ``episode_start`` every time, with ``yaml_payload = '{"seed": <seed>}'`` so that a served
    proxybench agent is reset with the same seed as in-process; ``act(obs)`` sends ``observations`` and
    ``get_commands(obs.time)`` in one write. ``privileged`` is learned from the node's protocol description
    (None) or forced. Other keyword arguments go to :class:`AgentProcess`.
    """

    def __init__(self, cmd: str | Sequence[str], *, name: str | None = None, restart: bool = True,
                 privileged: bool | None = None, **process_kwargs: Any):
        self._cmd = cmd
        self._kwargs = dict(process_kwargs, privileged=privileged)
        self.name = name or _name_of(cmd)
        self._init_session(lambda: AgentProcess(self._cmd, **self._kwargs), restart)
        self.privileged = self.process.privileged

    def reset(self, seed: int, episode: str | None = None) -> None:
        name = self._begin_episode(seed, episode)
        self.process.episode_start(name, json.dumps({"seed": int(seed)}))

    def act(self, obs: Observation) -> np.ndarray:
        return self.process.step(obs)

