"""The manifest of a recorded target: ``target.yaml`` at the root of a directory of recorded episodes.

A lab writes it once beside its files (``proxybench target record`` writes it for recordings it makes)::

    format: proxybench-target/1
    source: real                 # real | reality-model | robot-node | dtps-robot | simulation
    description: DB21 robots, lane following, Autolab Montréal
    who: Duckietown lab
    where: Autolab 2
    when: 2024-05-14
    map: loop_3x3                # a built-in map, or a map file relative to this manifest
    seconds: 60                  # the length of every episode (a run that ends earlier left the road)
    agents: [pid, vision, my-agent]
    episodes: [0, 1, 2, 3]       # every agent has these episodes ("00", "01", … are kept as written)
    trajectories: "runs/{agent}/{episode}.csv"   # CSV/Parquet: t [s], x [m], y [m], theta [rad] (map frame)
    # or, for a lab that kept only scores:
    # metrics_table: scores.csv  # columns agent, episode, then one column per metric

The model is strict: an unknown key or a value of the wrong kind is an error naming the field. Names end
up in file paths, so they are checked as such: an agent name is one path component (no ``/``, not ``..``),
and ``trajectories`` is a template with exactly ``{agent}`` and ``{episode}`` (``{episode:03d}``: the
episode zero-padded, the one format allowed), relative to the manifest's folder and never leaving it.
"""

from __future__ import annotations

import difflib
import re
import string
import typing
from datetime import date, datetime
from pathlib import Path, PurePosixPath
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, field_validator, model_validator

from proxybench.domain.kinds import ROBOT_NODE, DomainKind
from proxybench.dtps.robot_options import DtpsRobotOptions
from proxybench.protocol.options import RobotNodeOptions
from proxybench.untrusted import UntrustedInputError, load_yaml_file

__all__ = ["FORMAT", "MANIFEST_NAME", "SOURCES", "SOURCE_KINDS", "ExcludedRun", "RobotInfo", "SimulatorInfo",
           "TargetError", "TargetManifest", "check_pattern", "format_errors", "load_manifest", "source_of",
           "write_manifest"]

FORMAT = "proxybench-target/1"
MANIFEST_NAME = "target.yaml"
#: where a recording came from (its ``source``) → the :class:`DomainKind` its episodes ran in. The manifest keeps
#: its own words on purpose: ``robot-node`` for a robot domain (a process on the robot protocol, whose own
#: description says whether it simulates), ``dtps-robot`` for a DTPS robot (real or a Duckiematrix robot, which
#: proxybench cannot tell apart: the recording says what the user said), and ``real`` for physical robots recorded
#: outside proxybench, which no domain kind names (proxybench never ran them). Only ``real`` is a physical robot
SOURCE_KINDS: dict[str, DomainKind | None] = {"real": None, "reality-model": DomainKind.REALITY_MODEL,
                                              ROBOT_NODE: DomainKind.ROBOT, "dtps-robot": DomainKind.ROBOT,
                                              "simulation": DomainKind.SIMULATION}
SOURCES = tuple(SOURCE_KINDS)
DEFAULT_TRAJECTORIES = "episodes/{agent}/{episode}.parquet"
MANIFEST_MAX_BYTES = 1 << 20
#: an agent's name: one path component (it is put into file names)
_AGENT_NAME = re.compile(r"[^/\\\x00-\x1f\x7f]{1,128}")
_EPISODE_ID = re.compile(r"[0-9]{1,9}")
_PADDING = re.compile(r"0[1-9][0-9]?d")  # {episode:02d} … {episode:099d}


def check_pattern(pattern: str) -> str:
    """A ``trajectories`` template: ``{agent}`` and ``{episode}`` (or ``{episode:0Nd}``) in a relative path that
    stays in the manifest's folder. Anything else of ``str.format`` (``{0}``, ``{agent[1]}``, ``{agent.x}``,
    ``!r``, other format specs) is refused: the pattern comes from a file."""
    try:
        parsed = list(string.Formatter().parse(pattern))
    except ValueError as exc:
        raise ValueError(f"{pattern!r} is not a valid pattern ({exc}; write braces as {{{{ and }}}})") from None
    seen = set()
    for _, name, spec, conversion in parsed:
        if name is None:
            continue
        if name not in ("agent", "episode"):
            raise ValueError(f"{pattern!r}: {{{name}}} is not allowed (only {{agent}} and {{episode}})")
        if conversion or (spec and not (name == "episode" and _PADDING.fullmatch(spec))):
            raise ValueError(f"{pattern!r}: {{{name}{'!' + conversion if conversion else ''}:{spec}}} is not allowed "
                             "(the one format is zero-padding of the episode, e.g. {episode:03d})")
        seen.add(name)
    for key in ("agent", "episode"):
        if key not in seen:
            raise ValueError(f"the pattern {pattern!r} lacks {{{key}}}")
    if pattern.startswith(("/", "~")) or "\\" in pattern or ".." in PurePosixPath(pattern).parts:
        raise ValueError(f"{pattern!r} must be a path relative to the manifest's folder, without '..'")
    return pattern


def source_of(kind: DomainKind) -> str:
    """The manifest's word for recordings made on a domain of ``kind``.

    >>> source_of(DomainKind.ROBOT), source_of(DomainKind.REALITY_MODEL)
    ('robot-node', 'reality-model')
    """
    return next(s for s, k in SOURCE_KINDS.items() if k is kind)


class TargetError(ValueError):
    """A target that cannot be used; the message names the file, row, column or field at fault."""


class SimulatorInfo(BaseModel):
    """Which simulator a simulated robot node is (e.g. gym-duckietown), its version and θ; a hidden θ is kept
    only as its hash (``params`` then holds ``{hidden: true, sha256: ...}``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(min_length=1)
    package: str = ""
    version: str = ""
    hidden: bool = False
    sha256: str = ""
    changed: dict[str, Any] | None = Field(None, description="θ that differs from the simulator's defaults")

    def describe(self) -> str:
        """``gym-duckietown 6.1.34, trim=0.1``, ``..., its default parameters`` or ``..., parameters hidden``.

        >>> SimulatorInfo(name="gym-duckietown", version="6.1.34", changed={"trim": 0.1}).describe()
        'gym-duckietown 6.1.34, trim=0.1'
        """
        what = f"{self.name} {self.version}".strip()
        if self.hidden:
            return f"{what}, parameters hidden (sha256 {self.sha256[:16]}…)"
        if self.changed is None:
            return what
        return what + (", " + ", ".join(f"{k}={v}" for k, v in self.changed.items()) if self.changed
                       else ", its default parameters")


class RobotInfo(BaseModel):
    """The robot node a recording was made on: its command, what it said it is, and how it was started
    (``options``: working directory, transport, timeouts, reflection; None in recordings made before
    proxybench kept them). Provenance only: nothing is started from a recording."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    command: str = Field(min_length=1, description="the command that started the robot node")
    kind: str = Field("", description="what the node said it is (its robot_interface_description)")
    options: RobotNodeOptions | None = Field(None, description="how the node was started (--robot-cwd, ...)")
    simulator: SimulatorInfo | None = Field(None, description="which simulator a simulated node said it is")
    dtps: DtpsRobotOptions | None = Field(None, description="a DTPS robot (command dtps:ADDRESS): how it was driven")

    def describe(self) -> str:
        """One line: the command and, when known, how it was started.

        >>> RobotInfo(command="./bridge", options=RobotNodeOptions(cwd="/lab", transport="fifo")).describe()
        '`./bridge` (cwd /lab, transport fifo, start timeout 120 s, step timeout 10 s, describe_protocol asked)'
        """
        if self.dtps is not None:
            d = self.dtps
            pose = d.pose if not d.pose_url else f"{d.pose} on {d.pose_url}"
            return f"`{self.command}` (pose from {pose}, commands on {d.pwm}, reset by {d.reset})"
        if self.options is None:
            return f"`{self.command}` (start-up options not recorded)"
        o = self.options
        parts = [f"cwd {o.cwd}" if o.cwd else "cwd: that of the recording command", f"transport {o.transport}"]
        parts += [f"FIFOs in {o.fifo_dir}"] if o.fifo_dir else []
        parts += [f"start timeout {o.start_timeout:g} s", f"step timeout {o.step_timeout:g} s",
                  "describe_protocol asked" if o.reflection else "no describe_protocol"]
        return f"`{self.command}` ({', '.join(parts)})"


class ExcludedRun(BaseModel):
    """A run the lab recorded but that may not be scored (the DTA's validation phase), and why."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    agent: str
    run: str = Field(description="where the run's log is")
    reason: str = Field(min_length=1)


class TargetManifest(BaseModel):
    """What a recorded target holds and where it came from."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: Literal["proxybench-target/1"] = FORMAT
    source: Literal["real", "reality-model", "robot-node", "dtps-robot", "simulation"] = Field(
        description="real (physical robots), reality-model (proxybench's simulated stand-in), dtps-robot (a DTPS "
                    "robot proxybench drove: real or a Duckiematrix robot, as the user said), robot-node (a "
                    "process on the robot protocol), simulation (another simulator)")
    description: str = ""
    who: str = ""
    where: str = ""
    when: str = ""
    map: str = Field(min_length=1, description="built-in map name, or a map file relative to the manifest")
    seconds: float = Field(gt=0.0, le=3600.0, description="length of every episode [s]")
    agents: list[str] = Field(min_length=1, max_length=10_000,
                              description="agent names, as the experiments' --agent labels")
    episodes: list[int] = Field(min_length=1, max_length=100_000,
                                description="episode ids (numbers, or digits as written: \"07\"); every agent has "
                                            "each of them")
    trajectories: str | None = Field(None, description="file pattern with {agent} and {episode} (or {episode:03d})")
    metrics_table: str | None = Field(None, description="CSV/Parquet with agent, episode and metric columns")
    seed: int = Field(0, ge=0, description="experiment seed the episode seeds derive from (seed·10000 + episode)")
    robot: RobotInfo | None = None
    params: dict[str, Any] | None = Field(None, description="θ of a simulated target, for the record")
    truth: dict[str, Annotated[float, Field(allow_inf_nan=False)]] | None = Field(
        None, description="known calibrated θ, to annotate results only")
    recorded_with: str = ""
    excluded: list[ExcludedRun] = Field(default_factory=list, description="runs left out of the episodes, and why")
    _written: dict[int, str] = PrivateAttr(default_factory=dict)  # episode ids as the file wrote them

    @model_validator(mode="wrap")
    @classmethod
    def _keep_written_ids(cls, data: Any, handler: Any) -> TargetManifest:
        """Episode ids are numbers (their seeds derive from them); ids written as digits (``"07"``) keep that
        spelling for file names."""
        written = data.get("episodes") if isinstance(data, dict) else None
        model = handler(data)
        if isinstance(written, list):
            model._written = {int(w): w for w in written if isinstance(w, str)}
        return model

    @field_validator("episodes", mode="before")
    @classmethod
    def _episode_ids(cls, v: Any) -> Any:
        for k, e in enumerate(v if isinstance(v, list) else []):
            if isinstance(e, bool) or not (isinstance(e, int) or (isinstance(e, str) and _EPISODE_ID.fullmatch(e))):
                raise ValueError(f"item {k}: {e!r} is not an episode id (a whole number ≥ 0, or its digits as a "
                                 "string such as \"07\")")
        return v

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
            if not _AGENT_NAME.fullmatch(a) or a in (".", "..") or a != a.strip():
                raise ValueError(f"agent {a!r}: a name is put into file names: no '/', '\\', control characters, "
                                 "leading or trailing spaces, not '.' or '..', at most 128 characters")
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
            try:
                check_pattern(self.trajectories)
            except ValueError as exc:
                raise ValueError(f"trajectories: {exc}") from None
        if self.domain_kind is DomainKind.ROBOT and self.robot is None:
            raise ValueError(f"source {self.source} needs robot: {{command: ...}}")
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

    def episode_name(self, episode: int) -> str:
        """The episode id as the manifest wrote it (``"07"``), for file names."""
        return self._written.get(episode, str(episode))

    def trajectory_file(self, agent: str, episode: int) -> str:
        """The file of (agent, episode), relative to the manifest's folder: the pattern filled in
        (``{episode}`` as written, ``{episode:03d}`` zero-padded)."""
        return self.pattern.format(agent=_Verbatim(agent), episode=_Episode(episode, self.episode_name(episode)))

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


class _Verbatim(str):
    """An agent name in a pattern: formatted as it is, whatever the spec (the spec was checked)."""

    def __format__(self, spec: str) -> str:
        return str(self)


class _Episode:
    """An episode in a pattern: ``{episode}`` as written, ``{episode:0Nd}`` zero-padded."""

    def __init__(self, number: int, written: str) -> None:
        self.number, self.written = number, written

    def __format__(self, spec: str) -> str:
        return format(self.number, spec) if spec else self.written


def load_manifest(root: str | Path) -> TargetManifest:
    """Read ``root/target.yaml`` (or a manifest file given directly)."""
    root = Path(root)
    path = root / MANIFEST_NAME if root.is_dir() else root
    if not path.exists():
        where = f"{root} has no {MANIFEST_NAME}" if root.is_dir() else f"{root}: no such file or directory"
        raise TargetError(f"{where} (write one as in docs/targets.md, or record one with `proxybench target record`)")
    try:  # bounded: size, nesting, UTF-8; a folder named target.yaml is an error, not a traceback
        data = load_yaml_file(path, max_bytes=MANIFEST_MAX_BYTES, max_depth=16)
    except UntrustedInputError as exc:
        raise TargetError(str(exc)) from None
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
