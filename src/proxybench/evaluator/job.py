"""What the evaluator hands a job's worker: the typed lease and how to run it (``JOB_DIR/job.json``).

The loop (:mod:`.loop`) writes it with the model's own JSON and the worker (:mod:`.run`) parses it back into
the model, so the lease of :mod:`proxybench.contract` stays one typed object from the server's reply to the
worker's last read: no field is looked up by a string key on the way, and a file that does not parse is
refused naming the field. The file holds the hidden test seed: its folder is the evaluator user's only.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from proxybench.autolab.lab import Lab
from proxybench.contract import Lease
from proxybench.evaluator.lab_world import WorldAddress
from proxybench.evaluator.sandbox import Isolation, Limits

__all__ = ["EvaluatorInfo", "WorkerJob"]


class EvaluatorInfo(BaseModel):
    """Who evaluates: the evaluator's name, the features it offers and its proxybench version."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    features: list[str] = Field(default_factory=list)
    version: str = ""


class WorkerJob(BaseModel):
    """One leased job as its worker sees it. ``job_features``: what the job needs (``sim``, ``target``);
    ``isolation`` and ``limits``: how agent packages run here; ``video``: record the first validation
    episode; ``robot_cmd`` / ``robot_options``: the robot node target jobs run on (None: the reality model)
    and how to start it (the non-default fields of ``RobotNodeOptions``); ``autolab``: the lab (``lab.yaml``, its
    paths absolute) whose robot and watchtowers run and measure Autolab jobs (:mod:`.autolab`); ``autolab_robot``: the
    lab's robot this job holds (:mod:`.robots`; None: the first)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    lease: Lease
    job_features: list[str] = Field(default_factory=list)
    evaluator: EvaluatorInfo
    isolation: Isolation
    limits: Limits = Field(default_factory=Limits)
    video: bool = True
    robot_cmd: str | None = None
    robot_options: dict[str, Any] = Field(default_factory=dict)
    autolab: Lab | None = None
    autolab_robot: str | None = None
    #: the lab's shared world (``world: shared``) this job's robot lives in: its server's socket and key
    lab_world: WorldAddress | None = None

    @model_validator(mode="after")
    def _robot_of_the_lab(self) -> WorkerJob:
        if self.lab_world is not None and (self.autolab is None or self.autolab.world != "shared"):
            raise ValueError("lab_world: given for a job whose lab (autolab) has no shared world")
        if self.autolab_robot is not None:
            if self.autolab is None:
                raise ValueError("autolab_robot: a robot is given but no lab (autolab)")
            names = [r.name for r in self.autolab.robots]
            if self.autolab_robot not in names:
                raise ValueError(f"autolab_robot: lab {self.autolab.name!r} has no robot {self.autolab_robot!r} "
                                 f"(it has {', '.join(names)})")
        return self

    def write(self, path: Path) -> Path:
        """Write the job as JSON (the model's own)."""
        path.write_text(self.model_dump_json(indent=1))
        return path

    @classmethod
    def read(cls, path: Path) -> WorkerJob:
        """Parse a file written by :meth:`write` (a ``pydantic.ValidationError`` names the field at fault)."""
        return cls.model_validate_json(path.read_text())
