"""The settings of the held-out experiment (``proxybench heldout``): :class:`HeldOutConfig` and its criteria.

Apart from the experiment (:mod:`proxybench.experiments.heldout.run`), so that the command line generated from the
config loads neither the runner nor the targets.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from proxybench.domain.params import check_image_size
from proxybench.experiments.config import param_values
from proxybench.experiments.study import Cli, StudyConfig

__all__ = ["DEFAULTS", "Criteria", "HeldOutConfig", "HeldOutSettings", "ModeDefaults", "default_help",
           "load_heldout_config"]

_FULL_AGENTS = ("straight", "bang-bang", "pid", "pid-fast", "pid-sluggish", "pid-twitchy", "pure-pursuit",
                "vision", "vision-fast", "vision-slow", "vision-pitch25", "vision-twitchy")
_QUICK_AGENTS = ("straight", "pid", "pid-twitchy", "pure-pursuit", "vision", "vision-fast", "vision-pitch25",
                 "vision-slow")


class Criteria(StudyConfig):
    """When a metric's pick counts as a hit; fixed before anything runs (every combination is tabled)."""

    primary_reference: Literal["order", "truth"] = "order"
    """what the report's verdicts compare a pick with: order (the best available θ, see heldout_scoring) or truth
    (the grid θ nearest the hidden truth)"""
    primary_tolerance_steps: int = Field(1, ge=0, le=10)
    """how many grid steps (along any axis) the verdicts' pick may be from it"""
    tolerances: tuple[int, ...] = (0, 1)
    """the tolerances [grid steps] tabled"""
    level: float = Field(0.95, gt=0.5, lt=1.0)
    """confidence level of the intervals"""


class HeldOutConfig(StudyConfig):
    """The experiment file of ``proxybench heldout`` (every field has a default; ``--quick`` smaller ones)."""

    targets: int | None = Field(None, ge=1, le=1000)
    """held-out targets drawn"""
    family_seed: int = Field(20_250, ge=0)
    """seed of the held-out family: only the targets read it"""
    negative_case: bool = True
    """add the standing negative case (the shipped reality model against pinhole proxies)"""
    agents: Annotated[list[str] | None, Cli("--agent", metavar="AGENT")] = Field(None, min_length=2)
    """zoo name, NAME=COMMAND (node), NAME=sdk:COMMAND (duckietown-sdk program), checkpoint X.pt, or agent package
    .zip/.tar.gz"""
    map: str = "loop_3x3"
    """map name or file"""
    episodes: int | None = Field(None, ge=1, le=1000)
    """evaluation episodes per agent"""
    reference_episodes: int | None = Field(None, ge=2, le=1000)
    """reference episodes per agent (other seeds): they give the best available θ"""
    seconds: float | None = Field(None, gt=0.0, le=3600.0)
    """episode length [s]"""
    tasks: Annotated[dict[str, tuple[str, ...]], Cli("--task", metavar="NAME=METRIC,METRIC")] = Field(
        default_factory=lambda: {"distance+lane_score": ("driven_lanedir_consec", "lane_score"),
                                 "distance+survival (thesis)": ("driven_lanedir_consec", "survival_time")})
    """a task: its name and its metrics"""
    primary_task: str = "distance+lane_score"
    """the task the report's verdicts use (one of the tasks)"""
    grid: Annotated[dict[str, tuple[float, ...]] | None, Cli("--grid")] = None
    """proxy θ grid: the values of one axis"""
    image_size: Annotated[tuple[int, int], Cli(metavar="WIDTHxHEIGHT", sep="x")] = (160, 120)
    """camera image [px]"""
    criteria: Criteria = Field(default_factory=Criteria)
    """when a pick is a hit"""
    n_boot: int | None = Field(None, ge=10, le=100_000)
    """bootstrap resamples per θ"""
    agent_boot: int = Field(200, ge=10, le=100_000)
    """bootstrap agent sets (sensitivity to the agent set)"""
    reference_boot: int = Field(50, ge=0, le=10_000)
    """bootstrap resamples of the reference episodes (stability of the best available θ)"""
    seed: int = Field(0, ge=0, le=100_000)
    """episode and resampling seed"""

    _image = field_validator("image_size")(check_image_size)

    @field_validator("tasks")
    @classmethod
    def _tasks(cls, v: dict[str, tuple[str, ...]]) -> dict[str, tuple[str, ...]]:
        from proxybench.tasks.metrics import METRICS

        if not v:
            raise ValueError("give at least one task")
        for name, metrics in v.items():
            for m in metrics:
                if m not in METRICS:
                    raise ValueError(f"task {name!r}: unknown metric {m!r}; known: {', '.join(METRICS)}")
            if not metrics or len(set(metrics)) != len(metrics):
                raise ValueError(f"task {name!r}: give distinct metrics")
        return v

    @field_validator("grid")
    @classmethod
    def _grid(cls, v: dict[str, tuple[float, ...]] | None) -> dict[str, tuple[float, ...]] | None:
        param_values(v, 2, "grid ")
        return v

    @model_validator(mode="after")
    def _primary_task(self) -> HeldOutConfig:
        if self.primary_task not in self.tasks:
            raise ValueError(f"primary_task: {self.primary_task!r} is not one of the tasks ({', '.join(self.tasks)})")
        return self


class ModeDefaults(BaseModel):
    """What a field left unset takes, in one mode (full or ``--quick``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    targets: int
    agents: tuple[str, ...]
    episodes: int
    reference_episodes: int
    seconds: float
    grid: dict[str, tuple[float, ...]]
    n_boot: int


#: defaults per mode (False: full, True: ``--quick``)
DEFAULTS: dict[bool, ModeDefaults] = {
    False: ModeDefaults(targets=12, agents=_FULL_AGENTS, episodes=3, reference_episodes=8, seconds=20.0,
                        grid={"trim": (-0.2, -0.1, 0.0, 0.1, 0.2),
                              "camera_pitch": (15.15, 17.15, 19.15, 21.15, 23.15)}, n_boot=100),
    True: ModeDefaults(targets=3, agents=_QUICK_AGENTS, episodes=2, reference_episodes=4, seconds=12.0,
                       grid={"trim": (-0.2, 0.0, 0.2), "camera_pitch": (15.15, 19.15, 23.15)}, n_boot=50),
}


def default_help() -> dict[str, str]:
    """How ``--help`` words the defaults that ``--quick`` settles."""
    full, quick = DEFAULTS[False], DEFAULTS[True]

    def grid(g: dict[str, tuple[float, ...]]) -> str:
        return " × ".join(f"{k} {v[0]:g}…{v[-1]:g} in {len(v)}" for k, v in g.items())

    out = {k: f"{getattr(full, k):g}; --quick {getattr(quick, k):g}"
           for k in ("targets", "episodes", "reference_episodes", "seconds", "n_boot")}
    return out | {"agents": f"{len(full.agents)} zoo agents; --quick {len(quick.agents)}",
                  "grid": f"{grid(full.grid)}; --quick {grid(quick.grid)}"}


class HeldOutSettings(BaseModel):
    """Every choice of a held-out study (the config, then its mode's defaults): what criteria.json pre-registers
    (``model_dump(mode="json")``, fields in this order) and what the run, the scoring and the report read."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    quick: bool
    targets: int
    family_seed_sha256: str
    negative_case: bool
    agents: tuple[str, ...]
    map: str
    episodes: int
    reference_episodes: int
    seconds: float
    tasks: dict[str, tuple[str, ...]]
    primary_task: str
    grid: dict[str, tuple[float, ...]]
    image_size: tuple[int, int]
    criteria: Criteria
    n_boot: int
    agent_boot: int
    reference_boot: int
    seed: int


def load_heldout_config(path: str | Path | None, overrides: dict[str, Any] | None = None) -> HeldOutConfig:
    """The experiment file at ``path`` (or none) with ``overrides`` on top; errors name the field."""
    return HeldOutConfig.load(path, overrides)
