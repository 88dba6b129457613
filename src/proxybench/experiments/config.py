"""One experiment file for ``proxybench predictivity``, ``optimize`` and ``plan`` (``--config FILE``).

Every field is optional and has a command-line option; what neither gives takes the command's default
(shown by ``--help``). Unknown keys and bad values are errors naming the field. Relative working
directories in the file are taken from its folder; ``NAME=COMMAND`` strings run where proxybench runs::

    target: reality              # reality | DIR (a recorded target) | robot:COMMAND
    target_params: {}            # the reality model's θ, overridden (reality only)
    robot_nodes: 1               # processes of a robot node at once (robot:CMD only; 1 for a physical robot)
    robot_options:               # how to start and talk to the robot node (robot:CMD only; all optional)
      cwd: ../my-bridge          # working directory of the command
      transport: fifo            # pipe | fifo (AIDO's default)
      start_timeout: 120         # s: start + handshake, and each episode's setup
      step_timeout: 10           # s: each per-frame exchange
      reflection: false          # skip describe_protocol
    agents: [pid, vision, my-agent=python3 agent.py, models/bc.pt, my-agent.zip]
    # or, as in benchmark files, an agent node with how to start it (tasks/agent_entries.py):
    #   - name: my-lf                # its label
    #     command: cd solution && exec python3 solution.py
    #     cwd: ../submissions/my-lf  # relative to this file (default: this file's folder)
    #     transport: fifo            # pipe | fifo; also start_timeout, step_timeout, reflection
    map: loop_3x3                # default: the recorded target's map, else loop_3x3
    episodes: 10                 # per agent; a recorded target: how many of its episodes (default all)
    seconds: 60                  # episode length; a recorded target fixes it
    metrics: [driven_lanedir_consec, survival_time]
    image_size: [160, 120]
    proxy: {}                    # θ every proxy has, on top of the nominal calibration
    sweep:                       # predictivity: values per parameter
      trim: [-0.3, -0.2, -0.1, 0.0, 0.1, 0.2, 0.3]
      camera_pitch: [15, 19.15, 23]
    search:                      # optimize
      space: {trim: [-0.3, 0.3], camera_pitch: [12, 26]}
      objective: prpv            # prpv (θ* = argmin PRPV, the thesis) | ppv | mix | plv (argmax PLV, eq. 3.6.2)
      trials: 60
      sampler: tpe               # tpe | gp | random (plv: tpe | random)
      family: false              # plv only: search families p(θ) (a uniform range per parameter), not instances
    plv: {}                      # objective plv: PLV settings (PLVConfig fields, e.g. ladder, seeds, train: {...})
    n_boot: 300
    pod_seconds: 10
    seed: 0
    truth: {}                    # the target's known θ, to mark on plots only (never used by a sweep or search)
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator, model_validator

from proxybench.experiments.proxies import DEFAULT_SEARCH, DEFAULT_SWEEP, proxy_params
from proxybench.protocol.options import RobotNodeOptions
from proxybench.targets.manifest import TargetError, format_errors
from proxybench.tasks.agent_entries import AgentEntry, resolve_agent_cwd
from proxybench.untrusted import problems

__all__ = ["COMMAND_DEFAULTS", "ConfigError", "Experiment", "ExperimentConfig", "SearchConfig", "load_config",
           "resolve"]

FULL_AGENTS = ("random", "straight", "bang-bang", "pid", "pid-fast", "pid-sluggish", "pid-twitchy", "pure-pursuit",
               "pure-pursuit-fast", "vision", "vision-fast", "vision-slow", "vision-pitch15", "vision-pitch25",
               "vision-wide", "vision-twitchy")
QUICK_AGENTS = ("straight", "bang-bang", "pid", "pid-fast", "pid-twitchy", "pure-pursuit", "vision", "vision-fast",
                "vision-pitch25", "vision-twitchy", "vision-slow", "pid-sluggish")
OBJECTIVES = ("prpv", "ppv", "mix", "plv")

#: what a field left unset takes, per command and mode (a recorded target's map, length, agents and
#: episodes come first)
COMMAND_DEFAULTS: dict[tuple[str, bool], dict[str, Any]] = {
    ("predictivity", False): {"agents": FULL_AGENTS, "episodes": 10, "seconds": 60.0, "n_boot": 300,
                              "pod_seconds": 10.0, "trials": 60},
    ("predictivity", True): {"agents": QUICK_AGENTS, "episodes": 3, "seconds": 20.0, "n_boot": 100,
                             "pod_seconds": 4.0, "trials": 60},
    ("optimize", False): {"agents": QUICK_AGENTS, "episodes": 4, "seconds": 20.0, "n_boot": 300,
                          "pod_seconds": 0.0, "trials": 60},
    ("optimize", True): {"agents": QUICK_AGENTS[:8], "episodes": 2, "seconds": 12.0, "n_boot": 100,
                         "pod_seconds": 0.0, "trials": 20},
    # plan: ``episodes`` is the pilot's size per agent
    ("plan", False): {"agents": QUICK_AGENTS, "episodes": 3, "seconds": 20.0, "n_boot": 300,
                      "pod_seconds": 0.0, "trials": 0},
    ("plan", True): {"agents": QUICK_AGENTS[:6], "episodes": 3, "seconds": 8.0, "n_boot": 100,
                     "pod_seconds": 0.0, "trials": 0},
}


class ConfigError(TargetError):
    """An experiment that cannot run as given; the message names the field (and file) at fault."""


def _param_name(name: str) -> str:
    from proxybench.domain.params import DomainParams, unknown_parameter

    if name not in DomainParams.model_fields:
        raise ValueError(unknown_parameter(name))
    return name


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SearchConfig(_Strict):
    """What ``optimize`` searches and how."""

    space: dict[str, tuple[float, float]] = Field(default_factory=lambda: dict(DEFAULT_SEARCH))
    objective: Literal["prpv", "ppv", "mix", "plv"] = "prpv"
    trials: int | None = Field(None, ge=1, le=100_000)
    sampler: Literal["tpe", "gp", "random"] = "tpe"
    storage: str | None = None
    study_name: str = "proxybench-proxy"  # objective plv: "proxybench-plv" unless given
    family: bool = False  # objective plv: each trial proposes a family p(θ), a uniform range per parameter

    @model_validator(mode="after")
    def _family_is_plv(self) -> SearchConfig:
        if self.family and self.objective != "plv":
            raise ValueError(f"family: searching families p(θ) needs objective plv, not {self.objective!r}")
        return self

    @field_validator("space")
    @classmethod
    def _ranges(cls, v: dict[str, tuple[float, float]]) -> dict[str, tuple[float, float]]:
        if not v:
            raise ValueError("give at least one parameter to search")
        for name, (lo, hi) in v.items():
            _param_name(name)
            if not lo < hi:
                raise ValueError(f"{name} needs low < high, got [{lo}, {hi}]")
        return v


class ExperimentConfig(_Strict):
    """The experiment file (see the module docstring); ``None`` means the command's default."""

    target: str = "reality"
    target_params: dict[str, Any] = Field(default_factory=dict)
    robot_nodes: int = Field(1, ge=1, le=64)
    robot_options: RobotNodeOptions | None = None
    agents: list[str | AgentEntry] | None = Field(None, min_length=1)
    map: str | None = None
    episodes: int | None = Field(None, ge=1, le=10_000)
    seconds: float | None = Field(None, gt=0.0, le=3600.0)
    metrics: tuple[str, ...] = ("driven_lanedir_consec", "survival_time")
    image_size: tuple[int, int] = (160, 120)
    proxy: dict[str, Any] = Field(default_factory=dict)
    sweep: dict[str, tuple[float, ...]] = Field(default_factory=lambda: dict(DEFAULT_SWEEP))
    search: SearchConfig = Field(default_factory=SearchConfig)
    n_boot: int | None = Field(None, ge=10, le=100_000)
    pod_seconds: float | None = Field(None, ge=0.0, le=600.0)
    seed: int = Field(0, ge=0, le=100_000)
    truth: dict[str, float] = Field(default_factory=dict)
    plv: dict[str, Any] = Field(default_factory=dict)  # PLVConfig fields for objective plv, checked when used

    @model_validator(mode="before")
    @classmethod
    def _agent_entries(cls, data: Any, info: ValidationInfo) -> Any:
        """Agents given as mappings (the form of benchmark files) are checked here, each problem named by its
        entry (``agents.1.transprot: unknown key (did you mean 'transport'?)``), and a relative ``cwd`` is
        taken from the file's folder (the default for a node entry, as in benchmark files)."""
        agents = data.get("agents") if isinstance(data, dict) else None
        if not isinstance(agents, list):
            return data
        base = (info.context or {}).get("base_dir")
        out, problems = [], []
        for i, item in enumerate(agents):
            if not isinstance(item, dict):
                out.append(item)
                continue
            try:
                out.append(resolve_agent_cwd(AgentEntry.model_validate(item), base))
            except ValidationError as exc:
                problems += [f"agents.{i}{_entry_problem(e)}" for e in exc.errors()]
        if problems:
            raise ValueError("\n".join(problems))
        return {**data, "agents": out}

    @field_validator("metrics")
    @classmethod
    def _known_metrics(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        from proxybench.tasks.metrics import METRICS

        if not v:
            raise ValueError("give at least one metric")
        for name in v:
            if name not in METRICS:
                close = difflib.get_close_matches(name, list(METRICS), n=1)
                raise ValueError(f"unknown metric {name!r}" + (f" (did you mean {close[0]!r}?)" if close
                                                               else f"; known: {', '.join(METRICS)}"))
        if len(set(v)) != len(v):
            raise ValueError("a metric is listed twice")
        return v

    @field_validator("sweep")
    @classmethod
    def _sweep(cls, v: dict[str, tuple[float, ...]]) -> dict[str, tuple[float, ...]]:
        if not v:
            raise ValueError("give at least one parameter to sweep")
        for name, values in v.items():
            _param_name(name)
            if not values:
                raise ValueError(f"{name}: give at least one value")
            if len(set(values)) != len(values):
                raise ValueError(f"{name}: a value is listed twice")
        return v

    @field_validator("truth")
    @classmethod
    def _truth(cls, v: dict[str, float]) -> dict[str, float]:
        for name in v:
            _param_name(name)
        return v

    @field_validator("image_size")
    @classmethod
    def _image(cls, v: tuple[int, int]) -> tuple[int, int]:
        if not (8 <= v[0] <= 4096 and 8 <= v[1] <= 4096):
            raise ValueError(f"width and height must be within 8…4096 px, got {v[0]}×{v[1]}")
        return v

    @model_validator(mode="after")
    def _proxy_theta(self) -> ExperimentConfig:
        try:
            proxy_params(self.image_size, self.proxy)
        except ValidationError as exc:
            raise ValueError(problems(exc, "proxy")) from None
        return self


def _entry_problem(err: Any) -> str:
    """``.field: message`` of one error of an agent entry (an unknown key with its likely meaning)."""
    loc = "".join(f".{p}" for p in err["loc"])
    msg = err["msg"].removeprefix("Value error, ")
    if err["type"] == "extra_forbidden":
        close = difflib.get_close_matches(str(err["loc"][-1]), list(AgentEntry.model_fields), n=1)
        msg = "unknown key" + (f" (did you mean {close[0]!r}?)" if close
                               else f"; known: {', '.join(AgentEntry.model_fields)}")
    elif err["type"] == "missing":
        msg = "required, missing"
    return f"{loc}: {msg}"


def _robot_cwd_from(data: dict[str, Any], base: Path) -> dict[str, Any]:
    """The file's ``robot_options.cwd``, when relative, taken from the file's folder ``base``."""
    options = data.get("robot_options")
    cwd = options.get("cwd") if isinstance(options, dict) else None
    if not isinstance(cwd, str) or not cwd or Path(cwd).expanduser().is_absolute():
        return data
    return {**data, "robot_options": {**options, "cwd": str((base / cwd).resolve())}}


def load_config(path: str | Path | None, overrides: dict[str, Any] | None = None) -> ExperimentConfig:
    """The experiment file at ``path`` (or none), with ``overrides`` (the command line) on top."""
    data: dict[str, Any] = {}
    origin = "command line"
    if path is not None:
        path = Path(path)
        origin = str(path)
        try:
            loaded = yaml.safe_load(path.read_text())
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"{path}: not valid YAML ({exc})") from None
        if loaded is not None and not isinstance(loaded, dict):
            raise ConfigError(f"{path}: expected a mapping of fields, got {type(loaded).__name__}")
        data = _robot_cwd_from(loaded or {}, path.parent)
    over = dict(overrides or {})
    for section in ("search", "robot_options"):  # an option on the command line changes one field of the file's
        if section in over:
            data[section] = {**(data.get(section) or {}), **over.pop(section)}
    data.update(over)
    context = {"base_dir": Path(path).parent.resolve()} if path is not None and "agents" not in over else None
    try:
        return ExperimentConfig.model_validate(data, context=context)
    except ValidationError as exc:
        raise ConfigError(format_errors(exc, origin, ExperimentConfig)) from None


@dataclass
class Experiment:
    """An experiment with every choice made: what the runs and the report use."""

    command: str
    target_text: str
    agents: list[Any]  # runner AgentSpecs
    map: str
    episodes: int
    seconds: float
    metrics: tuple[str, ...]
    image_size: tuple[int, int]
    proxy: dict[str, Any]
    sweep: dict[str, tuple[float, ...]]
    search: SearchConfig
    trials: int
    n_boot: int
    pod_seconds: float
    seed: int
    truth: dict[str, float] = field(default_factory=dict)

    @property
    def agent_labels(self) -> list[str]:
        return [a.label for a in self.agents]

    def to_dict(self) -> dict[str, Any]:
        return {"command": self.command, "target": self.target_text, "agents": self.agent_labels,
                "agent_commands": {a.label: a.command for a in self.agents if a.command},
                "map": self.map, "episodes": self.episodes, "seconds": self.seconds, "metrics": list(self.metrics),
                "image_size": list(self.image_size), "proxy": self.proxy,
                "sweep": {k: list(v) for k, v in self.sweep.items()}, "search": self.search.model_dump(),
                "trials": self.trials, "n_boot": self.n_boot, "pod_seconds": self.pod_seconds, "seed": self.seed,
                "truth": self.truth}


def resolve(cfg: ExperimentConfig, command: Literal["predictivity", "optimize", "plan"], *, quick: bool = False,
            work_dir: str | Path = "out/agents", target=None):
    """(Experiment, Target): the config's choices, the target's fixed ones, then the command's defaults.

    A recorded target fixes the map and episode length (asking for others is an error naming the field)
    and offers its agents and episodes as defaults.
    """
    from proxybench.experiments.agent_args import AgentArgError, parse_agents
    from proxybench.targets.spec import open_target

    target = target or open_target(cfg.target, params=cfg.target_params, robot_nodes=cfg.robot_nodes,
                                   robot_options=cfg.robot_options,
                                   frame_rate=proxy_params(cfg.image_size, cfg.proxy).frame_rate)
    d = COMMAND_DEFAULTS[(command, quick)]
    if target.fixed_map is not None and cfg.map is not None and cfg.map != target.fixed_map:
        raise ConfigError(f"map: the target was recorded on {target.fixed_map!r}, the experiment asks for {cfg.map!r}")
    if target.fixed_seconds is not None and cfg.seconds is not None and abs(cfg.seconds - target.fixed_seconds) > 1e-9:
        raise ConfigError(f"seconds: the target's episodes last {target.fixed_seconds:g} s, the experiment asks for "
                          f"{cfg.seconds:g} s (proxies replay the target's episodes)")
    if target.n_episodes is not None and cfg.episodes is not None and cfg.episodes > target.n_episodes:
        raise ConfigError(f"episodes: {cfg.episodes} asked, the target has {target.n_episodes} per agent")
    names = cfg.agents or target.fixed_agents or list(d["agents"])
    try:
        agents = parse_agents(names, work_dir)
    except AgentArgError as exc:
        if cfg.agents is None and target.fixed_agents is not None:
            raise ConfigError(f"agents: the target's {exc}; name how to run each of its agents with --agent "
                              "(NAME=COMMAND for a node, a checkpoint or a package)") from None
        raise ConfigError(f"agents: {exc}") from None
    if target.fixed_agents is not None:
        unknown = [a.label for a in agents if a.label not in target.fixed_agents]
        if unknown:
            raise ConfigError(f"agents: {', '.join(map(repr, unknown))} not in the recorded target (it has "
                              f"{', '.join(target.fixed_agents)})")
    map_name = cfg.map or target.fixed_map or "loop_3x3"
    if target.fixed_map is not None:
        from proxybench.targets.recorded import resolve_map

        map_name = resolve_map(target.root, target.fixed_map)
    exp = Experiment(
        command=command, target_text=cfg.target, agents=agents, map=map_name,
        episodes=cfg.episodes or target.n_episodes or d["episodes"],
        seconds=cfg.seconds or target.fixed_seconds or d["seconds"], metrics=tuple(cfg.metrics),
        image_size=tuple(cfg.image_size), proxy=dict(cfg.proxy), sweep=dict(cfg.sweep), search=cfg.search,
        trials=cfg.search.trials or d["trials"], n_boot=cfg.n_boot or d["n_boot"],
        pod_seconds=d["pod_seconds"] if cfg.pod_seconds is None else cfg.pod_seconds, seed=cfg.seed,
        truth=dict(cfg.truth))
    return exp, target
