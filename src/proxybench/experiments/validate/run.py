"""`proxybench validate`: does tuning a simulator help, on agents and target episodes it was not tuned on?

The study the thesis' central claim needs (docs/validate.md). For each of many targets — drawn from a
*family* (held-out structural stand-ins, or another simulator), their θ drawn at run time from a seed whose
hash alone is written down until the reveal, wider than the proxies' search space and off-centre, so that
keeping the nominal calibration is a real competitor that can lose:

1. the agent pool is split at random into a tuning set A and a disjoint held-out set B;
2. the target runs A on episodes E1 and B on fresh episodes E2 (its own seeds per target);
3. every candidate θ (a grid over the search space, and the nominal calibration) replays all of them;
4. each method (:data:`~proxybench.usefulness.validation.METHODS`: PRPV, ε-PRPV, probabilistic PRPV, PPV,
   Pearson, Spearman, Kendall, MMRV, trajectory matching, and the nominal θ) picks θ from A on E1; two pick a
   continuous θ instead: ``trajectory_fit`` (trajectory matching over continuous θ, from the best grid
   candidate) and ``calibration`` (scripted drives on the target, no simulator: trim and command delay);
5. the pick is judged on B on E2 (:func:`~proxybench.usefulness.validation.quality`; a continuous pick is
   replayed like a candidate): the primary comparison is PRPV's quality against the calibrations', per stratum
   (near and far, from the hidden θ), against a margin; the regret against the oracle θ (the best grid
   candidate for B on E2 in hindsight) is paired against the nominal θ's as before.

``criteria.json`` — the endpoints, the test, the minimum detectable effect, the commit and a hash of the
scoring code — is written before the first episode and never rewritten; every finished target and every look
goes into the hash-chained ``looks.jsonl``, and the report checks both, and the code it scores with
(:mod:`~proxybench.experiments.validate.registration`). Every episode goes through the runner's cache, and each
finished target is written to ``targets/``, so an interrupted study resumes. The scoring itself is
:mod:`~proxybench.experiments.validate.scoring`.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.experiments.agent_args import AgentArgError, parse_agents
from proxybench.experiments.config import ConfigError
from proxybench.experiments.proxies import proxy_params
from proxybench.experiments.validate import registration
from proxybench.experiments.validate.config import (
    FAMILIES,
    PYTHON,
    ValidateConfig,
    ValidateSettings,
    nominal_theta,
    settings_for,
    stratum_of,
)
from proxybench.experiments.validate.measures import (
    QUALITIES,
    ContinuousPick,
    TargetRecord,
    ValidationSummary,
    regrets,
)
from proxybench.experiments.validate.scoring import ValidationRun, calibrated_theta, score_target, summarize
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
from proxybench.runner.replay import replay_runs
from proxybench.runner.sweep import run_jobs
from proxybench.targets.base import Target, TargetRun, by_agent
from proxybench.usefulness import validation

__all__ = [
    "FAMILIES",
    "QUALITIES",
    "ValidateConfig",
    "ValidationResult",
    "ValidationRun",
    "regrets",
    "run_validate",
    "settings_for",
    "summarize",
]

Progress = Callable[[str, int, int], None]

# -- running ------------------------------------------------------------------------------------------------------

@dataclass
class ValidationResult:
    """A run of the study and what it concludes (the report reads both)."""

    run: ValidationRun
    summary: ValidationSummary
    look_sha256: str = ""  # the look's line in looks.jsonl


@dataclass(frozen=True)
class BCRecipe:
    """How one behaviour-cloned agent of the pool is trained: where its data comes from and how much of it.

    ``where``: ``nominal`` (the expert in the nominal proxy), ``other`` (a proxy at ``changes``: a network that
    learnt in another θ), ``randomized`` (the domain-randomised family), ``dagger`` (nominal, then DAgger rounds
    with ``on_policy`` frames the network drove itself) or ``gym`` (another simulator: gym-duckietown at its own
    defaults behind the robot protocol, never at a target's θ; needs ``proxybench gym setup``). Networks that
    learnt elsewhere than where they are judged make held-out agents less like the tuning ones."""

    where: str
    samples: int
    changes: tuple[tuple[str, float], ...] = ()
    on_policy: int = 0


#: the study's behaviour-cloned agents, the i-th by recipe i (cycling): the first two as every earlier study had them
#: (the nominal proxy, 1,500 and 6,000 frames), then a network trained at camera pitch 25° with trim 0.1, one in the
#: domain-randomised family, one with two DAgger rounds, one in gym-duckietown (the gym family trains six), and
#: the nominal proxy with 3,000 and 12,000 frames
BC_RECIPES = (BCRecipe("nominal", 1500), BCRecipe("nominal", 6000),
              BCRecipe("other", 3000, changes=(("camera_pitch", 25.0), ("trim", 0.1))),
              BCRecipe("randomized", 6000), BCRecipe("dagger", 3000, on_policy=1500), BCRecipe("gym", 3000),
              BCRecipe("nominal", 3000), BCRecipe("nominal", 12000),
              BCRecipe("other", 3000, changes=(("camera_pitch", 13.0), ("command_delay", 0.1))))


def train_bc_agents(s: ValidateSettings, folder: Path, progress: Progress | None = None) -> list[str]:
    """Checkpoints of ``bc_agents`` networks cloned from the expert, the i-th by :data:`BC_RECIPES` [i], from the
    study's seed (trained once; a resumed study reuses them). Needs PyTorch (the ``learning`` extra)."""
    if not s.bc_agents:
        return []
    try:
        import torch  # noqa: F401
    except ImportError:
        raise ConfigError("bc_agents: training behaviour-cloned agents needs PyTorch (pip install "
                          "'proxybench[learning]'); or set bc_agents: 0") from None
    from proxybench.learning import save_checkpoint

    _check_gym_recipes(s.bc_agents)
    paths = []
    for i in range(s.bc_agents):
        path = folder / f"bc-{s.seed}-{i}.pt"
        recipe = BC_RECIPES[i % len(BC_RECIPES)]
        if not (path.exists() and path.with_suffix(".json").exists()):
            seed = s.seed * 100 + i
            say = (lambda what, i=i: (lambda d, t: progress(f"BC agent {i}: {what}", d, t))) if progress else (
                lambda what: None)
            model = _train_bc(recipe, seed, say)
            save_checkpoint(path, model, {"samples": recipe.samples, "study_seed": s.seed, "index": i,
                                          "where": recipe.where, "changes": dict(recipe.changes),
                                          "on_policy": recipe.on_policy})
        paths.append(str(path))
    return paths


def _check_gym_recipes(n: int) -> None:
    """A recipe that trains in gym-duckietown needs its environment: a one-line error before anything trains."""
    if not any(BC_RECIPES[i % len(BC_RECIPES)].where == "gym" for i in range(n)):
        return
    from proxybench.gym.environment import check_environment

    problems = check_environment(render=False).problems
    if problems:
        first = next(i for i in range(n) if BC_RECIPES[i % len(BC_RECIPES)].where == "gym")
        raise ConfigError(f"bc_agents: network {first} trains in gym-duckietown, whose environment is not ready "
                          f"({problems[0]}); or set bc_agents to {first} or fewer")


def _train_bc(recipe: BCRecipe, seed: int, say: Callable[[str], Any]):
    """One network by ``recipe`` (80×60 images, 16 robots collecting, 8 epochs / 800 steps as before)."""
    from proxybench.learning import (
        ModelConfig,
        TrainConfig,
        build_model,
        proxy_domain,
        randomized_domain,
        robot_domain,
        train,
    )
    from proxybench.learning.collection import CollectConfig, collect

    domain = {"randomized": lambda: randomized_domain(80, 60),
              "other": lambda: proxy_domain(80, 60, **dict(recipe.changes)),
              "gym": lambda: robot_domain(f"{shlex.quote(sys.executable)} -m proxybench gym serve", 80, 60)
              }.get(recipe.where, lambda: proxy_domain(80, 60))()
    collect_cfg = CollectConfig(samples=recipe.samples, robots=16, seed=seed)
    train_cfg = TrainConfig(epochs=8.0, max_steps=800, seed=seed)
    data = collect(domain, collect_cfg, progress=say("data"))
    model = build_model(ModelConfig(), seed=seed)
    train(model, data, train_cfg)
    if recipe.where == "dagger":
        from proxybench.experiments.plv.dagger import dagger

        dagger(model, domain, data, recipe.on_policy, collect_cfg, train_cfg, progress=say("DAgger"))
    return model


def _family_targets(s: ValidateSettings, draw_seed: int, out: Path) -> list[Any]:
    """The family's targets, black boxes until reveal (their θ drawn from ``draw_seed``)."""
    ranges = dict(s.draw)
    indices = stratified_draws(s, draw_seed)
    if s.family == "gym":
        from proxybench.gym.environment import check_environment
        from proxybench.targets.gym import gym_targets

        env = check_environment(render=False)
        if env.problems:
            raise ConfigError("family gym: gym-duckietown's environment is not ready: " + "; ".join(env.problems))
        return gym_targets(s.targets, draw_seed, ranges, out / "secret" / "gym", nodes=s.robot_nodes,
                           indices=indices)
    from proxybench.targets.heldout import heldout_targets

    return heldout_targets(s.targets, draw_seed, ranges, indices)


#: draws tried at most to fill the strata (a stratum the draw reaches with probability p needs about N / p)
MAX_DRAWS = 100_000


def drawn_theta(s: ValidateSettings, draw_seed: int, index: int) -> dict[str, float]:
    """θ of draw ``index`` under proxybench's names, as the target's reveal will state it (for its stratum)."""
    if s.family == "gym":
        from proxybench.targets.gym import draw_gym

        return s.to_proxy(draw_gym(draw_seed, index, dict(s.draw)))
    from proxybench.targets.heldout import HeldOutTarget

    return HeldOutTarget(draw_seed, index, dict(s.draw)).reveal()


def stratified_draws(s: ValidateSettings, draw_seed: int) -> list[int] | None:
    """With strata allocated by design (``per_stratum``): the draws kept, in draw order, until every stratum has
    its targets (a draw whose stratum is full is skipped), then shuffled by the secret seed so that a target's place
    says nothing of its stratum. None: the first ``targets`` draws, strata as they fall."""
    quota = {name: st.allocated for name, st in s.primary.strata.items()}
    if any(q is None for q in quota.values()):
        return None
    kept: list[int] = []
    taken = dict.fromkeys(quota, 0)
    for i in range(MAX_DRAWS):
        stratum = stratum_of(drawn_theta(s, draw_seed, i), s.near)
        if taken[stratum] < (quota[stratum] or 0):
            taken[stratum] += 1
            kept.append(i)
            if len(kept) == s.targets:
                order = np.random.default_rng([draw_seed, 0x57A7]).permutation(len(kept))
                return [kept[j] for j in order]
    short = ", ".join(f"{n} {taken[n]} of {q}" for n, q in quota.items())
    raise ConfigError(f"per_stratum: {MAX_DRAWS:,} draws did not fill the strata ({short}); widen --draw")


def _candidates(s: ValidateSettings) -> list[dict[str, float]]:
    """Every grid point (the nominal θ is the grid's centre: settings_for sees to it)."""
    names = list(s.grid)
    return [dict(zip(names, map(float, values), strict=True)) for values in itertools.product(*s.grid.values())]


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


#: the calibration drives (zoo agents, :mod:`proxybench.agents.calibration`): episodes of each and their length
_DRIVES = ("calib-straight", "calib-step")
_DRIVE_EPISODES = 2
_DRIVE_SECONDS = 6.0
#: the trajectory fit's budget: evaluations of the mean trajectory error (each replays every tuning run)
_FIT_EVALUATIONS = 40


def _calibration(target: Target, s: ValidateSettings, kw: dict[str, Any], stage) -> tuple[ContinuousPick, int]:
    """Run the calibration drives on the target (target episodes: counted) and estimate θ from them; (the pick or
    why there is none, episodes run)."""
    from proxybench.agents.calibration import STEP_TIME
    from proxybench.tasks.trajectory import Trajectory
    from proxybench.usefulness.calibration import curvature_per_trim

    fixed = getattr(target, "fixed_agents", None)
    if fixed is not None and not set(_DRIVES) <= set(fixed):
        return calibrated_theta(s, [], [], per_trim=1.0, step_time=STEP_TIME,
                                reason="the target is a recording: it cannot drive the calibration drives"), 0
    run = target.run([AgentSpec(a) for a in _DRIVES], episodes=list(range(_DRIVE_EPISODES)),
                     progress=stage("calibration drives on the target"), **{**kw, "seconds": _DRIVE_SECONDS})
    tracks: dict[str, list[tuple[np.ndarray, ...]]] = {a: [] for a in _DRIVES}
    for (agent, _e), path in sorted(run.files.items()):
        tr = Trajectory.load(path)
        tracks[agent].append((tr["t"], tr["x"], tr["y"], tr["theta"]))
    nominal = proxy_params(tuple(s.image_size))  # the robot model a lab knows: the DB18's
    per_trim = curvature_per_trim(kinematic=nominal.dynamics == "kinematic", wheel_distance=nominal.wheel_distance,
                                  v_decay=nominal.v_decay, v_gain=nominal.v_gain, w_decay=nominal.w_decay,
                                  w_gain=nominal.w_gain)
    pick = calibrated_theta(s, tracks["calib-straight"], [r[:3] for r in tracks["calib-step"]], per_trim=per_trim,
                            step_time=STEP_TIME)
    return pick, run.ran


#: parameters that change an open-loop replay (no camera): trajectory matching can identify only these
_MOTION = {"trim", "gain", "command_delay", "v_decay", "v_gain", "w_decay", "w_gain", "kinematic_max_speed",
           "wheel_distance", "wheel_radius", "motor_deadband", "motor_saturation", "slip_speed", "slip_turn",
           "motor_gamma_left", "motor_gamma_right", "delay_jitter"}


def _trajectory_fit(grid: list[dict[str, float]], traj_err: list[float], t_a: TargetRun,
                    s: ValidateSettings) -> ContinuousPick:
    """Trajectory matching over continuous θ: from the grid candidate with the lowest trajectory error, bounded
    Powell over the grid's motion parameters within their draw range (:data:`_FIT_EVALUATIONS` evaluations of the
    mean trajectory error over the tuning runs' open-loop replays); the others (a camera) stay nominal, as no
    replay without a camera can see them."""
    from scipy.optimize import minimize

    runs = _recorded_runs(t_a)
    err = np.asarray(traj_err, float)
    if not runs or not np.isfinite(err).any():
        return ContinuousPick(theta=None, reason="the target's runs carry no pose: no trajectory to match")
    start = grid[int(np.nanargmin(err))]
    theta = {**start, **{n: v for n, v in nominal_theta(s.grid).items() if n not in _MOTION}}
    free = [n for n in s.grid if n in _MOTION]
    if not free:
        return ContinuousPick(theta=theta, score=float(np.nanmin(err)))
    draw = s.proxy_draw()
    bounds = [(min(draw.get(n, s.grid[n])), max(draw.get(n, s.grid[n]))) for n in free]
    scale = np.array([hi - lo for lo, hi in bounds])
    lows = np.array([lo for lo, _ in bounds])

    def error(z: np.ndarray) -> float:  # z: the free parameters scaled to [0, 1] over their bounds
        values = lows + np.clip(z, 0.0, 1.0) * scale
        return _mean_error({**theta, **dict(zip(free, map(float, values), strict=True))}, runs, t_a.map, s)

    z0 = np.clip((np.array([theta[n] for n in free]) - lows) / scale, 0.0, 1.0)  # a grid end may lie outside the draw
    best = minimize(error, z0, method="Powell", bounds=[(0.0, 1.0)] * len(free),
                    options={"maxfev": _FIT_EVALUATIONS, "xtol": 1e-3, "ftol": 1e-4})
    z, value = (best.x, float(best.fun)) if best.fun <= np.nanmin(err) else (z0, float(np.nanmin(err)))
    values = lows + np.clip(z, 0.0, 1.0) * scale
    return ContinuousPick(theta={**theta, **{n: round(float(v), 6) for n, v in zip(free, values, strict=True)}},
                          score=value)


def _mean_error(theta: dict[str, float], runs, map_name: str, s: ValidateSettings) -> float:
    """The mean distance [m] between the recorded runs and their open-loop replays under θ."""
    params = proxy_params(tuple(s.image_size), **theta)
    replays = replay_runs(map_name, params, [(t, pwm, pose, seed) for t, pwm, pose, seed, _ in runs], s.seconds)
    return float(np.nanmean([validation.trajectory_error(rep, r[4]) for rep, r in zip(replays, runs, strict=True)]))


def split_agents(k: int, specs: list[AgentSpec], s: ValidateSettings) -> tuple[list[AgentSpec], list[AgentSpec]]:
    """Target ``k``'s tuning agents A and held-out agents B (seeded per target). ``family``: a random split of the
    pool's families (agents/families.py), tuning on one side on even targets and on the other on odd ones, so no
    held-out agent is a variant of a tuning one; ``random``: ``tuning_share`` of the agents at random."""
    rng = np.random.default_rng([s.seed, k, 0x5B1])
    if s.split == "family":
        from proxybench.agents.families import family_map
        from proxybench.usefulness.agent_resampling import family_splits

        by_label = {a.label: a for a in specs}
        families = family_map(list(by_label))
        for _ in range(50):  # a split whose sides both hold two agents (a quality needs two of each)
            first, second = family_splits(families, rng)[k % 2]
            if len(first) >= 2 and len(second) >= 2:
                return [by_label[a] for a in first], [by_label[a] for a in second]
        raise ConfigError(f"split: the pool's families ({', '.join(sorted(set(families.values())))}) cannot be split "
                          "into two sides of two agents or more; add agents of other families or use split: random")
    order = rng.permutation(len(specs))
    n_a = max(2, min(len(specs) - 2, round(len(specs) * s.tuning_share)))
    return [specs[i] for i in sorted(order[:n_a])], [specs[i] for i in sorted(order[n_a:])]


def run_target(k: int, target: Target, s: ValidateSettings, specs: list[AgentSpec], run_dir: Path,
               backend: Backend, progress: Progress | None = None) -> TargetRecord:
    """Run target ``k``: its episodes (the tuning agents on E1, the held-out agents on E2, the calibration drives),
    the methods' continuous picks, every candidate's replays (the grid: both halves; a continuous pick: the
    held-out half), and score it."""
    tune, held = split_agents(k, specs, s)
    seed_t = s.seed * 1000 + k + 1
    e1 = list(range(s.episodes_tune))
    e2 = list(range(s.episodes_tune, s.episodes_tune + s.episodes_eval))
    map_name = s.maps[k % len(s.maps)]
    metrics, size = tuple(s.metrics), tuple(s.image_size)
    stage = (lambda name: (lambda _st, d, t: progress(f"target {k}: {name}", d, t))) if progress else (lambda _n: None)
    kw = {"map_name": map_name, "seconds": s.seconds, "seed": seed_t, "metrics": metrics, "image_size": size,
          "run_dir": run_dir, "backend": backend}
    t_a = target.run(tune, episodes=e1, progress=stage("tuning agents on the target"), **kw)
    t_b = target.run(held, episodes=e2, progress=stage("held-out agents on the target"), **kw)
    grid = _candidates(s)
    # the methods that pick a θ of their own
    continuous: dict[str, ContinuousPick] = {}
    drives_ran = 0
    if "calibration" in s.methods:
        continuous["calibration"], drives_ran = _calibration(target, s, kw, stage)
    wants_traj = "trajectory" in s.methods or "trajectory_fit" in s.methods
    traj_err = _trajectory_errors(grid, t_a, s) if wants_traj else None
    if "trajectory_fit" in s.methods and traj_err is not None:
        continuous["trajectory_fit"] = _trajectory_fit(grid, traj_err, t_a, s)
    extra = []
    for c in continuous.values():
        if c.theta is not None and c.theta not in grid and c.theta not in extra:
            extra.append(c.theta)
    cands = [*grid, *extra]
    # every candidate replays the held-out runs; the grid's also the tuning runs (the grid methods pick from them)
    by_label = {a.label: a for a in specs}
    jobs_a, jobs_b = [], []
    for c, theta in enumerate(cands):
        dom = DomainSpec(f"candidate {c}", proxy_params(size, **theta))
        if c < len(grid):
            jobs_a.append(_replay_jobs(by_label, t_a, dom, metrics))
        jobs_b.append(_replay_jobs(by_label, t_b, dom, metrics))
    flat = [j for js in (*jobs_a, *jobs_b) for j in js]
    sweep = run_jobs(flat, run_dir, backend,
                     progress=(lambda d, t, _r: progress(f"target {k}: candidates", d, t)) if progress else None)
    results = dict(zip((j.key for j in flat), sweep.results, strict=True))
    prox_a = [by_agent(js, [results[j.key] for j in js], metrics) for js in jobs_a]
    prox_b = [by_agent(js, [results[j.key] for j in js], metrics) for js in jobs_b]
    record = score_target(s, k, cands, t_a.results, t_b.results, prox_a, prox_b, traj_err, continuous)
    return record.model_copy(update={
        "target": getattr(target, "name", f"target-{k}"), "map": map_name, "tuning_agents": [a.label for a in tune],
        "heldout_agents": [a.label for a in held], "seed": seed_t,
        "episodes_run": t_a.ran + t_b.ran + drives_ran + sweep.ran})


def _trajectory_errors(cands: list[dict[str, float]], t_a: TargetRun, s: ValidateSettings) -> list[float]:
    """Per candidate: the mean distance [m] between the target's recorded tuning runs and their open-loop replays."""
    runs = _recorded_runs(t_a)
    if not runs:
        return [float("nan")] * len(cands)
    return [_mean_error(theta, runs, t_a.map, s) for theta in cands]


def run_validate(cfg: ValidateConfig, out: str | Path, backend: Backend | None = None,
                 progress: Progress | None = None, *, quick: bool = False, finished_only: bool = False
                 ) -> ValidationRun:
    """Register the study (or resume it: same settings, its secret there), then run every target not finished;
    each finished target lands in ``out/targets/`` and is logged in ``looks.jsonl``. The pre-registration's
    checks end up in the run's ``problems``.

    ``finished_only``: run nothing, gather the targets finished so far (an interim look at a long study; the
    criteria must exist and be for these settings)."""
    t0 = time.perf_counter()
    out = Path(out)
    s = registration.registered_rule(cfg, settings_for(cfg, quick), out)
    criteria, draw_seed, notes = registration.open_study(cfg, s, out, interim=finished_only)
    specs: list[AgentSpec] = []
    if not finished_only:
        try:
            agents = [a.replace(PYTHON, shlex.quote(sys.executable)) for a in s.agents]
            specs = parse_agents([*agents, *train_bc_agents(s, out / "agents", progress)], out / "agents")
        except AgentArgError as exc:
            raise ConfigError(f"agents: {exc}") from None
    backend = backend or InlineBackend()
    targets = _family_targets(s, draw_seed, out)
    folder = out / "targets"
    folder.mkdir(exist_ok=True)
    key = hashlib.sha256(json.dumps(s.model_dump(mode="json"), sort_keys=True).encode()).hexdigest()[:16]
    logged = registration.logged_records(registration.read_looks(out)[0])
    records, indices, used, problems, ran = [], [], {}, [], 0
    if progress and not finished_only:  # the clock of the targets' ETA starts now, not when the first one is done
        progress("targets", sum(1 for k in logged if k < len(targets)), len(targets))
    for k, target in enumerate(targets):
        path = folder / f"{k:03d}.json"
        try:
            data = path.read_bytes()
            rec = TargetRecord.model_validate_json(data)
        except (OSError, ValueError):  # none yet, or damaged: run it (again)
            rec = None
        if rec is not None and rec.settings_key == key:
            if logged.get(k) == hashlib.sha256(data).hexdigest():
                records.append(rec)
                indices.append(k)
                used[k] = data
                continue
            # not the record the log holds: edited after it was scored (a problem), or not logged (yet: a look taken
            # while the study runs may read a record before its line); never trusted
            if k in logged:
                problems.append(f"{path.relative_to(out)} is not the record looks.jsonl holds for target {k} (edited "
                                f"after it was scored): {'left out of this look' if finished_only else 'scored again'}")
        if finished_only:
            continue
        rec = run_target(k, target, s, specs, out / "runs", backend, progress).model_copy(update={"settings_key": key})
        data = json.dumps(rec.model_dump(), indent=1).encode()
        path.write_bytes(data)
        registration.record_target(out, k, data, len(records) + 1)
        records.append(rec)
        indices.append(k)
        used[k] = data
        ran += rec.episodes_run
        if progress:
            progress("targets", k + 1, len(targets))
    if finished_only and len(records) < 2:
        raise ConfigError(f"{out}: {len(records)} target(s) finished; an interim look needs at least 2")
    found, unchanged = registration.check_registration(out, s, criteria, used)
    return ValidationRun(s, out / registration.CRITERIA, records, targets, ran, time.perf_counter() - t0,
                         notes=notes, indices=indices, problems=[*problems, *found], scoring_unchanged=unchanged)
