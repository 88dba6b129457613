"""Caller-side life of a node across episodes, shared by :class:`~.remote.RemoteAgent` and
:class:`~.robot_process.RemoteRobot`: one ``seed`` per process, episode names, a fresh process after a
failure, no second ``describe_protocol`` for a node that failed it once, and closing it (a context manager)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Self

from proxybench.protocol.process import NodeProcess

__all__ = ["NodeSession"]


class NodeSession:
    """Caller-side life of a node across episodes (a mixin of RemoteAgent and RemoteRobot): the process is
    seeded once (the languages allow one ``seed``) and, with ``restart``, replaced after a failure. The
    factory reads its options from ``self._kwargs``: once a node has failed ``describe_protocol``, its
    replacements start without asking (``reflection=False``), saving the failed start each time."""

    process: NodeProcess
    _kwargs: dict[str, Any]

    def _init_session(self, factory: Callable[[], NodeProcess], restart: bool) -> None:
        self._factory = factory
        self.restart = restart
        self.restarts = 0
        self.process = self._new_process()
        self._seeded = False
        self._episodes = 0

    def _new_process(self) -> NodeProcess:
        process = self._factory()
        if process.reflection_note is not None:
            self._kwargs["reflection"] = False
        return process

    def _begin_episode(self, seed: int, episode: str | None) -> str:
        """Restart a failed process if allowed, send ``seed`` once per process; returns the episode's name."""
        if not self.process.alive and self.process.failure is not None and self.restart:
            self.process = self._new_process()
            self.restarts += 1
            self._seeded = False
        if not self._seeded:
            self.process.seed(int(seed))
            self._seeded = True
        name = episode if episode is not None else f"episode-{self._episodes}"
        self._episodes += 1
        return name

    def close(self) -> int | None:
        """End the node process; its exit status."""
        return self.process.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
