"""Agent kinds beyond the zoo (a behaviour-cloning checkpoint, a user's own loader), found by entry point.

An agent is named by a string: a zoo name, or something a *kind* claims (a checkpoint path ``X.pt``). A kind
is an object registered under the ``proxybench.agent_kinds`` entry-point group (``pyproject.toml``), so the
agents layer resolves a checkpoint without importing the learning code above it, and a user package can
add a kind of its own::

    [project.entry-points."proxybench.agent_kinds"]
    my-kind = "my_package.loader:KIND"

A kind has ``claims(name) -> bool`` (cheap: no PyTorch), ``make(name) -> Agent`` and ``identity(name) ->
str``: what identifies the agent's behaviour in a cached job's key (e.g. a digest of its files, so that
retraining into the same path invalidates cached episodes).
"""

from __future__ import annotations

from functools import cache
from importlib.metadata import EntryPoint, entry_points
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from proxybench.agents.base import Agent

__all__ = ["GROUP", "AgentKind", "find_kind", "kinds"]

GROUP = "proxybench.agent_kinds"
#: the kinds proxybench ships, also when it runs from a source tree without installed metadata
BUILT_IN = (EntryPoint("checkpoint", "proxybench.learning:CHECKPOINTS", GROUP),)


class AgentKind(Protocol):
    """A family of agents named by strings that are not zoo names."""

    def claims(self, name: str) -> bool: ...

    def make(self, name: str) -> Agent: ...

    def identity(self, name: str) -> str: ...


@cache
def kinds() -> tuple[tuple[str, AgentKind], ...]:
    """(name, kind) of every registered kind: the built-in ones, then those of installed packages."""
    found = {ep.name: ep for ep in BUILT_IN}
    for ep in entry_points(group=GROUP):
        found.setdefault(ep.name, ep)
    return tuple((name, ep.load()) for name, ep in found.items())


def find_kind(name: str) -> AgentKind | None:
    """The kind that claims the agent ``name`` (not a zoo name), if any."""
    return next((kind for _, kind in kinds() if kind.claims(name)), None)
