"""Benchmark files: what a user writes to define a task — map, episodes, domain, metrics and scoring.

A benchmark is a YAML file validated strictly (unknown keys are errors at every level, so a typo never
silently falls back to a default). Every problem is reported as ``<file>: <field path>: <message>``,
e.g. ``aido_lf.yaml: scoring.0.tolerance: Input should be greater than or equal to 0``.

Episodes are fixed by the file: either ``{count, seed}`` — episode i gets a seed derived from (seed, i)
and the simulator samples a valid start pose from it — or explicit ``{poses: [[x, y, θ], ...]}`` [m, m,
rad] in the map frame, each checked to lie on the road. ``routes`` (one list of turns per episode)
fixes the exits taken at intersections; with explicit poses each plan is checked against the map.
Scoring criteria name aggregated columns as :mod:`proxybench.tasks.aggregate` writes them
(``<metric>_<stat>``; a bare ``<metric>`` means its mean). ``npcs`` lists NPC Duckiebots and pedestrians
that every episode's world holds (schema in :mod:`proxybench.tasks.npcs`); ``agents`` the agents that
``proxybench evaluate`` runs when none are named: zoo agents or agent nodes with their start-up options
(:mod:`proxybench.tasks.agent_entries`).

>>> b = Benchmark.load("aido_lf")
>>> b.domain_params().frame_rate, [c.metric for c in b.criteria()][:2]
(15.0, ['driven_lanedir_consec_median', 'survival_time_median'])
>>> [s.index for s in b.episode_specs()] == list(range(5))
True
"""

from __future__ import annotations

import difflib
import math
import typing
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from proxybench.agents.zoo import ZOO
from proxybench.domain.maps import Map, MapError, load_map
from proxybench.domain.npcs import Traffic
from proxybench.domain.params import DomainParams
from proxybench.domain.reality import reality_params
from proxybench.tasks.agent_entries import AgentEntry, agent_entry_issues, as_entry, resolve_agent_cwd
from proxybench.tasks.aggregate import STATS
from proxybench.tasks.metrics import METRICS
from proxybench.tasks.npcs import NpcEntry, npc_issues, traffic_of
from proxybench.tasks.scoring import Criterion
from proxybench.untrusted import UntrustedInputError, inside, load_yaml_file

__all__ = [
    "NAMED_DOMAINS",
    "Benchmark",
    "BenchmarkError",
    "DomainChoice",
    "EpisodeSpec",
    "Episodes",
    "ScoringEntry",
    "builtin_benchmark_names",
    "derive_seed",
    "parse_scoring_metric",
]

#: domains a benchmark may name (``domain: {named: ...}``); other modules may add entries
NAMED_DOMAINS: dict[str, Callable[[], DomainParams]] = {"default": DomainParams, "reality": reality_params}

#: statistic meant by a bare metric name in ``scoring``
DEFAULT_STAT = "mean"
BENCHMARK_MAX_BYTES = 1 << 20
_RATE_FIELDS = ("physics_rate", "frame_rate")


class BenchmarkError(ValueError):
    """A benchmark file is invalid; each line of the message names the file and the field path."""


@dataclass(frozen=True)
class EpisodeSpec:
    """Episode ``index`` of a benchmark: its ``seed`` and start ``pose`` (x, y, θ) [m, m, rad], or None
    to let the simulator sample a valid start from the seed; ``route``: turns at the intersections met,
    or None to draw them from the seed (``proxybench.domain.routes``)."""

    index: int
    seed: int
    pose: tuple[float, float, float] | None = None
    route: tuple[str, ...] | None = None


def parse_scoring_metric(name: str) -> tuple[str, str]:
    """(base metric, stat) of a scoring name ``<metric>_<stat>`` or ``<metric>`` (stat = ``DEFAULT_STAT``).

    Longest metric names are tried first, so a metric whose name contains ``_`` parses unambiguously.
    """
    for base in sorted(METRICS, key=len, reverse=True):
        if name == base:
            return base, DEFAULT_STAT
        if name.startswith(base + "_"):
            stat = name[len(base) + 1:]
            if stat not in STATS:
                raise ValueError(f"unknown statistic {stat!r} in {name!r} (use {base}_<stat>, "
                                 f"stat one of {', '.join(STATS)})")
            return base, stat
    raise ValueError(f"unknown metric in {name!r} (metrics: {', '.join(METRICS)})")


def _known_metric(name: str) -> str:
    if name not in METRICS:
        raise ValueError(f"unknown metric {name!r} (one of {', '.join(METRICS)})")
    return name


MetricName = Annotated[str, AfterValidator(_known_metric)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
Pose = tuple[FiniteFloat, FiniteFloat, FiniteFloat]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Episodes(_Strict):
    """Either ``count`` episodes from ``seed``, or one episode per explicit pose (optionally with ``seeds``)."""

    count: int | None = Field(None, gt=0, description="number of episodes with sampled starts")
    seed: int = Field(0, ge=0, description="seed from which each episode's seed is derived")
    poses: list[Pose] | None = Field(None, min_length=1, description="start poses [x m, y m, θ rad]")
    seeds: list[Annotated[int, Field(ge=0)]] | None = Field(None, description="one seed per pose")
    routes: list[list[Literal["left", "straight", "right"]]] | None = Field(
        None, description="one list of turns per episode, taken at the intersections in the order met; "
                          "after its end (or without routes) turns are drawn from the episode seed")

    @property
    def n(self) -> int:
        """Number of episodes."""
        return self.count if self.count is not None else len(self.poses or ())

    @model_validator(mode="after")
    def _one_kind(self) -> Episodes:
        if (self.count is None) == (self.poses is None):
            raise ValueError("give either count (sampled starts) or poses (explicit starts), not both or neither")
        if self.seeds is not None:
            if self.poses is None:
                raise ValueError("seeds go with poses; with count, episode seeds are derived from seed")
            if len(self.seeds) != len(self.poses):
                raise ValueError(f"seeds has {len(self.seeds)} entries for {len(self.poses)} poses")
        return self


class DomainChoice(_Strict):
    """The domain θ: explicit ``params`` (DomainParams fields) or a ``named`` entry of ``NAMED_DOMAINS``."""

    params: DomainParams | None = None
    named: str | None = None

    @field_validator("params")
    @classmethod
    def _rates_elsewhere(cls, p: DomainParams | None) -> DomainParams | None:
        clash = [f for f in _RATE_FIELDS if p is not None and f in p.model_fields_set]
        if clash:
            raise ValueError(f"set {' and '.join(clash)} at the top level of the benchmark, not in domain.params")
        return p

    @field_validator("named")
    @classmethod
    def _known_name(cls, name: str | None) -> str | None:
        if name is not None and name not in NAMED_DOMAINS:
            raise ValueError(f"unknown domain {name!r} (one of {', '.join(NAMED_DOMAINS)})")
        return name

    @model_validator(mode="after")
    def _one_kind(self) -> DomainChoice:
        if (self.params is None) == (self.named is None):
            raise ValueError("give either params or named, not both or neither")
        return self

    def base(self) -> DomainParams:
        return self.params if self.params is not None else NAMED_DOMAINS[self.named]()


class ScoringEntry(_Strict):
    """One criterion: an aggregated metric, its direction (defaults to the metric's) and tolerance."""

    metric: str
    higher_is_better: bool | None = None
    tolerance: float = Field(0.0, ge=0.0, allow_inf_nan=False, description="differences up to this tie")

    @field_validator("metric")
    @classmethod
    def _parse(cls, name: str) -> str:
        parse_scoring_metric(name)
        return name

    @property
    def base(self) -> str:
        return parse_scoring_metric(self.metric)[0]

    @property
    def column(self) -> str:
        """The aggregated column name, ``<metric>_<stat>``."""
        base, stat = parse_scoring_metric(self.metric)
        return f"{base}_{stat}"

    def criterion(self) -> Criterion:
        hib = METRICS[self.base].higher_is_better if self.higher_is_better is None else self.higher_is_better
        return Criterion(self.column, hib, self.tolerance)


def _resolve_map(name: str, base_dir: Path | None) -> str:
    """A built-in name stays as is; a map file is named relative to the benchmark file's folder and lies inside
    it (no ``..``, no absolute path, no link: :func:`proxybench.untrusted.inside`)."""
    if "/" not in name and "\\" not in name and not name.endswith((".yaml", ".yml")):
        return name
    if base_dir is None:
        raise ValueError(f"{name!r}: this benchmark has no file, so it names built-in maps only (a map file is "
                         "named relative to the benchmark file)")
    try:
        return str(inside(base_dir, name, field="map"))
    except UntrustedInputError as exc:
        raise ValueError(str(exc).removeprefix("map: ")) from None


class Benchmark(_Strict):
    """A benchmark definition. Load with :meth:`load`; every field is validated on construction."""

    name: str = Field(min_length=1)
    description: str = ""
    map: str = Field(description="built-in map name or path to a map YAML (relative to the benchmark file)")
    episodes: Episodes
    duration: float = Field(gt=0.0, allow_inf_nan=False, description="episode length [s]")
    physics_rate: float = Field(60.0, gt=0.0, allow_inf_nan=False, description="physics steps per second [Hz]")
    frame_rate: float = Field(15.0, gt=0.0, allow_inf_nan=False, description="camera frames per second [Hz]")
    domain: DomainChoice = DomainChoice(named="default")
    metrics: list[MetricName] = Field(min_length=1)
    scoring: list[ScoringEntry] = Field(min_length=1)
    npcs: list[NpcEntry] = Field(default_factory=list, description="NPC duckiebots and pedestrians of every episode")
    camera_only: bool = Field(False, description="refuse privileged agents (those reading the true lane pose)")
    wall_time_factor: float = Field(
        20.0, ge=1.0, le=1000.0, allow_inf_nan=False,
        description="an evaluator gives a job at most this multiple of its simulated time (every episode of every "
                    "split) in wall-clock time, plus a start-up allowance; beyond, the job ends failed")
    invalid_retries: int = Field(
        2, ge=0, le=10, strict=True,
        description="an Autolab (feature autolab) runs an episode its watchtowers' measurement made invalid (the DTA's "
                    "validation: the robot lost, the light changed, the recording ended early) again on the robot, "
                    "reset, up to this many times within the job; only then is the job the lab's host-error")
    agents: list[AgentEntry] = Field(default_factory=list, description="agents `evaluate` runs when none are named: "
                                     "zoo names, or {name, command, cwd, transport, ...} of agent nodes")

    @field_validator("agents", mode="before")
    @classmethod
    def _bare_names(cls, entries: Any) -> Any:
        return [as_entry(e) for e in entries] if isinstance(entries, list) else entries

    @field_validator("agents")
    @classmethod
    def _agent_dirs(cls, entries: list[AgentEntry], info: ValidationInfo) -> list[AgentEntry]:
        base = (info.context or {}).get("base_dir")
        out = []
        for i, e in enumerate(entries):
            try:
                out.append(resolve_agent_cwd(e, base))
            except ValueError as exc:
                raise ValueError(f"entry {i}: {exc}") from None
        return out

    @field_validator("map")
    @classmethod
    def _loadable(cls, name: str, info: ValidationInfo) -> str:
        resolved = _resolve_map(name, (info.context or {}).get("base_dir"))
        try:
            load_map(resolved)
        except MapError as exc:
            raise ValueError(str(exc)) from None
        return resolved

    @model_validator(mode="after")
    def _cross_checks(self) -> Benchmark:
        issues = [*self._metric_issues(), *self._rate_issues(), *self._pose_issues(), *self._route_issues(),
                  *npc_issues(self.npcs, self.load_map()), *agent_entry_issues(self.agents, ZOO)]
        if issues:
            raise ValueError("\n".join(f"{path}: {msg}" for path, msg in issues))
        return self

    def _metric_issues(self) -> list[tuple[str, str]]:
        issues = [(f"metrics.{i}", f"{m!r} is listed twice") for i, m in enumerate(self.metrics)
                  if m in self.metrics[:i]]
        for i, entry in enumerate(self.scoring):
            base = entry.base
            if base not in self.metrics:
                issues.append((f"scoring.{i}.metric", f"{entry.metric!r} scores {base!r}, which is not in metrics "
                                                      f"({', '.join(self.metrics)})"))
            elif entry.higher_is_better is not None and entry.higher_is_better != METRICS[base].higher_is_better:
                hib = METRICS[base].higher_is_better
                issues.append((f"scoring.{i}.higher_is_better", f"{base} is {METRICS[base].direction} "
                                                                f"(higher_is_better: {str(hib).lower()})"))
        return issues

    def _rate_issues(self) -> list[tuple[str, str]]:
        try:
            p = self.domain_params()
        except ValidationError as exc:
            return [("frame_rate", "; ".join(e["msg"].removeprefix("Value error, ") for e in exc.errors()))]
        if self.duration * p.frame_rate < 1.0:
            return [("duration", f"{self.duration:g} s is shorter than one frame at {p.frame_rate:g} Hz")]
        return []

    def _pose_issues(self) -> list[tuple[str, str]]:
        if not self.episodes.poses:
            return []
        from proxybench.domain.lane_pose import lane_poses
        from proxybench.domain.lanes import LaneNetwork

        m = self.load_map()
        rows = lane_poses(LaneNetwork(m), np.array(self.episodes.poses, dtype=float))
        issues = []
        for k, ((x, y, th), row) in enumerate(zip(self.episodes.poses, rows, strict=True)):
            if row[0] < 0.5 or row[9] < 0.5:  # LP.VALID (on a drivable tile), LP.ON_ROAD (inside its road)
                tile = m.tile_at(x, y)
                where = f"on a {tile.kind} tile" if tile is not None else "on no tile"
                issues.append((f"episodes.poses.{k}", f"({x:g}, {y:g}, {th:g}) is not on the road of map "
                                                      f"{m.name!r} ({where})"))
        return issues

    def _route_issues(self) -> list[tuple[str, str]]:
        routes = self.episodes.routes
        if routes is None:
            return []
        if len(routes) != self.episodes.n:
            return [("episodes.routes", f"{len(routes)} routes for {self.episodes.n} episodes (give one per episode)")]
        if not self.episodes.poses or self._pose_issues():
            return []  # sampled starts: a turn the map does not allow is replaced by a draw, and logged
        from proxybench.domain.lanes import LaneNetwork
        from proxybench.domain.routes import RouteGraph, route_issues

        graph = RouteGraph(LaneNetwork(self.load_map()))
        return [(f"episodes.routes.{e}.{k}", msg) for e, (pose, turns) in enumerate(zip(self.episodes.poses, routes,
                                                                                        strict=True))
                for k, msg in route_issues(graph, pose, turns)]

    # -- loading -----------------------------------------------------------------------------------

    @classmethod
    def load(cls, source: str | Path) -> Benchmark:
        """Load a benchmark YAML file, or a built-in benchmark by name (see :func:`builtin_benchmark_names`).

        Raises:
            BenchmarkError: naming the file and the field path of every problem found.
        """
        path, origin = _locate(source)
        try:  # bounded: size, nesting, UTF-8 (a folder or a binary file is an error, not a traceback)
            data = load_yaml_file(path, max_bytes=BENCHMARK_MAX_BYTES, max_depth=32)
        except UntrustedInputError as exc:
            raise BenchmarkError(str(exc).replace(str(path), origin, 1)) from None
        return cls.from_dict(data, origin=origin, base_dir=path.parent)

    @classmethod
    def from_dict(cls, data: Any, *, origin: str = "<benchmark>", base_dir: Path | None = None) -> Benchmark:
        """Validate a parsed benchmark; ``origin`` names it in errors, ``base_dir`` anchors relative map paths."""
        if not isinstance(data, dict):
            raise BenchmarkError(f"{origin}: expected a mapping of benchmark fields, got {type(data).__name__}")
        try:
            return cls.model_validate(data, context={"base_dir": base_dir})
        except ValidationError as exc:
            raise BenchmarkError(_format_errors(exc, origin)) from None

    # -- derived -----------------------------------------------------------------------------------

    def load_map(self) -> Map:
        return load_map(self.map)

    def traffic(self) -> Traffic | None:
        """The NPCs of every episode as the domain's ``Traffic`` (None if the benchmark has none)."""
        return traffic_of(self.npcs)

    def domain_params(self) -> DomainParams:
        """θ of the benchmark's domain with the benchmark's physics and frame rates."""
        return self.domain.base().replace(physics_rate=self.physics_rate, frame_rate=self.frame_rate)

    def episode_specs(self) -> list[EpisodeSpec]:
        """The episodes, fixed by the file: the same list on every call, machine and run."""
        ep = self.episodes
        routes = [tuple(r) for r in ep.routes] if ep.routes is not None else [None] * ep.n
        if ep.poses is None:
            return [EpisodeSpec(i, derive_seed(ep.seed, i), route=routes[i]) for i in range(ep.count or 0)]
        seeds = ep.seeds if ep.seeds is not None else [derive_seed(ep.seed, i) for i in range(len(ep.poses))]
        pairs = zip(ep.poses, seeds, routes, strict=True)
        return [EpisodeSpec(i, s, (float(p[0]), float(p[1]), float(p[2])), r) for i, (p, s, r) in enumerate(pairs)]

    @property
    def simulated_seconds(self) -> float:
        """Simulated time of one split: every episode's duration."""
        return self.episodes.n * self.duration

    def criteria(self) -> list[Criterion]:
        """The scoring criteria, in order, on aggregated column names (``<metric>_<stat>``)."""
        return [entry.criterion() for entry in self.scoring]

    @property
    def frames(self) -> int:
        """Camera frames (agent decisions) per episode."""
        return math.ceil(self.duration * self.frame_rate - 1e-9)

    def check_agent(self, agent: Any) -> None:
        """Refuse a privileged agent (``agent.privileged``, or a bool) on a camera-only benchmark."""
        privileged = agent if isinstance(agent, bool) else bool(getattr(agent, "privileged", False))
        if self.camera_only and privileged:
            who = getattr(agent, "name", None) or type(agent).__name__
            raise BenchmarkError(f"benchmark {self.name!r} is camera-only: privileged agent {who!r} "
                                 "(it reads the true lane pose) is not admitted")


def derive_seed(seed: int, index: int) -> int:
    """Seed of episode ``index`` from the benchmark seed: well mixed, stable across numpy versions."""
    return int(np.random.SeedSequence(seed, spawn_key=(index,)).generate_state(1)[0])


def _benchmarks_dir() -> Any:
    return resources.files("proxybench") / "benchmarks"


def builtin_benchmark_names() -> list[str]:
    """Names of the benchmarks shipped with proxybench (``proxybench/benchmarks/*.yaml``)."""
    return sorted(p.name[:-5] for p in _benchmarks_dir().iterdir() if p.name.endswith(".yaml"))


def _locate(source: str | Path) -> tuple[Path, str]:
    """(file, name to use in messages) of a path or built-in benchmark name."""
    path = Path(source)
    if path.exists():  # a folder too: the loader says what is wrong with it
        return path, str(source)
    name = str(source)
    if "/" not in name and "\\" not in name:
        candidate = _benchmarks_dir() / f"{name.removesuffix('.yaml')}.yaml"
        if candidate.is_file():
            return Path(str(candidate)), candidate.name
    raise BenchmarkError(f"{source}: no such benchmark file or built-in benchmark "
                         f"(built-in: {', '.join(builtin_benchmark_names())})")


def _format_errors(exc: ValidationError, origin: str) -> str:
    """One ``<origin>: <field path>: <message>`` line per problem."""
    lines = []
    for err in exc.errors():
        msg = err["msg"].removeprefix("Value error, ")
        loc = ".".join(str(p) for p in err["loc"])
        if err["type"] == "extra_forbidden":
            msg = "unknown key" + _key_hint(str(err["loc"][-1]), _allowed_keys(err["loc"][:-1]))
        if loc:
            lines.append(f"{origin}: {loc}: {msg}")
        else:  # cross-field checks put their paths in the message, one per line
            lines.extend(f"{origin}: {line}" for line in msg.splitlines())
    return "\n".join(lines)


def _key_hint(key: str, allowed: list[str]) -> str:
    """' (did you mean ...?)' for a likely typo, else the allowed keys when they are few enough to read."""
    close = difflib.get_close_matches(key, allowed, n=3, cutoff=0.6)
    if close:
        return f" (did you mean {' or '.join(close)}?)"
    return f" (allowed: {', '.join(allowed)})" if 0 < len(allowed) <= 15 else ""


def _allowed_keys(loc: tuple[Any, ...]) -> list[str]:
    """The field names of the model at ``loc`` inside a benchmark, for 'unknown key' messages."""
    model: Any = Benchmark
    annotation: Any = None
    for part in loc:
        if isinstance(part, int):
            continue
        tagged = _tagged_model(annotation, part)  # the tag of a discriminated union (npcs.0.duckiebot.…)
        if tagged is not None:
            model = tagged
            continue
        field = model.model_fields.get(part) if isinstance(model, type) and issubclass(model, BaseModel) else None
        if field is None:
            return []
        annotation = field.annotation
        model = _model_in(annotation)
    return list(model.model_fields) if isinstance(model, type) and issubclass(model, BaseModel) else []


def _tagged_model(annotation: Any, tag: Any) -> Any:
    """The model of a union in ``annotation`` whose ``kind`` is the literal ``tag``, if any."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        kind = annotation.model_fields.get("kind")
        return annotation if kind is not None and typing.get_args(kind.annotation) == (tag,) else None
    for arg in typing.get_args(annotation):
        found = _tagged_model(arg, tag)
        if found is not None:
            return found
    return None


def _model_in(annotation: Any) -> Any:
    """The pydantic model inside an annotation such as ``Episodes``, ``X | None`` or ``list[X]``."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        found = _model_in(arg)
        if found is not None:
            return found
    return None
