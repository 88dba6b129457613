"""`proxybench validate`: does tuning a simulator help, on agents and target episodes it was not tuned on?

The study the thesis' central claim needs (docs/validate.md). For each of many targets — drawn from a
*family* (held-out structural stand-ins, or another simulator), their θ drawn at run time from a seed whose
hash alone is written down until the reveal, wider than the proxies' search space and off-centre, so that
keeping the nominal calibration is a real competitor that can lose:

1. the agent pool is split at random into a tuning set A and a disjoint held-out set B;
2. the target runs A on episodes E1 and B on fresh episodes E2 (its own seeds per target);
3. every candidate θ (a grid over the search space, and the nominal calibration) replays all of them;
4. each method (:data:`~proxybench.usefulness.validation.METHODS`: PRPV, ε-PRPV, probabilistic PRPV, PPV,
   Pearson, Spearman, Kendall, MMRV, trajectory matching, and the nominal θ) picks θ from A on E1;
5. the pick is judged on B on E2 (:func:`~proxybench.usefulness.validation.quality`): its regret against the
   oracle θ (the best candidate for B on E2 in hindsight), paired against the nominal θ's.

``criteria.json`` — the endpoints, the test, the minimum detectable effect, the commit and a hash of the
scoring code — is written before the first episode; the report checks the code it scores with against it.
Every episode goes through the runner's cache, and each finished target is written to ``targets/``, so an
interrupted study resumes.
"""

from __future__ import annotations

import hashlib
import inspect
import itertools
import json
import secrets
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from proxybench.experiments.agent_args import AgentArgError, parse_agents
from proxybench.experiments.config import ConfigError, param_name
from proxybench.experiments.proxies import proxy_params
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
from proxybench.runner.replay import replay_runs
from proxybench.runner.sweep import run_jobs
from proxybench.targets.base import Target, TargetRun, by_agent
from proxybench.tasks.metrics import METRICS as TASK_METRICS
from proxybench.usefulness import validation
from proxybench.usefulness.validation import METHODS, minimum_detectable_effect, pick, quality, selection_scores

__all__ = ["FAMILIES", "ValidateConfig", "ValidationRun", "run_validate", "settings_for"]

Progress = Callable[[str, int, int], None]

#: the 16 zoo agents of distinct behaviour (the "-stop" variants equal their base on maps without stop lines)
_POOL = ("random", "straight", "bang-bang", "pid", "pid-fast", "pid-sluggish", "pid-twitchy", "pure-pursuit",
         "pure-pursuit-fast", "vision", "vision-fast", "vision-slow", "vision-pitch15", "vision-pitch25",
         "vision-wide", "vision-twitchy")
#: a camera agent behind the AIDO protocol (its own process per episode), to keep node agents in every pool;
#: ``{python}`` is the interpreter running the study, filled in at run time so that the settings (and with them
#: criteria.json) do not depend on how proxybench was started (``python`` or ``python3`` of the same venv)
PYTHON = "{python}"
NODE_AGENT = f"vision-node={PYTHON} -m proxybench.protocol vision"
_QUICK_POOL = ("straight", "pid", "pid-twitchy", "pure-pursuit", "vision", "vision-fast", "vision-pitch25",
               "vision-slow")

#: per family and mode: targets, pool, episodes (E1, E2), seconds, search grid, target θ ranges (wider than the
#: grid and off-centre), maps
FAMILIES: dict[str, dict[bool, dict[str, Any]]] = {
    "heldout": {
        False: {"targets": 40, "agents": (*_POOL, NODE_AGENT), "bc_agents": 2, "episodes_tune": 3, "episodes_eval": 3,
                "seconds": 15.0, "grid": {"trim": (-0.2, 0.0, 0.2), "camera_pitch": (15.15, 19.15, 23.15)},
                "draw": {"trim": (-0.15, 0.35), "camera_pitch": (13.15, 27.15), "gain": (0.85, 1.15),
                         "command_delay": (0.02, 0.2), "blur_time": (0.0, 0.1), "camera_height": (0.1, 0.116)},
                "maps": ("loop_3x3",)},
        True: {"targets": 3, "agents": _QUICK_POOL, "episodes_tune": 2, "episodes_eval": 2, "seconds": 6.0,
               "grid": {"trim": (-0.2, 0.0, 0.2), "camera_pitch": (15.15, 19.15, 23.15)},
               "draw": {"trim": (-0.15, 0.35), "camera_pitch": (13.15, 27.15)}, "maps": ("loop_3x3",)},
    },
}
FAMILIES["gym"] = {
    False: {**FAMILIES["heldout"][False], "grid": {"trim": (-0.2, 0.0, 0.2), "command_delay": (0.05, 0.15, 0.25)},
            "draw": {"trim": (-0.15, 0.35), "delay": (0.02, 0.3), "cam_angle": (13.15, 27.15),
                     "cam_height": (0.1, 0.116)}, "maps": ("loop_3x3", "zigzag"), "robot_nodes": 2},
    True: {**FAMILIES["heldout"][True], "grid": {"trim": (-0.2, 0.0, 0.2), "command_delay": (0.05, 0.15, 0.25)},
           "draw": {"trim": (-0.15, 0.35), "delay": (0.02, 0.3)}, "maps": ("loop_3x3",), "robot_nodes": 2},
}
#: the family's parameter names for the target draw, when they are not proxybench's (gym's own names)
_GYM_TO_PROXY = {"delay": "command_delay", "cam_angle": "camera_pitch", "cam_height": "camera_height"}
SCORING_FILES = (validation.__file__,)


class ValidateConfig(BaseModel):
    """The study's settings; every field left unset takes the family's default (``--quick``: smaller ones)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    family: Literal["heldout", "gym"] = "heldout"
    targets: int | None = Field(None, ge=2, le=1000)
    agents: list[str] | None = Field(None, min_length=4)
    tuning_share: float = Field(0.5, gt=0.0, lt=1.0)
    episodes_tune: int | None = Field(None, ge=1, le=100)
    episodes_eval: int | None = Field(None, ge=1, le=100)
    seconds: float | None = Field(None, gt=0.0, le=600.0)
    maps: tuple[str, ...] | None = None
    grid: dict[str, tuple[float, ...]] | None = None
    draw: dict[str, tuple[float, float]] | None = None
    metrics: tuple[str, ...] = ("driven_lanedir_consec", "lane_score")
    tolerances: dict[str, float] | None = None
    methods: tuple[str, ...] = METHODS
    top_k: int = Field(3, ge=1, le=20)
    alpha: float = Field(0.05, gt=0.0, lt=0.5)
    power: float = Field(0.8, gt=0.5, lt=1.0)
    image_size: tuple[int, int] = (160, 120)
    n_boot: int = Field(100, ge=10, le=10_000)
    seed: int = Field(0, ge=0, le=100_000)
    draw_seed: int | None = Field(None, ge=0, description="None: drawn at run time and kept out of criteria.json")
    bc_agents: int | None = Field(None, ge=0, le=8, description="behaviour-cloned agents trained for the pool")

    @field_validator("metrics")
    @classmethod
    def _metrics(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [m for m in v if m not in TASK_METRICS]
        if unknown or not v:
            raise ValueError(f"unknown metric(s) {unknown}; known: {', '.join(TASK_METRICS)}")
        return v

    @field_validator("methods")
    @classmethod
    def _methods(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [m for m in v if m not in METHODS]
        if unknown or "nominal" not in v:
            raise ValueError(f"methods: {unknown or 'nominal is missing'}; known: {', '.join(METHODS)} (nominal, "
                             "the baseline every method is compared with, is required)")
        return v

    @field_validator("grid")
    @classmethod
    def _names(cls, v: dict | None) -> dict | None:
        for name in v or {}:
            param_name(name)
        return v


def _draw_name(family: str, name: str) -> None:
    """A target parameter the family knows: proxybench's θ for held-out targets, gym's names for gym's."""
    if family != "gym":
        param_name(name)
        return
    from proxybench.gym.params import PARAMS

    if name not in PARAMS:
        raise ConfigError(f"draw: {name!r} is not a gym-duckietown parameter; `proxybench gym params` lists them")


def settings_for(cfg: ValidateConfig, quick: bool) -> dict[str, Any]:
    """Every choice made (the config, then the family's defaults); the draw seed is not among them."""
    d = FAMILIES[cfg.family][quick]
    seconds = cfg.seconds or d["seconds"]
    scale = seconds / 60.0  # AIDO's lane-following tolerances are for 60 s episodes
    tolerances = {"driven_lanedir_consec": 0.62 * scale, "survival_time": 2.0 * scale, "lane_score": 2.0 * scale,
                  **(cfg.tolerances or {})}
    s = {"family": cfg.family, "quick": quick, "targets": cfg.targets or d["targets"],
         "agents": list(cfg.agents or d["agents"]), "tuning_share": cfg.tuning_share,
         "episodes_tune": cfg.episodes_tune or d["episodes_tune"],
         "episodes_eval": cfg.episodes_eval or d["episodes_eval"],
         "seconds": seconds, "maps": list(cfg.maps or d["maps"]),
         "grid": {k: list(v) for k, v in (cfg.grid or d["grid"]).items()},
         "draw": {k: list(v) for k, v in (cfg.draw or d["draw"]).items()}, "metrics": list(cfg.metrics),
         "tolerances": {m: tolerances.get(m, 0.0) for m in cfg.metrics}, "methods": list(cfg.methods),
         "top_k": cfg.top_k, "alpha": cfg.alpha, "power": cfg.power, "image_size": list(cfg.image_size),
         "n_boot": cfg.n_boot, "seed": cfg.seed,
         "bc_agents": d.get("bc_agents", 0) if cfg.bc_agents is None else cfg.bc_agents,
         "robot_nodes": d.get("robot_nodes", 1)}
    draw = {_GYM_TO_PROXY.get(k, k) if cfg.family == "gym" else k: v for k, v in s["draw"].items()}
    for name in s["draw"]:
        _draw_name(cfg.family, name)
    outside = [k for k in s["grid"] if k in draw and not (min(draw[k]) < min(s["grid"][k])
                                                       or max(draw[k]) > max(s["grid"][k]))]
    if outside:
        raise ConfigError(f"draw: {', '.join(outside)} must be drawn wider than the grid searches it, so that the "
                          "nominal calibration can lose")
    return s


# -- criteria, written before the first episode -------------------------------------------------------------------

def _draw_seed(cfg: ValidateConfig, out: Path) -> int:
    """The seed of the targets' θ: the config's, else one drawn now and kept in ``out/secret/`` (mode 600)."""
    if cfg.draw_seed is not None:
        return cfg.draw_seed
    path = out / "secret" / "draw_seed"
    if path.exists():
        return int(path.read_text())
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    seed = secrets.randbits(48)
    path.write_text(str(seed))
    path.chmod(0o600)
    return seed


def scoring_hash() -> dict[str, str]:
    """sha256 of the code that scores the study (its measures and this module's scoring), per file."""
    sources = {Path(f).name: Path(f).read_bytes() for f in SCORING_FILES}
    sources["validate.py:score_target"] = inspect.getsource(score_target).encode()
    return {k: hashlib.sha256(v).hexdigest() for k, v in sources.items()}


def write_criteria(s: dict[str, Any], draw_seed: int, out: Path) -> Path:
    """``criteria.json``: endpoints, test, minimum detectable effect, commit and scoring-code hash, the settings,
    and only a hash of the draw seed. Kept when a resumed study has the same settings."""
    from proxybench.experiments.reporting import source_commit

    path = out / "criteria.json"
    seed_hash = hashlib.sha256(str(draw_seed).encode()).hexdigest()
    try:
        old = json.loads(path.read_text())
        if old.get("settings") == json.loads(json.dumps(s)) and old.get("draw_seed_sha256") == seed_hash:
            return path
    except (OSError, ValueError):
        pass
    n = s["targets"]
    doc = {
        "written": time.strftime("%Y-%m-%d %H:%M:%S %z"), "commit": source_commit(), "scoring_sha256": scoring_hash(),
        "draw_seed_sha256": seed_hash, "settings": s,
        "unit": "the target (each with its own episode seeds and tuning/held-out split of the agents)",
        "primary_endpoint": "regret of the picked θ on the held-out agents B over fresh target episodes E2: "
                            "PRPV/K(K−1) of the pick minus that of the oracle θ (the candidate lowest on it in "
                            "hindsight)",
        "secondary_endpoints": ["regret in 1 − Kendall τ_b (first metric)", "regret of picking the top agent (first "
                                "metric, its unit)", f"regret of picking the top {s['top_k']}", "hit rate: the pick "
                                "within one grid step of the oracle, beside the nominal pick's"],
        "primary_comparison": "PRPV's regret minus the nominal θ's, per target",
        "test": f"one-sided Wilcoxon signed-rank test of the paired differences (H1: PRPV's regret is lower), "
                f"alpha {s['alpha']}; a one-sided paired t-test and a percentile bootstrap interval of the mean "
                "difference beside it; every other method against the nominal θ the same way (secondary, no "
                "multiplicity correction: read them as descriptive)",
        "minimum_detectable_effect": {"d_z": minimum_detectable_effect(n, s["alpha"], s["power"]), "targets": n,
                                      "power": s["power"], "meaning": "mean paired difference in standard deviations "
                                      "of the differences a one-sided paired t-test detects with that power"},
        "decision": "tuning helps on held-out agents if the primary test rejects at alpha; otherwise the study does "
                    "not show it (an effect below the minimum detectable one may exist)",
    }
    path.write_text(json.dumps(doc, indent=1))
    return path


# -- running ------------------------------------------------------------------------------------------------------

@dataclass
class ValidationRun:
    """The settings, the criteria file and one record per target (picks, qualities of every candidate)."""

    settings: dict[str, Any]
    criteria_file: Path
    records: list[dict[str, Any]]
    targets: list[Any]
    episodes_run: int = 0
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    indices: list[int] = field(default_factory=list)  # the target index of each record (an interim look skips some)


#: data and training of the study's behaviour-cloned agents: different amounts, so that their quality differs
_BC_SAMPLES = (1500, 6000, 3000, 12000)


def train_bc_agents(s: dict[str, Any], folder: Path, progress: Progress | None = None) -> list[str]:
    """Checkpoints of ``bc_agents`` networks cloned from the expert in the nominal proxy, from the study's seed
    (trained once; a resumed study reuses them). Needs PyTorch (the ``learning`` extra)."""
    if not s["bc_agents"]:
        return []
    try:
        import torch  # noqa: F401
    except ImportError:
        raise ConfigError("bc_agents: training behaviour-cloned agents needs PyTorch (pip install "
                          "'proxybench[learning]'); or set bc_agents: 0") from None
    from proxybench.learning import ModelConfig, TrainConfig, build_model, proxy_domain, save_checkpoint, train
    from proxybench.runner.collect import CollectConfig, collect

    paths = []
    for i in range(s["bc_agents"]):
        path = folder / f"bc-{s['seed']}-{i}.pt"
        if not (path.exists() and path.with_suffix(".json").exists()):
            n = _BC_SAMPLES[i % len(_BC_SAMPLES)]
            data = collect(proxy_domain(80, 60), CollectConfig(samples=n, robots=16, seed=s["seed"] * 100 + i),
                           progress=(lambda d, t, i=i: progress(f"BC agent {i}: data", d, t)) if progress else None)
            model = build_model(ModelConfig(), seed=s["seed"] * 100 + i)
            train(model, data, TrainConfig(epochs=8.0, max_steps=800, seed=s["seed"] * 100 + i))
            save_checkpoint(path, model, {"samples": n, "study_seed": s["seed"], "index": i})
        paths.append(str(path))
    return paths


def _family_targets(s: dict[str, Any], draw_seed: int, out: Path) -> list[Any]:
    """The family's targets, black boxes until reveal (their θ drawn from ``draw_seed``)."""
    ranges = {k: tuple(v) for k, v in s["draw"].items()}
    if s["family"] == "gym":
        from proxybench.gym.environment import check_environment
        from proxybench.targets.gym import gym_targets

        env = check_environment(render=False)
        if env.problems:
            raise ConfigError("family gym: gym-duckietown's environment is not ready: " + "; ".join(env.problems))
        return gym_targets(s["targets"], draw_seed, ranges, out / "secret" / "gym", nodes=s["robot_nodes"])
    from proxybench.targets.heldout import heldout_targets

    return heldout_targets(s["targets"], draw_seed, ranges)


def _candidates(s: dict[str, Any]) -> list[dict[str, float]]:
    """Every grid point, then the nominal calibration if the grid does not hold it."""
    names = list(s["grid"])
    points = [dict(zip(names, values, strict=True)) for values in itertools.product(*s["grid"].values())]
    nominal = proxy_params(tuple(s["image_size"]))
    here = {n: float(getattr(nominal, n)) for n in names}
    if here not in points:
        points.append(here)
    return points


def _replay_jobs(specs: dict[str, AgentSpec], tgt: TargetRun, dom: DomainSpec, metrics) -> list[Job]:
    return [Job(specs[e.agent], dom, tgt.map, e.episode, e.seed, tgt.seconds, pose=e.pose, metrics=metrics)
            for e in tgt.episodes]


def _recorded_runs(tgt: TargetRun) -> list[tuple[np.ndarray, np.ndarray, tuple, int, np.ndarray]]:
    """(t, pwm, start pose, seed, (n, 3) t x y) of each of the target's recorded runs, for trajectory matching."""
    from proxybench.tasks.trajectory import Trajectory

    out = []
    for e in tgt.episodes:
        path = tgt.files.get((e.agent, e.episode))
        if not path:
            continue
        tr = Trajectory.load(path)
        t = tr["t"]
        out.append((t, np.column_stack([tr["pwm_left"], tr["pwm_right"]]), e.pose, e.seed,
                    np.column_stack([t, tr["x"], tr["y"]])))
    return out


def run_target(k: int, target: Target, s: dict[str, Any], specs: list[AgentSpec], run_dir: Path,
               backend: Backend, progress: Progress | None = None) -> dict[str, Any]:
    """Run target ``k`` (its episodes, every candidate's replays, the trajectory replays) and score it."""
    rng = np.random.default_rng([s["seed"], k, 0x5B1])
    order = rng.permutation(len(specs))
    n_a = max(2, min(len(specs) - 2, round(len(specs) * s["tuning_share"])))
    tune, held = [specs[i] for i in sorted(order[:n_a])], [specs[i] for i in sorted(order[n_a:])]
    seed_t = s["seed"] * 1000 + k + 1
    e1 = list(range(s["episodes_tune"]))
    e2 = list(range(s["episodes_tune"], s["episodes_tune"] + s["episodes_eval"]))
    map_name = s["maps"][k % len(s["maps"])]
    metrics, size = tuple(s["metrics"]), tuple(s["image_size"])
    stage = (lambda name: (lambda _st, d, t: progress(f"target {k}: {name}", d, t))) if progress else (lambda _n: None)
    kw = {"map_name": map_name, "seconds": s["seconds"], "seed": seed_t, "metrics": metrics, "image_size": size,
          "run_dir": run_dir, "backend": backend}
    t_a = target.run(tune, episodes=e1, progress=stage("tuning agents on the target"), **kw)
    t_b = target.run(held, episodes=e2, progress=stage("held-out agents on the target"), **kw)
    by_label = {a.label: a for a in specs}
    cands = _candidates(s)
    jobs_a, jobs_b = [], []
    for c, theta in enumerate(cands):
        dom = DomainSpec(f"candidate {c}", proxy_params(size, **theta))
        jobs_a.append(_replay_jobs(by_label, t_a, dom, metrics))
        jobs_b.append(_replay_jobs(by_label, t_b, dom, metrics))
    flat = [j for js in (*jobs_a, *jobs_b) for j in js]
    sweep = run_jobs(flat, run_dir, backend,
                     progress=(lambda d, t, _r: progress(f"target {k}: candidates", d, t)) if progress else None)
    results = dict(zip((j.key for j in flat), sweep.results, strict=True))
    prox_a = [by_agent(js, [results[j.key] for j in js], metrics) for js in jobs_a]
    prox_b = [by_agent(js, [results[j.key] for j in js], metrics) for js in jobs_b]
    traj_err = _trajectory_errors(cands, t_a, s) if "trajectory" in s["methods"] else None
    record = score_target(s, k, cands, t_a.results, t_b.results, prox_a, prox_b, traj_err)
    record.update({"target": getattr(target, "name", f"target-{k}"), "map": map_name, "tuning_agents": [a.label for a
                   in tune], "heldout_agents": [a.label for a in held], "seed": seed_t,
                   "episodes_run": t_a.ran + t_b.ran + sweep.ran})
    return record


def _trajectory_errors(cands: list[dict[str, float]], t_a: TargetRun, s: dict[str, Any]) -> list[float]:
    """Per candidate: the mean distance [m] between the target's recorded tuning runs and their open-loop replays."""
    runs = _recorded_runs(t_a)
    if not runs:
        return [float("nan")] * len(cands)
    out = []
    for theta in cands:
        params = proxy_params(tuple(s["image_size"]), **theta)
        replays = replay_runs(t_a.map, params, [(t, pwm, pose, seed) for t, pwm, pose, seed, _ in runs], s["seconds"])
        out.append(float(np.nanmean([validation.trajectory_error(rep, r[4]) for rep, r in zip(replays, runs,
                                                                                               strict=True)])))
    return out


def score_target(s: dict[str, Any], k: int, cands: list[dict[str, float]], target_a, target_b, prox_a: list,
                 prox_b: list, traj_err: list[float] | None) -> dict[str, Any]:
    """Each method's pick from the tuning agents, and the quality of every candidate on the held-out agents."""
    higher = tuple(TASK_METRICS[m].higher_is_better for m in s["metrics"])
    qualities = [quality(p, target_b, higher, k=s["top_k"]).as_dict() for p in prox_b]
    nominal = proxy_params(tuple(s["image_size"]))
    nominal_index = next(c for c, theta in enumerate(cands)
                         if all(abs(theta[n] - float(getattr(nominal, n))) < 1e-9 for n in theta))
    tol = [s["tolerances"][m] for m in s["metrics"]]
    picks, scores = {}, {}
    for method in s["methods"]:
        if method == "nominal":
            values = np.array([0.0 if c == nominal_index else 1.0 for c in range(len(cands))])
        elif method == "trajectory":
            values = np.asarray(traj_err if traj_err is not None else [np.nan] * len(cands), float)
        else:
            values = selection_scores(method, prox_a, target_a, higher, tolerances=tol, n_boot=s["n_boot"],
                                      seed=s["seed"] + k)
        if not np.isfinite(values).any():
            continue
        index, ties = pick(np.where(np.isfinite(values), values, np.inf),
                           np.random.default_rng([s["seed"], k, METHODS.index(method)]))
        picks[method] = {"index": index, "ties": ties}
        scores[method] = [float(v) for v in values]
    return {"candidates": cands, "nominal_index": nominal_index, "quality": qualities, "picks": picks,
            "scores": scores}


def run_validate(cfg: ValidateConfig, out: str | Path, backend: Backend | None = None,
                 progress: Progress | None = None, *, quick: bool = False, finished_only: bool = False
                 ) -> ValidationRun:
    """Write the criteria, then run (or resume) every target; each finished target lands in ``out/targets/``.

    ``finished_only``: run nothing, gather the targets finished so far (an interim look at a long study; the
    criteria must exist and be for these settings, and are never rewritten)."""
    t0 = time.perf_counter()
    out = Path(out)
    s = settings_for(cfg, quick)
    if finished_only:
        _check_criteria(s, out)
    out.mkdir(parents=True, exist_ok=True)
    draw_seed = _draw_seed(cfg, out)
    criteria = write_criteria(s, draw_seed, out)
    specs: list[AgentSpec] = []
    if not finished_only:
        try:
            agents = [a.replace(PYTHON, shlex.quote(sys.executable)) for a in s["agents"]]
            specs = parse_agents([*agents, *train_bc_agents(s, out / "agents", progress)], out / "agents")
        except AgentArgError as exc:
            raise ConfigError(f"agents: {exc}") from None
    backend = backend or InlineBackend()
    targets = _family_targets(s, draw_seed, out)
    folder = out / "targets"
    folder.mkdir(exist_ok=True)
    key = hashlib.sha256(json.dumps(s, sort_keys=True).encode()).hexdigest()[:16]
    records, indices, ran = [], [], 0
    for k, target in enumerate(targets):
        path = folder / f"{k:03d}.json"
        try:
            rec = json.loads(path.read_text())
            if rec.get("settings_key") == key:
                records.append(rec)
                indices.append(k)
                continue
        except (OSError, ValueError):
            pass
        if finished_only:
            continue
        rec = run_target(k, target, s, specs, out / "runs", backend, progress)
        rec["settings_key"] = key
        path.write_text(json.dumps(rec, indent=1))
        records.append(rec)
        indices.append(k)
        ran += rec["episodes_run"]
        if progress:
            progress("targets", k + 1, len(targets))
    if finished_only and len(records) < 2:
        raise ConfigError(f"{out}: {len(records)} target(s) finished; an interim look needs at least 2")
    return ValidationRun(s, criteria, records, targets, ran, time.perf_counter() - t0, indices=indices)


def _check_criteria(s: dict[str, Any], out: Path) -> None:
    """An interim look reads a study that exists, with these settings (it must not start or redefine one)."""
    path = out / "criteria.json"
    try:
        written = json.loads(path.read_text()).get("settings")
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: no study to look at ({exc.__class__.__name__}); run it first") from None
    now, written = json.loads(json.dumps(s)), written or {}
    if written != now:
        diff = sorted(k for k in set(written) | set(now) if written.get(k) != now.get(k))
        raise ConfigError(f"{path}: the study was started with other settings ({', '.join(diff)} differ); give the "
                          "same options as when it was started")


# -- the summary -------------------------------------------------------------------------------------------------

QUALITIES = ("prpv_norm", "kendall_gap", "top1_regret", "topk_regret")


def regrets(rec: dict[str, Any], method: str, measure: str = "prpv_norm") -> float:
    """The regret of ``method``'s pick on one target: its quality minus the oracle's (the lowest in hindsight)."""
    if method not in rec["picks"]:
        return float("nan")
    values = np.array([q[measure] for q in rec["quality"]], float)
    return float(values[rec["picks"][method]["index"]] - np.nanmin(values))


def _oracle_steps(rec: dict[str, Any], index: int, grid: dict[str, list[float]]) -> int:
    """Grid steps (the largest along any axis) from candidate ``index`` to the nearest oracle candidate."""
    values = np.array([q["prpv_norm"] for q in rec["quality"]], float)
    oracles = np.flatnonzero(np.isclose(values, np.nanmin(values)))
    pos = {n: {round(v, 9): i for i, v in enumerate(vals)} for n, vals in grid.items()}

    def where(c: int) -> list[float]:
        theta = rec["candidates"][c]
        return [pos[n].get(round(theta[n], 9), np.searchsorted(vals, theta[n]) - 0.5) for n, vals in grid.items()]

    here = np.array(where(index), float)
    return int(min(np.max(np.abs(here - np.array(where(o), float))) for o in oracles))


def summarize(run: ValidationRun) -> dict[str, Any]:
    """summary.json: per method, the regrets over targets (primary and secondary), each paired against the nominal
    θ, hit rates beside the nominal pick's; the criteria's commit and scoring hash checked against this code."""
    from proxybench.experiments.reporting import source_commit
    from proxybench.usefulness.heldout_scoring import wilson
    from proxybench.usefulness.validation import compare

    s, recs = run.settings, run.records
    criteria = json.loads(run.criteria_file.read_text())
    methods = [m for m in s["methods"] if any(m in r["picks"] for r in recs)]
    out: dict[str, Any] = {"family": s["family"], "targets": len(recs), "targets_planned": s["targets"],
                           "interim": len(recs) < s["targets"], "settings": s, "methods": {},
                           "criteria": {"written": criteria["written"], "commit": criteria["commit"],
                                        "commit_now": source_commit(),
                                        "scoring_unchanged": criteria["scoring_sha256"] == scoring_hash(),
                                        "minimum_detectable_effect": criteria["minimum_detectable_effect"]}}
    nominal = {m: [regrets(r, "nominal", m) for r in recs] for m in QUALITIES}
    for method in methods:
        entry: dict[str, Any] = {}
        for measure in QUALITIES:
            rg = [regrets(r, method, measure) for r in recs]
            finite = np.asarray(rg, float)[np.isfinite(rg)]
            entry[measure] = {"mean_regret": float(finite.mean()) if finite.size else float("nan"),
                              "vs_nominal": compare(method, "nominal", rg, nominal[measure], seed=s["seed"]).as_dict()}
        hits = [_oracle_steps(r, r["picks"][method]["index"], s["grid"]) <= 1 for r in recs if method in r["picks"]]
        lo, hi = wilson(sum(hits), len(hits)) if hits else (float("nan"), float("nan"))
        entry["hit_rate"] = {"hits": int(sum(hits)), "targets": len(hits), "low": lo, "high": hi}
        entry["ties"] = float(np.mean([r["picks"][method]["ties"] for r in recs if method in r["picks"]]))
        out["methods"][method] = entry
    primary = out["methods"].get("prpv", {}).get("prpv_norm", {}).get("vs_nominal")
    if primary is not None:
        sd = primary["sd"]
        mde = criteria["minimum_detectable_effect"]["d_z"]
        if out["interim"]:  # what the targets finished so far can detect, not what the full study will
            mde = minimum_detectable_effect(len(recs), s["alpha"], s["power"])
        out["primary"] = {**primary, "alpha": s["alpha"], "rejected": bool(primary["p_wilcoxon"] < s["alpha"]),
                          "d_z": mde,
                          "minimum_detectable_difference": float(mde * sd) if np.isfinite(sd) else float("nan")}
    indices = run.indices or list(range(len(recs)))
    reveal = [getattr(run.targets[i], "reveal", dict)() for i in indices]
    out["truths"] = [{k: v for k, v in tr.items() if k in s["grid"] or k in s["draw"]} for tr in reveal]
    return out
