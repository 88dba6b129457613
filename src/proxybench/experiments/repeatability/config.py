"""The settings of a repeatability study (``proxybench repeatability``) and its designs: plain data.

Apart from the study (:mod:`proxybench.experiments.repeatability.run`) so that the command line generated from
:class:`RepeatabilityConfig` does not load the simulator.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, field_validator, model_validator

from proxybench.experiments.config import robot_cwd_from
from proxybench.experiments.study import Cli, StudyConfig
from proxybench.protocol.options import RobotNodeOptions

__all__ = ["DESIGNS", "Design", "RepeatabilityConfig"]


@dataclass(frozen=True)
class Design:
    """``labs`` × ``robots`` per lab × ``runs`` per robot."""

    labs: int = 1
    robots: int = 1
    runs: int = 9

    def __post_init__(self) -> None:
        for name in ("labs", "robots", "runs"):
            if getattr(self, name) < 1:
                raise ValueError(f"design: {name} must be >= 1, got {getattr(self, name)}")
        if self.total < 2:
            raise ValueError(f"design {self.label}: repeatability needs at least 2 runs")

    @property
    def total(self) -> int:
        return self.labs * self.robots * self.runs

    @property
    def label(self) -> str:
        return f"{self.labs}×{self.robots}×{self.runs}"

    @property
    def group(self) -> str | None:
        """What the within/between split is over: robots (inside labs) or labs; None for one robot."""
        return "lab" if self.labs > 1 else "robot" if self.robots > 1 else None

    @classmethod
    def parse(cls, text: str) -> tuple[str, Design]:
        """A named design (``repeatability``, ``inter-robot``, ``inter-lab``) or ``LABSxROBOTSxRUNS``."""
        if text in DESIGNS:
            return text, DESIGNS[text]
        m = re.fullmatch(r"\s*(\d+)\s*[x×]\s*(\d+)\s*[x×]\s*(\d+)\s*", text)
        if not m:
            raise ValueError(f"unknown design {text!r}: use {', '.join(DESIGNS)} or LABSxROBOTSxRUNS (e.g. 1x3x3)")
        d = cls(*(int(g) for g in m.groups()))
        return d.label, d


DESIGNS: dict[str, Design] = {"repeatability": Design(1, 1, 9), "inter-robot": Design(1, 3, 3),
                              "inter-lab": Design(2, 1, 6)}


class RepeatabilityConfig(StudyConfig):
    """A repeatability study: the agent, the designs (simulated) or the recorded runs or the robot nodes."""

    agent: str = "vision"
    """zoo agent"""
    designs: Annotated[tuple[str, ...] | None, Cli("--design", metavar="DESIGN")] = None
    """repeatability | inter-robot | inter-lab | LABSxROBOTSxRUNS (e.g. 1x3x3)"""
    runs: int | None = Field(None, ge=2, le=10_000)
    """runs per robot, overriding every design's"""
    seconds: float = Field(30.0, gt=0.0, le=3600.0)
    """length of each run [s]"""
    map: str = "loop_3x3"
    """map name or file (of recorded runs: the frame of their t, x, y, theta)"""
    seed: int = Field(0, ge=0)
    """seed of the robots, labs, placements and episodes"""
    placement_cm: float = Field(0.5, ge=0.0, le=100.0)
    """operator's placement error across the lane, std [cm]"""
    placement_deg: float = Field(1.0, ge=0.0, le=90.0)
    """operator's placement error of the heading, std [deg]"""
    recorded: Annotated[tuple[Path, ...], Cli("--recorded", metavar="PATH")] = ()
    """recorded runs instead: a LAB/ROBOT/run.csv folder or run files; t, x, y, theta in the map frame"""
    robots: Annotated[dict[str, str], Cli("--robot-cmd", metavar="NAME=COMMAND")] = Field(default_factory=dict)
    """a robot node (one per robot) instead, on the robot protocol: each drives --runs runs (default 3)"""
    robot_options: Annotated[RobotNodeOptions | None, Cli(prefix="robot-")] = None
    """how to start and talk to the robot nodes"""

    @classmethod
    def prepare(cls, data: dict[str, Any], folder: Path | None) -> dict[str, Any]:
        """Recorded paths and the robot nodes' working directory: a file's inside its ``folder``, the command
        line's from where the command runs."""
        from proxybench.untrusted import inside

        recorded = data.get("recorded")
        if isinstance(recorded, list | tuple):
            data = {**data, "recorded": [
                (str(inside(folder, p, field=f"recorded.{i}")) if folder is not None else str(Path(p).expanduser()))
                if isinstance(p, str) else p for i, p in enumerate(recorded)]}
        return robot_cwd_from(data, folder)

    @field_validator("designs")
    @classmethod
    def _designs(cls, v: tuple[str, ...] | None) -> tuple[str, ...] | None:
        for text in v or ():
            Design.parse(text)
        return v

    @model_validator(mode="after")
    def _one_source(self) -> RepeatabilityConfig:
        if self.recorded and self.robots:
            raise ValueError("recorded and robots: give recorded runs or robot nodes, not both")
        if any(not name.strip() or not cmd.strip() for name, cmd in self.robots.items()):
            raise ValueError("robots: each needs a name and a command (NAME=COMMAND)")
        if self.robot_options is not None and not self.robots:
            raise ValueError("robot_options: only with robots (--robot-cmd): they say how to start its robot nodes")
        return self

    @property
    def source(self) -> str:
        return "recorded" if self.recorded else "robot node" if self.robots else "reality-model"
