"""The validation study's settings: :class:`ValidateConfig` (what a user sets: options and ``--config FILE``), the
families' typed defaults (:data:`FAMILIES`, a full and a quick mode each) and :class:`ValidateSettings`, every
choice made (the config over its family's defaults), frozen: what ``criteria.json`` pre-registers and every step
of the run reads. Light: importable without the simulator (the CLI builds its options from it).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_serializer

from proxybench.experiments.config import ConfigError, param_name
from proxybench.experiments.study import Cli, StudyConfig
from proxybench.usefulness.validation import METHODS as _METHODS

__all__ = ["FAMILIES", "NODE_AGENT", "PRIMARY_COMPARISONS", "PYTHON", "FamilyDefaults", "FamilyModes", "PrimaryPlan",
           "StratumPlan", "ValidateConfig", "ValidateSettings", "nominal_theta", "settings_for", "stratum_of"]

#: the 33 zoo agents of distinct behaviour in 10 families (the "-stop" variants equal their base on maps without stop
#: lines; the calibration drives are the calibration method's, not agents): the first 16 and the 17 independently
#: written controllers (agents/independent.py), so a family split can judge on controllers that share no code
_POOL = ("random", "straight", "bang-bang", "pid", "pid-fast", "pid-sluggish", "pid-twitchy", "pure-pursuit",
         "pure-pursuit-fast", "vision", "vision-fast", "vision-slow", "vision-pitch15", "vision-pitch25",
         "vision-wide", "vision-twitchy", "stanley", "stanley-gentle", "stanley-fast", "lqr", "lqr-soft",
         "lqr-delay", "mpc", "mpc-short", "mpc-fast", "cautious", "cautious-brisk", "hough", "hough-far",
         "hough-fast", "birdseye", "birdseye-far", "birdseye-pitch25")
#: a camera agent behind the AIDO protocol (its own process per episode), to keep node agents in every pool;
#: ``{python}`` is the interpreter running the study, filled in at run time so that the settings (and with them
#: criteria.json) do not depend on how proxybench was started (``python`` or ``python3`` of the same venv)
PYTHON = "{python}"
NODE_AGENT = f"vision-node={PYTHON} -m proxybench.protocol vision"
_QUICK_POOL = ("straight", "pid", "pid-twitchy", "pure-pursuit", "vision", "vision-fast", "vision-pitch25",
               "vision-slow")
#: the study's task metrics and selection methods (names of :mod:`proxybench.tasks.metrics`,
#: :data:`proxybench.usefulness.validation.METHODS`), checked when the config is validated
_METRICS = ("driven_lanedir_consec", "lane_score")


class FamilyDefaults(BaseModel):
    """What a family's study takes where the config is silent (one per mode)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    targets: int
    """targets drawn"""
    agents: tuple[str, ...]
    """the agent pool, split per target into tuning and held-out agents"""
    bc_agents: int = 0
    """behaviour-cloned agents trained for the pool"""
    episodes_tune: int
    """target episodes per tuning agent (E1)"""
    episodes_eval: int
    """fresh target episodes per held-out agent (E2)"""
    seconds: float
    """episode length [s]"""
    grid: dict[str, tuple[float, ...]]
    """the candidate θ: a grid over the search space"""
    draw: dict[str, tuple[float, float]]
    """the targets' θ ranges (the family's own parameter names), wider than the grid and off-centre"""
    maps: tuple[str, ...]
    """maps, one per target in turn"""
    near: dict[str, tuple[float, float]]
    """the near stratum: every parameter inside these ranges (proxybench's names), the range a factory-calibrated
    robot has; the far stratum is the rest"""
    robot_nodes: int = 1
    """processes of a robot-node target at once"""


class FamilyModes(BaseModel):
    """A family's defaults, full and ``--quick``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    full: FamilyDefaults
    quick: FamilyDefaults

    def mode(self, quick: bool) -> FamilyDefaults:
        return self.quick if quick else self.full


#: the search grids, centred on the nominal θ (trim 0, camera pitch 19.15°, command delay 0.10 s) in every family:
#: settings_for refuses a grid whose centre is not the nominal
_HELDOUT_GRID = {"trim": (-0.2, 0.0, 0.2), "camera_pitch": (15.15, 19.15, 23.15)}
_GYM_GRID = {"trim": (-0.2, 0.0, 0.2), "command_delay": (0.0, 0.10, 0.20)}
#: the near strata: |trim| <= 0.1 (a wheel pair a factory calibration leaves within 10 %) and the other searched
#: parameter inside the grid's range (a camera mount or a latency the factory's tolerance covers)
_HELDOUT_NEAR = {"trim": (-0.1, 0.1), "camera_pitch": (15.15, 23.15)}
_GYM_NEAR = {"trim": (-0.1, 0.1), "command_delay": (0.0, 0.2)}
_HELDOUT = FamilyModes(
    full=FamilyDefaults(targets=40, agents=(*_POOL, NODE_AGENT), bc_agents=5, episodes_tune=10, episodes_eval=10,
                        seconds=15.0, grid=_HELDOUT_GRID,
                        draw={"trim": (-0.15, 0.35), "camera_pitch": (13.15, 27.15), "gain": (0.85, 1.15),
                              "command_delay": (0.02, 0.2), "blur_time": (0.0, 0.1), "camera_height": (0.1, 0.116)},
                        maps=("loop_3x3",), near=_HELDOUT_NEAR),
    quick=FamilyDefaults(targets=3, agents=_QUICK_POOL, episodes_tune=2, episodes_eval=2, seconds=6.0,
                         grid=_HELDOUT_GRID, draw={"trim": (-0.15, 0.35), "camera_pitch": (13.15, 27.15)},
                         maps=("loop_3x3",), near=_HELDOUT_NEAR))
#: per family: targets, pool, episodes (E1, E2), seconds, search grid, target θ ranges (wider than the grid and
#: off-centre), maps; full and quick
FAMILIES: dict[str, FamilyModes] = {
    "heldout": _HELDOUT,
    "gym": FamilyModes(
        full=_HELDOUT.full.model_copy(update={
            "grid": _GYM_GRID, "maps": ("loop_3x3", "zigzag"), "robot_nodes": 2, "near": _GYM_NEAR, "bc_agents": 6,
            "draw": {"trim": (-0.15, 0.35), "delay": (0.02, 0.3), "cam_angle": (13.15, 27.15),
                     "cam_height": (0.1, 0.116)}}),
        quick=_HELDOUT.quick.model_copy(update={
            "grid": _GYM_GRID, "robot_nodes": 2, "near": _GYM_NEAR,
            "draw": {"trim": (-0.15, 0.35), "delay": (0.02, 0.3)}})),
}
#: the primary comparison: PRPV against each of these calibrations (docs/validate.md)
PRIMARY_COMPARISONS = ("calibration", "trajectory_fit")
#: the family's parameter names for the target draw, when they are not proxybench's (gym's own names)
_GYM_TO_PROXY = {"delay": "command_delay", "cam_angle": "camera_pitch", "cam_height": "camera_height"}


class ValidateConfig(StudyConfig):
    """The study's settings; every field left unset takes the family's default (``--quick``: smaller ones)."""

    family: Literal["heldout", "gym"] = "heldout"
    """target family: heldout (built-in structural stand-ins) | gym (gym-duckietown nodes, after `proxybench gym
    setup`)"""
    targets: int | None = Field(None, ge=2, le=1000)
    """targets drawn from the family"""
    agents: Annotated[tuple[str, ...] | None, Cli("--agent", metavar="AGENT")] = Field(None, min_length=4)
    """the agent pool: zoo names, NAME=COMMAND nodes, checkpoints (split per target into tuning and held-out)"""
    tuning_share: float = Field(0.5, gt=0.0, lt=1.0)
    """share of the pool that tunes θ (the rest judges it; a random split)"""
    split: Literal["family", "random"] = "family"
    """how the pool is split per target: family (tune on some agent families, judge on the others, the direction
    alternating over targets) | random (agents at random, tuning_share of them tuning)"""
    episodes_tune: int | None = Field(None, ge=1, le=100)
    """target episodes per tuning agent (E1)"""
    episodes_eval: int | None = Field(None, ge=1, le=100)
    """fresh target episodes per held-out agent (E2)"""
    seconds: float | None = Field(None, gt=0.0, le=600.0)
    """episode length [s]"""
    maps: Annotated[tuple[str, ...] | None, Cli("--map")] = None
    """maps, one per target in turn"""
    grid: dict[str, tuple[float, ...]] | None = None
    """the candidate θ: values per parameter (their grid; the nominal calibration is added)"""
    draw: dict[str, tuple[float, float]] | None = None
    """the targets' θ ranges LOW,HIGH (gym: gym's names), wider than the grid"""
    metrics: Annotated[tuple[str, ...], Cli("--metric")] = _METRICS
    """task metrics"""
    tolerances: dict[str, float] | None = None
    """ε per metric: differences within it are ties (default: AIDO's, scaled to the episode length)"""
    methods: Annotated[tuple[str, ...], Cli("--method")] = _METHODS
    """the selection methods compared (nominal, the baseline, is required)"""
    top_k: int = Field(3, ge=1, le=20)
    """k of the top-k regret"""
    alpha: float = Field(0.05, gt=0.0, lt=0.5)
    """the primary test's level"""
    power: float = Field(0.8, gt=0.5, lt=1.0)
    """the power of the minimum detectable effect"""
    margin: float = Field(0.02, gt=0.0, le=1.0)
    """the primary comparison's margin in PRPV/K(K−1): PRPV is non-inferior to a calibration when the upper bound
    of PRPV − calibration is below it"""
    assumed_sd: float = Field(0.10, gt=0.0, le=1.0)
    """the standard deviation of the paired differences the power computation assumes (PRPV/K(K−1))"""
    multiplicity: Literal["holm", "none"] | None = None
    """how the primary tests (2 strata × 2 comparisons) share alpha: holm (Holm's step-down; a new study's
    default) | none (each at alpha, as studies registered before 28 Nov 2026); unset on a folder that holds a
    study: what its criteria registered"""
    per_stratum: int | None = Field(None, ge=2, le=500)
    """targets in each stratum (near, far): the draw goes on until each has this many, so the strata's sizes are
    declared, not left to the draw's shares (targets = 2 × this)"""
    near: dict[str, tuple[float, float]] | None = None
    """the near stratum LOW,HIGH per parameter (proxybench's names): the θ a factory-calibrated robot has; the far
    stratum is the rest (default: the family's: |trim| <= 0.1 and the other searched parameter within the grid)"""
    image_size: Annotated[tuple[int, int], Cli(metavar="WIDTHxHEIGHT", sep="x")] = (160, 120)
    """camera image [px]"""
    n_boot: int = Field(100, ge=10, le=10_000)
    """bootstrap resamples of the probabilistic methods"""
    seed: int = Field(0, ge=0, le=100_000)
    """the study's seed (agent splits, episode seeds, BC agents)"""
    draw_seed: int | None = Field(None, ge=0)
    """the targets' θ seed (default: drawn at run time and kept out of criteria.json)"""
    bc_agents: int | None = Field(None, ge=0, le=8)
    """behaviour-cloned agents trained for the pool (needs PyTorch)"""
    interim: bool = False
    """run nothing: report the targets finished so far (an interim look; give the settings the study was started
    with; it shows no target's θ, and the decision waits for all targets)"""
    new_study: bool = False
    """start a new study in a folder that holds one: the old study (criteria, look log, secret, targets, runs,
    report) is moved to OUT/superseded-TIME/ first (without it, other settings on such a folder are refused)"""
    target: Annotated[str | None, Cli(metavar="DIR|robot:CMD|dtps:HOST/PATH")] = None
    """the study on your own target instead of a family: a recording DIR, robot:CMD, dtps:HOST[:PORT]/PATH or
    reality; every agent runs on it once, then many random agent × episode splits (docs/validate.md, "On your own
    target")"""

    @field_validator("metrics")
    @classmethod
    def _metrics(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        from proxybench.tasks.metrics import METRICS

        unknown = [m for m in v if m not in METRICS]
        if unknown or not v:
            raise ValueError(f"unknown metric(s) {unknown}; known: {', '.join(METRICS)}")
        return v

    @field_validator("methods")
    @classmethod
    def _methods(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [m for m in v if m not in _METHODS]
        if unknown or "nominal" not in v:
            raise ValueError(f"{unknown or 'nominal is missing'}; known: {', '.join(_METHODS)} (nominal, the baseline "
                             "every method is compared with, is required)")
        return v

    @field_validator("grid", "near")
    @classmethod
    def _names(cls, v: dict | None) -> dict | None:
        for name in v or {}:
            param_name(name)
        return v

    @field_validator("near")
    @classmethod
    def _ranges(cls, v: dict | None) -> dict | None:
        for name, r in (v or {}).items():
            if len(r) != 2 or r[0] > r[1]:
                raise ValueError(f"{name}: give LOW,HIGH with LOW <= HIGH, got {list(r)}")
        return v


class StratumPlan(BaseModel):
    """One pre-declared stratum of the primary comparison: what puts a target in it, and the size it needs."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    definition: str
    """which targets (from their hidden θ, assigned at the reveal)"""
    share: float
    """the share of targets the draw puts in it (uniform draw; a parameter not drawn sits at the nominal)"""
    needed: int
    """targets it needs to show non-inferiority within the margin with the declared power, at the assumed SD and a
    true difference of 0"""
    allocated: int | None = None
    """targets the draw puts in it by design (``--per-stratum``: drawn until it has them); None: ``share`` of the
    targets, as they fall"""

    @model_serializer(mode="wrap")
    def _omit_unallocated(self, handler: Any) -> dict[str, Any]:
        """No ``allocated`` key when it is None: the criteria (and every target's settings key) of a study drawn as
        the targets fall are byte-identical to those written before the field existed."""
        data = handler(self)
        if data.get("allocated") is None:
            data.pop("allocated", None)
        return data

    def planned(self, targets: int, alpha: float, power: float, assumed_sd: float) -> tuple[float, float | None]:
        """(targets in it: ``allocated``, else expected: ``targets`` × share; the margin (PRPV/K(K−1)) that many can
        show with ``power`` at the assumed SD; None under 2). Derived, not a setting: a study of other size differs
        in ``targets`` alone."""
        from proxybench.usefulness.validation import minimum_detectable_effect

        n = float(self.allocated) if self.allocated is not None else targets * self.share
        return round(n, 3), (round(minimum_detectable_effect(int(n), alpha, power) * assumed_sd, 6)
                             if int(n) >= 2 else None)


class PrimaryPlan(BaseModel):
    """The pre-registered primary comparison: PRPV against the calibrations, per stratum, with a margin."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    comparisons: tuple[str, ...]
    """PRPV − each of these, in the quality of the pick on the held-out agents (PRPV/K(K−1) on B over E2)"""
    margin: float
    assumed_sd: float
    strata: dict[str, StratumPlan]
    test: str
    decision: str
    multiplicity: Literal["holm"] | None = None
    """how the primary tests (strata × comparisons) share alpha: ``holm`` (Holm's step-down, the default of a
    study registered since 28 Nov 2026); None: each test at alpha, as the studies registered before"""

    @model_serializer(mode="wrap")
    def _omit_uncorrected(self, handler: Any) -> dict[str, Any]:
        """No ``multiplicity`` key when it is None: the criteria of a study registered before the field existed
        read (and hash) byte for byte as they were written."""
        data = handler(self)
        if data.get("multiplicity") is None:
            data.pop("multiplicity", None)
        return data

    @property
    def tests(self) -> int:
        """How many primary tests share alpha: strata × comparisons."""
        return len(self.strata) * len(self.comparisons)

    def level(self, alpha: float) -> float:
        """The strictest level a primary test is held to: the level the sizes are planned at."""
        return first_level(alpha, self.tests, self.multiplicity)


def first_level(alpha: float, tests: int, multiplicity: str | None) -> float:
    """The level the first of ``tests`` primary tests is held to: alpha/tests under Holm (its first step),
    alpha itself uncorrected."""
    return alpha / tests if multiplicity == "holm" else alpha


class ValidateSettings(BaseModel):
    """Every choice of a validation study (the config, then its family's defaults); the draw seed is not among them.

    Its JSON (``model_dump(mode="json")``, fields in this order) is what ``criteria.json`` pre-registers and what a
    finished target's ``settings_key`` hashes, so a field added here changes every key: add one only with a new
    study."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    family: Literal["heldout", "gym"]
    quick: bool
    targets: int
    agents: tuple[str, ...]
    tuning_share: float
    split: Literal["family", "random"]
    episodes_tune: int
    episodes_eval: int
    seconds: float
    maps: tuple[str, ...]
    grid: dict[str, tuple[float, ...]]
    draw: dict[str, tuple[float, ...]]
    metrics: tuple[str, ...]
    tolerances: dict[str, float]
    methods: tuple[str, ...]
    top_k: int
    alpha: float
    power: float
    image_size: tuple[int, int]
    n_boot: int
    seed: int
    bc_agents: int
    robot_nodes: int
    margin: float
    assumed_sd: float
    near: dict[str, tuple[float, float]]
    primary: PrimaryPlan

    def proxy_draw(self) -> dict[str, tuple[float, ...]]:
        """The targets' θ ranges under proxybench's names (gym's renamed)."""
        return self.to_proxy(self.draw)

    def to_proxy(self, theta: dict) -> dict:
        """``theta`` (a target's θ or ranges, under the family's names) under proxybench's names."""
        return {_GYM_TO_PROXY.get(k, k) if self.family == "gym" else k: v for k, v in theta.items()}


def _draw_name(family: str, name: str) -> None:
    """A target parameter the family knows: proxybench's θ for held-out targets, gym's names for gym's."""
    if family != "gym":
        param_name(name)
        return
    from proxybench.gym.params import PARAMS

    if name not in PARAMS:
        raise ConfigError(f"draw: {name!r} is not a gym-duckietown parameter; `proxybench gym params` lists them")


def nominal_theta(names) -> dict[str, float]:
    """The nominal calibration's value of each named parameter (proxybench's names)."""
    from proxybench.domain.params import NOMINAL_CALIBRATION, DomainParams

    return {n: float(NOMINAL_CALIBRATION.get(n, DomainParams.model_fields[n].default)) for n in names}


def _check_centred(grid: dict[str, tuple[float, ...]]) -> None:
    """A grid's centre must be the nominal θ: an odd number of values per parameter, the nominal in the middle."""
    for name, nom in nominal_theta(grid).items():
        values = sorted(grid[name])
        if len(values) % 2 == 0:
            raise ConfigError(f"grid: {name} has {len(values)} values and so no centre; give an odd number with the "
                              f"nominal {nom:g} in the middle")
        mid = values[len(values) // 2]
        if abs(mid - nom) > 1e-9:
            raise ConfigError(f"grid: {name}'s centre is {mid:g}, the nominal θ's is {nom:g}; centre the grid on the "
                              "nominal so that tuning and the nominal θ start even")


def stratum_of(theta: dict[str, float], near: dict[str, tuple[float, float]]) -> str:
    """``near`` when every parameter of the near box is inside it (a parameter θ lacks: at the nominal), else
    ``far``."""
    nominal = nominal_theta(near)
    inside = all(lo - 1e-12 <= float(theta.get(n, nominal[n])) <= hi + 1e-12 for n, (lo, hi) in near.items())
    return "near" if inside else "far"


def _plan(s: dict, draw: dict[str, tuple[float, ...]], per_stratum: int | None = None,
          multiplicity: Literal["holm"] | None = "holm") -> PrimaryPlan:
    """The primary comparison's plan: per stratum its share of the draw and the targets it needs at the level the
    multiplicity rule holds the first test to (the targets planned in it and their MDE follow from the study's
    ``targets``: :meth:`StratumPlan.planned`)."""
    from proxybench.usefulness.validation import targets_needed

    tests = 2 * len(PRIMARY_COMPARISONS)  # the near and far strata × the comparisons
    level = first_level(s["alpha"], tests, multiplicity)
    near, nominal = s["near"], nominal_theta(s["near"])
    share = 1.0
    for n, (lo, hi) in near.items():
        if n in draw:
            a, b = min(draw[n]), max(draw[n])
            share *= max(0.0, min(hi, b) - max(lo, a)) / (b - a) if b > a else float(lo <= a <= hi)
        else:
            share *= float(lo <= nominal[n] <= hi)
    needed = targets_needed(s["margin"], s["assumed_sd"], level, s["power"])
    box = ", ".join(f"{n} in [{lo:g}, {hi:g}]" for n, (lo, hi) in near.items())
    strata = {}
    for name, sh, words in (("near", share, f"every one of {box} (the θ a factory-calibrated robot has)"),
                            ("far", 1.0 - share, f"the rest: some parameter outside {box}")):
        if per_stratum is not None and sh <= 0.0:
            raise ConfigError(f"per_stratum: the draw puts no target in the {name} stratum ({box}); widen --draw or "
                              "leave per_stratum out")
        strata[name] = StratumPlan(definition=words, share=round(sh, 6), needed=needed, allocated=per_stratum)
    tail = ("a target where a calibration is not applicable is left out of that comparison; strata assigned from "
            "the hidden θ at the reveal (final report only)")
    test = (f"per stratum and comparison, the paired differences PRPV − calibration of the pick's quality on the "
            f"held-out agents (PRPV/K(K−1), B on E2); the upper bound of their one-sided {1 - s['alpha']:g} t "
            f"interval: non-inferior if below the margin {s['margin']:g}, superior if below 0; {tail}")
    if multiplicity == "holm":
        test = (f"per stratum and comparison ({tests} tests), the paired differences PRPV − calibration of the pick's "
                "quality on the held-out agents (PRPV/K(K−1), B on E2), tested under Holm's step-down so that the "
                f"chance of any false 'non-inferior' among the {tests} is at most {s['alpha']:g}: ordered by their "
                f"one-sided t p-value against the margin {s['margin']:g}, the j-th (from 1) is non-inferior if the "
                f"upper bound of its one-sided t interval at level {s['alpha']:g}/({tests} − j + 1) is below the "
                f"margin and every earlier one was; superior if non-inferior and that bound is below 0; {tail}")
    return PrimaryPlan(
        comparisons=PRIMARY_COMPARISONS, margin=s["margin"], assumed_sd=s["assumed_sd"], strata=strata, test=test,
        decision=("'PRPV is non-inferior to X within the margin in stratum S' only when the test says so, 'PRPV is "
                  "superior to X in stratum S' only when the upper bound is below 0; otherwise 'not shown', with "
                  "the interval and n; PRPV − nominal θ is a secondary comparison"),
        multiplicity=multiplicity)


def settings_for(cfg: ValidateConfig, quick: bool) -> ValidateSettings:
    """Every choice made (the config, then the family's defaults); the draw seed is not among them. Refuses a grid
    whose centre is not the nominal θ and a draw that is not wider than the grid."""
    d = FAMILIES[cfg.family].mode(quick)
    seconds = cfg.seconds or d.seconds
    scale = seconds / 60.0  # AIDO's lane-following tolerances are for 60 s episodes
    tolerances = {"driven_lanedir_consec": 0.62 * scale, "survival_time": 2.0 * scale, "lane_score": 2.0 * scale,
                  **(cfg.tolerances or {})}
    grid = cfg.grid or d.grid
    _check_centred(grid)
    if cfg.per_stratum is not None and cfg.targets is not None and cfg.targets != 2 * cfg.per_stratum:
        raise ConfigError(f"targets: {cfg.targets} is not 2 × per_stratum ({2 * cfg.per_stratum}); give one of them")
    targets = 2 * cfg.per_stratum if cfg.per_stratum is not None else cfg.targets or d.targets
    fields = dict(
        family=cfg.family, quick=quick, targets=targets, agents=cfg.agents or d.agents,
        tuning_share=cfg.tuning_share, split=cfg.split, episodes_tune=cfg.episodes_tune or d.episodes_tune,
        episodes_eval=cfg.episodes_eval or d.episodes_eval, seconds=seconds, maps=cfg.maps or d.maps,
        grid=grid, draw=cfg.draw or d.draw, metrics=cfg.metrics,
        tolerances={m: tolerances.get(m, 0.0) for m in cfg.metrics}, methods=cfg.methods, top_k=cfg.top_k,
        alpha=cfg.alpha, power=cfg.power, image_size=cfg.image_size, n_boot=cfg.n_boot, seed=cfg.seed,
        bc_agents=d.bc_agents if cfg.bc_agents is None else cfg.bc_agents, robot_nodes=d.robot_nodes,
        margin=cfg.margin, assumed_sd=cfg.assumed_sd, near=cfg.near or d.near)
    for name in fields["draw"]:
        _draw_name(cfg.family, name)
    draw = {_GYM_TO_PROXY.get(k, k) if cfg.family == "gym" else k: v for k, v in fields["draw"].items()}
    rule = None if cfg.multiplicity == "none" else "holm"
    s = ValidateSettings(**fields, primary=_plan(fields, draw, cfg.per_stratum, rule))
    outside = [k for k in s.grid if k in draw and not (min(draw[k]) < min(s.grid[k]) or max(draw[k]) > max(s.grid[k]))]
    if outside:
        raise ConfigError(f"draw: {', '.join(outside)} must be drawn wider than the grid searches it, so that the "
                          "nominal calibration can lose")
    return s
