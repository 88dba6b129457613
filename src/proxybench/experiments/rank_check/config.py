"""What rank-check is told: the family, the targets, the agents and the episodes (unset: the mode's default)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field

from proxybench.experiments.study import Cli, StudyConfig

__all__ = ["DEFAULTS", "RankCheckConfig"]

#: what a field left unset takes, in the full and the --quick mode
DEFAULTS: dict[bool, dict[str, Any]] = {
    False: {"targets": 40, "episodes": 10, "truth_episodes": 60, "seconds": 10.0, "proxy_episodes": 100,
            "agents": ["straight", "bang-bang", "pid", "pid-fast", "pid-twitchy", "pure-pursuit", "vision",
                       "vision-fast"]},
    True: {"targets": 2, "episodes": 4, "truth_episodes": 10, "seconds": 4.0, "proxy_episodes": 8,
           "agents": ["straight", "pid", "pid-fast"]},
}


class RankCheckConfig(StudyConfig):
    """Which targets, how many episodes, which agents; unset: the mode's default."""

    family: Literal["heldout", "gym"] = "heldout"
    """heldout (proxybench's held-out stand-ins) | gym (gym-duckietown nodes; `proxybench gym setup` first)"""
    targets: int | None = Field(None, ge=1, le=1000)
    """targets drawn from the family"""
    agents: Annotated[list[str] | None, Cli("--agent", metavar="AGENT")] = Field(None, min_length=2)
    """zoo agents ranked on every target"""
    episodes: int | None = Field(None, ge=2, le=1000)
    """target episodes per agent that rank decides from"""
    truth_episodes: int | None = Field(None, ge=2, le=10_000)
    """further target episodes per agent (other ids) that judge the decisions"""
    seconds: float | None = Field(None, gt=0.0, le=600.0)
    """episode length [s]"""
    proxy_episodes: int | None = Field(None, ge=2, le=100_000)
    """the proxy's own episodes per agent"""
    alpha: float = Field(0.05, gt=0.0, lt=1.0)
    """rank's level"""
    seed: int = Field(0, ge=0, le=100_000)
    """the targets' draw and their episodes"""

    def filled(self, quick: bool) -> RankCheckConfig:
        """This config with the mode's defaults where a field is unset."""
        d = DEFAULTS[quick]
        return self.model_copy(update={k: v for k, v in d.items() if getattr(self, k) is None})
