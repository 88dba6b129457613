"""One experiment file for ``proxybench predictivity``, ``optimize`` and ``plan`` (``--config FILE``).

:class:`ExperimentConfig` is that file; every field is optional and is also a command-line option, generated
from the field (its docstring is its ``--help``), with sections flattened: ``search`` (optimize: ``--param``,
``--trials``, …), ``plan`` (``--width``, ``--budget``, …), ``robot_options`` (``--robot-cwd``, …). What neither
the command line nor the file gives takes the command's default (:data:`COMMAND_DEFAULTS`, worded for
``--help`` by :func:`default_help`); a recorded target's map, length, agents and episodes come before it.
Unknown keys and bad values are errors naming the field and file. Relative working directories in the file
are taken from its folder; ``NAME=COMMAND`` strings run where proxybench runs. docs/targets.md shows the
file with every field (tests/test_config_options.py holds it to this model).
"""

from __future__ import annotations

import difflib
import importlib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, ClassVar, Literal

from pydantic import Field, ValidationError, ValidationInfo, field_validator, model_validator

from proxybench.domain.params import check_image_size
from proxybench.dtps.robot_options import DtpsRobotOptions
from proxybench.experiments.proxies import DEFAULT_SEARCH, DEFAULT_SWEEP, proxy_params
from proxybench.experiments.study import Cli, ConfigError, Study, StudyConfig
from proxybench.protocol.options import RobotNodeOptions
from proxybench.targets.base import Episodes, episode_count, parse_episodes
from proxybench.tasks.agent_entries import AgentEntry, resolve_agent_cwd
from proxybench.untrusted import problems

__all__ = ["COMMAND_DEFAULTS", "ConfigError", "Experiment", "ExperimentConfig", "ExperimentStudy", "PlanConfig",
           "SearchConfig", "default_help", "load_config", "param_name", "param_values", "resolve",
           "resolve_run"]

FULL_AGENTS = ("random", "straight", "bang-bang", "pid", "pid-fast", "pid-sluggish", "pid-twitchy", "pure-pursuit",
               "pure-pursuit-fast", "vision", "vision-fast", "vision-slow", "vision-pitch15", "vision-pitch25",
               "vision-wide", "vision-twitchy")
QUICK_AGENTS = ("straight", "bang-bang", "pid", "pid-fast", "pid-twitchy", "pure-pursuit", "vision", "vision-fast",
                "vision-pitch25", "vision-twitchy", "vision-slow", "pid-sluggish")
OBJECTIVES = ("prpv", "ppv", "mix", "plv")
#: the commands whose defaults :data:`COMMAND_DEFAULTS` holds
Command = Literal["predictivity", "optimize", "plan", "rank"]

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
    # plan: ``episodes`` is the pilot's size per agent; ``reps`` and ``budget`` are plan's own
    ("plan", False): {"agents": QUICK_AGENTS, "episodes": 3, "seconds": 20.0, "n_boot": 300,
                      "pod_seconds": 0.0, "trials": 0, "reps": 400, "budget": 20},
    ("plan", True): {"agents": QUICK_AGENTS[:6], "episodes": 3, "seconds": 8.0, "n_boot": 100,
                     "pod_seconds": 0.0, "trials": 0, "reps": 150, "budget": 4},
    # rank: ``episodes`` are the target's (the sequential mode's pilot), ``proxy_episodes`` the proxy's own per agent
    ("rank", False): {"agents": QUICK_AGENTS[:8], "episodes": 10, "seconds": 20.0, "n_boot": 0, "pod_seconds": 0.0,
                      "trials": 0, "proxy_episodes": 100, "budget": 80},
    ("rank", True): {"agents": QUICK_AGENTS[:4], "episodes": 4, "seconds": 6.0, "n_boot": 0, "pod_seconds": 0.0,
                     "trials": 0, "proxy_episodes": 16, "budget": 8},
}


def default_help(command: str) -> dict[str, str]:
    """How ``--help`` words the defaults that are settled only when the command runs (by ``--quick`` and by
    the target: a recorded target fixes the map and episode length and offers its agents and episodes)."""
    full, quick = COMMAND_DEFAULTS[(command, False)], COMMAND_DEFAULTS[(command, True)]

    def both(key: str, fmt=lambda v: f"{v:g}") -> str:
        return f"{fmt(full[key])}; --quick {fmt(quick[key])}"

    def agents(v: tuple[str, ...]) -> str:
        return f"{len(v)} zoo agents"

    recorded = "a recorded target's (it fixes it), else "
    out = {"agents": f"the target's, else {both('agents', agents)}",
           "map": recorded + "loop_3x3", "episodes": f"a recorded target's (all of them), else {both('episodes')}",
           "seconds": recorded + both("seconds"), "n_boot": both("n_boot"), "pod_seconds": both("pod_seconds"),
           "search.trials": f"{both('trials')}; objective plv: 12, --quick 4",
           "search.study_name": "proxybench-proxy; objective plv: proxybench-plv"}
    if command == "plan":
        out |= {"plan.reps": both("reps"), "plan.budget": both("budget"), "sweep": "none (no candidates)",
                "episodes": f"a recorded target's (all of them), else {both('episodes')}; at least 2"}
    return out


def param_name(name: str) -> str:
    """``name`` if it is a domain parameter, else a ValueError with the likely meant one."""
    from proxybench.domain.params import DomainParams, unknown_parameter

    if name not in DomainParams.model_fields:
        raise ValueError(unknown_parameter(name))
    return name


def param_values(v: dict[str, tuple[float, ...]] | None, least: int, label: str = "") -> None:
    """A ValueError unless every name of ``v`` is a domain parameter with ``least`` or more values, none twice."""
    for name, values in (v or {}).items():
        param_name(name)
        if len(values) < least or len(set(values)) != len(values):
            raise ValueError(f"{label}{name}: give {least} or more values, none twice, got {list(values)}")


class SearchConfig(StudyConfig):
    """What ``optimize`` searches and how."""

    space: Annotated[dict[str, tuple[float, float]], Cli("--param", metavar="NAME=LOW:HIGH", sep=":")] = Field(
        default_factory=lambda: dict(DEFAULT_SEARCH))
    """a parameter to search and its range"""
    objective: Literal["prpv", "ppv", "mix", "plv"] = "prpv"
    """prpv (the thesis' θ* = argmin PRPV) | ppv | mix (PRPV/K(K−1) + PPV/m) | plv (argmax PLV, eq. 3.6.2: trains a
    behaviour-cloning agent per trial; needs the learning extra)"""
    trials: int | None = Field(None, ge=1, le=100_000)
    """trials of the search"""
    sampler: Literal["tpe", "gp", "random"] = "tpe"
    """Optuna's sampler (objective plv: tpe or random)"""
    storage: str | None = None
    """SQLite file or SQLAlchemy URL of the study (PostgreSQL to share it); resumes a stored study"""
    study_name: str = "proxybench-proxy"
    """name of the study in the storage (objective plv: proxybench-plv unless given)"""
    family: bool = False
    """objective plv: search families p(θ) (a uniform range per parameter) instead of instances θ"""

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
            param_name(name)
            if not lo < hi:
                raise ValueError(f"{name} needs low < high, got [{lo}, {hi}]")
        return v


class PlanConfig(StudyConfig):
    """What ``plan`` aims for, and the budget of ``plan --sequential``."""

    width: float | None = Field(None, ge=0.0, allow_inf_nan=False)
    """PRPV order-range width to reach"""
    p_correct: float | None = Field(None, gt=0.0, lt=1.0)
    """probability of picking the pilot's best candidate θ to reach (with candidates: --sweep)"""
    confidence: float = Field(0.8, gt=0.0, lt=1.0)
    """probability of reaching the width"""
    power: float = Field(0.8, gt=0.0, lt=1.0)
    """probability of settling a pair (per-pair needs)"""
    tolerance: Annotated[dict[str, float], Cli("--tolerance", default="AIDO's semiorder tolerances scaled to the "
                                               "episode length")] = Field(default_factory=dict)
    """ε of a metric: pairs within it are ties (NAME=0: strict order)"""
    range_level: Annotated[float, Cli("--range")] = Field(0.8, gt=0.0, lt=1.0)
    """central share of the pilot's posterior that the episode ranges span"""
    pilot_as_truth: bool = False
    """take the pilot's means and spreads as the truth (the former planner; ranges then collapse to points)"""
    max_episodes: int = Field(320, ge=2, le=100_000)
    """largest n per agent considered"""
    reps: int | None = Field(None, ge=20, le=100_000)
    """simulated experiments per n"""
    sequential: bool = False
    """then run more target episodes where they settle most (live targets)"""
    budget: int | None = Field(None, ge=1, le=100_000)
    """target episodes the sequential allocation may run"""
    batch: int = Field(2, ge=1, le=1000)
    """episodes per round of the sequential allocation (e.g. the workers)"""


class ExperimentConfig(StudyConfig):
    """The experiment file (see the module docstring); ``None`` means the command's default."""

    target: str = "reality"
    """reality (the simulated reality model) | DIR (a recorded target) | robot:CMD (a robot node) |
    dtps:HOST[:PORT]/PATH (a DTPS robot)"""
    target_params: Annotated[dict[str, Any], Cli("--target-param")] = Field(default_factory=dict)
    """the reality model's θ, overridden (reality only)"""
    robot_nodes: int = Field(1, ge=1, le=64)
    """processes of a robot node at once (robot:CMD only; 1 for a physical robot)"""
    robot_options: Annotated[RobotNodeOptions | None, Cli(prefix="robot-")] = None
    """how to start and talk to the robot node (robot:CMD only)"""
    dtps_options: Annotated[DtpsRobotOptions | None, Cli("--dtps-option", metavar="KEY=VALUE", prefix="dtps-")] = None
    """how to drive a DTPS robot (dtps:HOST[:PORT]/PATH only; docs/dtps.md)"""
    agents: Annotated[list[str | AgentEntry] | None, Cli("--agent", metavar="AGENT")] = Field(None, min_length=1)
    """zoo name, NAME=COMMAND (node), NAME=sdk:COMMAND (duckietown-sdk program), checkpoint X.pt, or agent package
    .zip/.tar.gz"""
    map: str | None = None
    """map name or file"""
    episodes: Annotated[int | tuple[int, ...] | None, Cli(metavar="N|IDS")] = None
    """episodes per agent: a count N (ids 0 … N−1) or ids such as 0-4,7 (a fit / held-out split of one target; a
    single id is 7-7)"""
    seconds: float | None = Field(None, gt=0.0, le=3600.0)
    """episode length [s]"""
    metrics: Annotated[tuple[str, ...], Cli("--metric")] = ("driven_lanedir_consec", "survival_time")
    """task metric"""
    image_size: Annotated[tuple[int, int], Cli(metavar="WIDTHxHEIGHT", sep="x")] = (160, 120)
    """camera image [px]"""
    proxy: Annotated[dict[str, Any], Cli("--proxy-param")] = Field(default_factory=dict)
    """θ every proxy has, on top of the nominal calibration"""
    sweep: dict[str, tuple[float, ...]] = Field(default_factory=lambda: dict(DEFAULT_SWEEP))
    """predictivity: values of a parameter to sweep (plan: candidate θ to pick among)"""
    search: Annotated[SearchConfig, Cli(prefix="")] = Field(default_factory=SearchConfig)
    """optimize: what to search and how"""
    plan: Annotated[PlanConfig, Cli(prefix="")] = Field(default_factory=PlanConfig)
    """plan: what to aim for, and the sequential budget"""
    n_boot: int | None = Field(None, ge=10, le=100_000)
    """bootstrap resamples (intervals, noise floor)"""
    pod_seconds: float | None = Field(None, ge=0.0, le=600.0)
    """POD rollout [s], 0: none"""
    seed: int = Field(0, ge=0, le=100_000)
    """experiment seed (episodes, resampling, sampler)"""
    truth: dict[str, Annotated[float, Field(allow_inf_nan=False)]] = Field(default_factory=dict)
    """the target's known θ, marked on plots and printed beside results only (never used by a sweep or search)"""
    plv: dict[str, Any] = Field(default_factory=dict)
    """objective plv: PLV settings (PLVConfig fields, e.g. ladder, seeds, train: {...}), checked when used"""

    @classmethod
    def prepare(cls, data: dict[str, Any], folder: Path | None) -> dict[str, Any]:
        """The robot's working directory and the DTPS robot's files: a file's inside its ``folder``, the command
        line's from where the command runs."""
        return robot_cwd_from(data, folder, DTPS_FILES)

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
            except ValueError as exc:  # a cwd that leaves the file's folder
                problems.append(f"agents.{i}.{exc}")
        if problems:
            raise ValueError("\n".join(problems))
        return {**data, "agents": out}

    @field_validator("episodes", mode="before")
    @classmethod
    def _episodes(cls, v: Any) -> Any:
        if v is None:
            return v
        value = parse_episodes(v)
        if isinstance(value, int) and not 1 <= value <= 10_000:
            raise ValueError(f"a count within 1…10000, got {value}")
        return value

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
        param_values(v, 1)
        return v

    @field_validator("truth")
    @classmethod
    def _truth(cls, v: dict[str, float]) -> dict[str, float]:
        for name in v:
            param_name(name)
        return v

    _image = field_validator("image_size")(check_image_size)

    @model_validator(mode="after")
    def _proxy_theta(self) -> ExperimentConfig:
        try:
            proxy_params(self.image_size, self.proxy)
        except ValidationError as exc:
            raise ValueError(problems(exc, "proxy")) from None
        return self


#: the files a DTPS robot's options name (a section's keys that are paths)
DTPS_FILES = ("start_poses", "reset_input")


def robot_cwd_from(data: dict[str, Any], folder: Path | None, dtps_files: tuple[str, ...] = ()) -> dict[str, Any]:
    """``data`` with ``robot_options.cwd`` (and the DTPS robot's ``dtps_files``) resolved: a file's paths inside its
    ``folder`` (:func:`proxybench.untrusted.inside`), the command line's (``folder`` None) from where the command
    runs; a working directory must be a folder."""
    from proxybench.untrusted import inside

    for section, keys in (("robot_options", ("cwd",)), ("dtps_options", dtps_files)):
        options = data.get(section)
        for key in keys:
            value = options.get(key) if isinstance(options, dict) else None
            if not isinstance(value, str) or not value:
                continue
            path = inside(folder, value, field=f"{section}.{key}") if folder is not None else \
                Path(value).expanduser().resolve()
            if key == "cwd" and not path.is_dir():
                raise ConfigError(f"{section}.{key}: {value!r} is not a directory")
            options = {**options, key: str(path)}
            data = {**data, section: options}
    return data


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


def load_config(path: str | Path | None, overrides: dict[str, Any] | None = None,
                model: type[ExperimentConfig] | None = None) -> ExperimentConfig:
    """The experiment file at ``path`` (or none), with ``overrides`` (the command line) on top (``model``: a
    study's extension of the file, :class:`ExperimentConfig` by default)."""
    over = dict(overrides or {})
    context = {"base_dir": Path(path).parent.resolve()} if path is not None and "agents" not in over else None
    return (model or ExperimentConfig).load(path, over, context=context)


@dataclass
class Experiment:
    """An experiment with every choice made: what the runs and the report use."""

    command: str
    target_text: str
    agents: list[Any]  # runner AgentSpecs
    map: str
    episodes: Episodes  # a count, or the ids of a split
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

    @property
    def episode_count(self) -> int:
        """Episodes per agent (of a count or a split)."""
        return episode_count(self.episodes)

    def to_dict(self) -> dict[str, Any]:
        return {"command": self.command, "target": self.target_text, "agents": self.agent_labels,
                "agent_commands": {a.label: a.command for a in self.agents if a.command},
                "map": self.map, "seconds": self.seconds,
                "episodes": self.episodes if isinstance(self.episodes, int) else list(self.episodes),
                "metrics": list(self.metrics),
                "image_size": list(self.image_size), "proxy": self.proxy,
                "sweep": {k: list(v) for k, v in self.sweep.items()}, "search": self.search.model_dump(),
                "trials": self.trials, "n_boot": self.n_boot, "pod_seconds": self.pod_seconds, "seed": self.seed,
                "truth": self.truth}


def resolve(cfg: ExperimentConfig, command: Command, *, quick: bool = False,
            work_dir: str | Path = "out/agents", target=None):
    """(Experiment, Target): the config's choices, the target's fixed ones, then the command's defaults.

    A recorded target fixes the map and episode length (asking for others is an error naming the field)
    and offers its agents and episodes as defaults.
    """
    from proxybench.experiments.agent_args import AgentArgError, parse_agents
    from proxybench.targets.spec import open_target

    target = target or open_target(cfg.target, params=cfg.target_params, robot_nodes=cfg.robot_nodes,
                                   robot_options=cfg.robot_options, dtps_options=cfg.dtps_options,
                                   frame_rate=proxy_params(cfg.image_size, cfg.proxy).frame_rate)
    d = COMMAND_DEFAULTS[(command, quick)]
    if target.fixed_map is not None and cfg.map is not None and cfg.map != target.fixed_map:
        raise ConfigError(f"map: the target was recorded on {target.fixed_map!r}, the experiment asks for {cfg.map!r}")
    if target.fixed_seconds is not None and cfg.seconds is not None and abs(cfg.seconds - target.fixed_seconds) > 1e-9:
        raise ConfigError(f"seconds: the target's episodes last {target.fixed_seconds:g} s, the experiment asks for "
                          f"{cfg.seconds:g} s (proxies replay the target's episodes)")
    if target.n_episodes is not None and isinstance(cfg.episodes, int) and cfg.episodes > target.n_episodes:
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


def resolve_run(cfg: ExperimentConfig | Experiment, command: Literal["predictivity", "optimize"], run_dir: Path, *,
                quick: bool = False, target=None):
    """(Experiment, Target) of a study run in ``run_dir``: an experiment file's content resolved by :func:`resolve`
    (its agents built beside the run, in ``agents/``), or an already resolved :class:`Experiment` with ``target``
    (or, without one, its target text opened)."""
    if isinstance(cfg, ExperimentConfig):
        return resolve(cfg, command, quick=quick, work_dir=run_dir.parent / "agents", target=target)
    if target is None:
        from proxybench.targets.spec import open_target

        target = open_target(cfg.target_text)
    return cfg, target


class ExperimentStudy(Study[ExperimentConfig, Any]):
    """A study of the experiment file (predictivity, score-proxy, optimize, plan, plv-vs-prpv): its fields as
    options, less ``exclude``; defaults worded as :func:`default_help` words ``command``'s (``extra_defaults``
    beside)."""

    #: whose defaults (:data:`COMMAND_DEFAULTS`) a field left unset takes: the study's own name's by default
    defaults_of: ClassVar[Command | None] = None
    config: ClassVar[type[ExperimentConfig]] = ExperimentConfig
    config_help = "experiment file (YAML; every field: docs/targets.md)"
    extra_defaults: ClassVar[dict[str, str]] = {}

    #: ``module:function`` of the study's run, called (config, out, backend, progress, quick=) when the study does
    #: not write its own ``run``; and of its report, called (result, out): imported on use, so a command's
    #: ``--help`` does not load the runner
    runs: ClassVar[str | None] = None
    reports: ClassVar[str | None] = None

    def run(self, config: ExperimentConfig, out: Path, backend: Any, progress: Any, *, quick: bool = False) -> Any:
        return _function(self.runs, f"{self.name}.runs")(config, out, backend, progress, quick=quick)

    def write_report(self, result: Any, out: Path, *, wall: float = 0.0) -> list[Path]:
        return _function(self.reports, f"{self.name}.reports")(result, out)

    @property
    def command(self) -> Command:
        return self.defaults_of or typing.cast(Command, self.name)

    def help_defaults(self) -> dict[str, str]:
        return default_help(self.command) | self.extra_defaults

    def load(self, path: Path | None, overrides: dict[str, Any], *, quick: bool = False) -> ExperimentConfig:
        return load_config(path, overrides, self.config)


def _function(spec: str | None, what: str) -> Any:
    """The function ``module:name`` names (a study that names none must write the method itself)."""
    if spec is None:
        raise NotImplementedError(f"{what}: the study names no function and does not override the method")
    module, _, name = spec.partition(":")
    return getattr(importlib.import_module(module), name)
