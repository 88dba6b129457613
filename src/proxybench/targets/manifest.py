"""The manifest of a recorded target: ``target.yaml`` at the root of a directory of recorded episodes.

A lab writes it once beside its files (``proxybench target record`` writes it for recordings it makes)::

    format: proxybench-target/1
    source: real                 # real | reality-model | robot-node | simulation
    description: DB21 robots, lane following, Autolab Montréal
    who: Duckietown lab
    where: Autolab 2
    when: 2024-05-14
    map: loop_3x3                # a built-in map, or a map file relative to this manifest
    seconds: 60                  # the length of every episode (a run that ends earlier left the road)
    agents: [pid, vision, my-agent]
    episodes: [0, 1, 2, 3]       # every agent has these episodes
    trajectories: "runs/{agent}/{episode}.csv"   # CSV/Parquet: t [s], x [m], y [m], theta [rad] (map frame)
    # or, for a lab that kept only scores:
    # metrics_table: scores.csv  # columns agent, episode, then one column per metric

The model is strict: an unknown key or a value of the wrong kind is an error naming the field.
"""

from __future__ import annotations

import difflib
import typing
from datetime import date, datetime
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from proxybench.domain.kinds import ROBOT_NODE, DomainKind
from proxybench.protocol.options import RobotNodeOptions

__all__ = ["FORMAT", "MANIFEST_NAME", "SOURCES", "SOURCE_KINDS", "RobotInfo", "TargetError", "TargetManifest",
           "format_errors", "load_manifest", "source_of", "write_manifest"]

FORMAT = "proxybench-target/1"
MANIFEST_NAME = "target.yaml"
#: where a recording came from (its ``source``) → the :class:`DomainKind` its episodes ran in. The manifest keeps
#: its own words on purpose: ``robot-node`` for a robot domain (a process on the robot protocol, whose own
#: description says whether it simulates), and ``real`` for physical robots recorded outside proxybench, which no
#: domain kind names (proxybench never ran them). Only ``real`` is a physical robot; the others are simulations
SOURCE_KINDS: dict[str, DomainKind | None] = {"real": None, "reality-model": DomainKind.REALITY_MODEL,
                                              ROBOT_NODE: DomainKind.ROBOT, "simulation": DomainKind.SIMULATION}
SOURCES = tuple(SOURCE_KINDS)
DEFAULT_TRAJECTORIES = "episodes/{agent}/{episode}.parquet"


def source_of(kind: DomainKind) -> str:
    """The manifest's word for recordings made on a domain of ``kind``.

    >>> source_of(DomainKind.ROBOT), source_of(DomainKind.REALITY_MODEL)
    ('robot-node', 'reality-model')
    """
    return next(s for s, k in SOURCE_KINDS.items() if k is kind)


class TargetError(ValueError):
    """A target that cannot be used; the message names the file, row, column or field at fault."""


class RobotInfo(BaseModel):
    """The robot node a recording was made on: its command, what it said it is, and how it was started
    (``options``: working directory, transport, timeouts, reflection; None in recordings made before
    proxybench kept them). Provenance only: nothing is started from a recording."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    command: str = Field(min_length=1, description="the command that started the robot node")
    kind: str = Field("", description="what the node said it is (its robot_interface_description)")
    options: RobotNodeOptions | None = Field(None, description="how the node was started (--robot-cwd, ...)")

    def describe(self) -> str:
        """One line: the command and, when known, how it was started.

        >>> RobotInfo(command="./bridge", options=RobotNodeOptions(cwd="/lab", transport="fifo")).describe()
        '`./bridge` (cwd /lab, transport fifo, start timeout 120 s, step timeout 10 s, describe_protocol asked)'
        """
        if self.options is None:
            return f"`{self.command}` (start-up options not recorded)"
        o = self.options
        parts = [f"cwd {o.cwd}" if o.cwd else "cwd: that of the recording command", f"transport {o.transport}"]
        parts += [f"FIFOs in {o.fifo_dir}"] if o.fifo_dir else []
        parts += [f"start timeout {o.start_timeout:g} s", f"step timeout {o.step_timeout:g} s",
                  "describe_protocol asked" if o.reflection else "no describe_protocol"]
        return f"`{self.command}` ({', '.join(parts)})"


class TargetManifest(BaseModel):
    """What a recorded target holds and where it came from."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: Literal["proxybench-target/1"] = FORMAT
    source: Literal["real", "reality-model", "robot-node", "simulation"] = Field(
        description="real (physical robots), reality-model (proxybench's simulated stand-in), robot-node (a "
                    "process on the robot protocol), simulation (another simulator)")
    description: str = ""
    who: str = ""
    where: str = ""
    when: str = ""
    map: str = Field(min_length=1, description="built-in map name, or a map file relative to the manifest")
    seconds: float = Field(gt=0.0, le=3600.0, description="length of every episode [s]")
    agents: list[str] = Field(min_length=1, description="agent names, as the experiments' --agent labels")
    episodes: list[int] = Field(min_length=1, description="episode ids; every agent has each of them")
    trajectories: str | None = Field(None, description="file pattern with {agent} and {episode}")
    metrics_table: str | None = Field(None, description="CSV/Parquet with agent, episode and metric columns")
    seed: int = Field(0, ge=0, description="experiment seed the episode seeds derive from (seed·10000 + episode)")
    robot: RobotInfo | None = None
    params: dict[str, Any] | None = Field(None, description="θ of a simulated target, for the record")
    truth: dict[str, float] | None = Field(None, description="known calibrated θ, to annotate results only")
    recorded_with: str = ""

    @field_validator("when", mode="before")
    @classmethod
    def _date_text(cls, v: Any) -> Any:
        return v.isoformat() if isinstance(v, date | datetime) else v  # YAML reads 2024-05-14 as a date

    @field_validator("agents")
    @classmethod
    def _unique_agents(cls, v: list[str]) -> list[str]:
        seen: set[str] = set()
        for a in v:
            if not a.strip():
                raise ValueError("an agent name is empty")
            if a in seen:
                raise ValueError(f"agent {a!r} is listed twice")
            seen.add(a)
        return v

    @field_validator("episodes")
    @classmethod
    def _unique_episodes(cls, v: list[int]) -> list[int]:
        if len(set(v)) != len(v):
            raise ValueError("an episode id is listed twice")
        if any(e < 0 for e in v):
            raise ValueError("episode ids are ≥ 0")
        return v

    @model_validator(mode="after")
    def _one_kind(self) -> TargetManifest:
        if self.trajectories is not None and self.metrics_table is not None:
            raise ValueError("give trajectories or metrics_table, not both")
        if self.trajectories is not None:
            for key in ("{agent}", "{episode}"):
                if key not in self.trajectories:
                    raise ValueError(f"trajectories: the pattern {self.trajectories!r} lacks {key}")
        if self.domain_kind is DomainKind.ROBOT and self.robot is None:
            raise ValueError("source robot-node needs robot: {command: ...}")
        return self

    @property
    def kind(self) -> str:
        """``trajectories`` (one file per agent and episode) or ``metrics`` (a table of scores)."""
        return "metrics" if self.metrics_table is not None else "trajectories"

    @property
    def pattern(self) -> str:
        return self.trajectories or DEFAULT_TRAJECTORIES

    @property
    def simulated(self) -> bool:
        return self.source != "real"

    @property
    def domain_kind(self) -> DomainKind | None:
        """The kind of domain the episodes ran in (None: real robots, recorded outside proxybench)."""
        return SOURCE_KINDS[self.source]


def _allowed(model: type[BaseModel], loc: tuple) -> list[str]:
    fields = model.model_fields
    for part in loc:
        if isinstance(part, int):  # an item of a list
            continue
        f = fields.get(str(part))
        sub = _model_fields(f.annotation) if f is not None else None
        if sub is None:
            return list(fields)
        fields = sub
    return list(fields)


def _model_fields(annotation: Any) -> dict[str, Any] | None:
    """The fields of the model in ``annotation`` (itself, or inside ``X | None`` / ``list[X]``), if any."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation.model_fields
    for arg in typing.get_args(annotation):
        found = _model_fields(arg)
        if found is not None:
            return found
    return None


def format_errors(exc: ValidationError, origin: str, model: type[BaseModel]) -> str:
    """One ``<origin>: <field>: <message>`` line per problem; unknown keys get a did-you-mean hint."""
    lines = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        if not loc:  # checks of the whole model name their fields in the message, one line each
            lines.extend(f"{origin}: {line}" for line in msg.splitlines())
            continue
        if err["type"] == "extra_forbidden":
            allowed = _allowed(model, err["loc"][:-1])
            close = difflib.get_close_matches(str(err["loc"][-1]), allowed, n=1)
            msg = "unknown key" + (f" (did you mean {close[0]!r}?)" if close else f"; known: {', '.join(allowed)}")
        elif err["type"] == "missing":
            msg = "required, missing"
        lines.append(f"{origin}: {loc}: {msg}")
    return "\n".join(lines)


def load_manifest(root: str | Path) -> TargetManifest:
    """Read ``root/target.yaml`` (or a manifest file given directly)."""
    root = Path(root)
    path = root / MANIFEST_NAME if root.is_dir() else root
    if not path.exists():
        where = f"{root} has no {MANIFEST_NAME}" if root.is_dir() else f"{root}: no such file or directory"
        raise TargetError(f"{where} (write one as in docs/targets.md, or record one with `proxybench target record`)")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise TargetError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise TargetError(f"{path}: expected a mapping of fields, got {type(data).__name__}")
    try:
        return TargetManifest.model_validate(data)
    except ValidationError as exc:
        raise TargetError(format_errors(exc, str(path), TargetManifest)) from None


def write_manifest(root: str | Path, manifest: TargetManifest) -> Path:
    """Write ``root/target.yaml`` atomically."""
    path = Path(root) / MANIFEST_NAME
    data = manifest.model_dump(mode="json", exclude_none=True)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True))
    tmp.replace(path)
    return path
