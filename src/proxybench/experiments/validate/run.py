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
from proxybench.experiments.validate.config import FAMILIES, PYTHON, ValidateConfig, ValidateSettings, settings_for
from proxybench.experiments.validate.measures import QUALITIES, TargetRecord, ValidationSummary, regrets
from proxybench.experiments.validate.scoring import ValidationRun, score_target, summarize
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


#: data and training of the study's behaviour-cloned agents: different amounts, so that their quality differs
_BC_SAMPLES = (1500, 6000, 3000, 12000)


def train_bc_agents(s: ValidateSettings, folder: Path, progress: Progress | None = None) -> list[str]:
    """Checkpoints of ``bc_agents`` networks cloned from the expert in the nominal proxy, from the study's seed
    (trained once; a resumed study reuses them). Needs PyTorch (the ``learning`` extra)."""
    if not s.bc_agents:
        return []
    try:
        import torch  # noqa: F401
    except ImportError:
        raise ConfigError("bc_agents: training behaviour-cloned agents needs PyTorch (pip install "
                          "'proxybench[learning]'); or set bc_agents: 0") from None
    from proxybench.learning import ModelConfig, TrainConfig, build_model, proxy_domain, save_checkpoint, train
    from proxybench.learning.collection import CollectConfig, collect

    paths = []
    for i in range(s.bc_agents):
        path = folder / f"bc-{s.seed}-{i}.pt"
        if not (path.exists() and path.with_suffix(".json").exists()):
            n = _BC_SAMPLES[i % len(_BC_SAMPLES)]
            data = collect(proxy_domain(80, 60), CollectConfig(samples=n, robots=16, seed=s.seed * 100 + i),
                           progress=(lambda d, t, i=i: progress(f"BC agent {i}: data", d, t)) if progress else None)
            model = build_model(ModelConfig(), seed=s.seed * 100 + i)
            train(model, data, TrainConfig(epochs=8.0, max_steps=800, seed=s.seed * 100 + i))
            save_checkpoint(path, model, {"samples": n, "study_seed": s.seed, "index": i})
        paths.append(str(path))
    return paths


def _family_targets(s: ValidateSettings, draw_seed: int, out: Path) -> list[Any]:
    """The family's targets, black boxes until reveal (their θ drawn from ``draw_seed``)."""
    ranges = dict(s.draw)
    if s.family == "gym":
        from proxybench.gym.environment import check_environment
        from proxybench.targets.gym import gym_targets

        env = check_environment(render=False)
        if env.problems:
            raise ConfigError("family gym: gym-duckietown's environment is not ready: " + "; ".join(env.problems))
        return gym_targets(s.targets, draw_seed, ranges, out / "secret" / "gym", nodes=s.robot_nodes)
    from proxybench.targets.heldout import heldout_targets

    return heldout_targets(s.targets, draw_seed, ranges)


def _candidates(s: ValidateSettings) -> list[dict[str, float]]:
    """Every grid point, then the nominal calibration if the grid does not hold it."""
    names = list(s.grid)
    points = [dict(zip(names, values, strict=True)) for values in itertools.product(*s.grid.values())]
    nominal = proxy_params(tuple(s.image_size))
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


def run_target(k: int, target: Target, s: ValidateSettings, specs: list[AgentSpec], run_dir: Path,
               backend: Backend, progress: Progress | None = None) -> TargetRecord:
    """Run target ``k`` (its episodes, every candidate's replays, the trajectory replays) and score it."""
    rng = np.random.default_rng([s.seed, k, 0x5B1])
    order = rng.permutation(len(specs))
    n_a = max(2, min(len(specs) - 2, round(len(specs) * s.tuning_share)))
    tune, held = [specs[i] for i in sorted(order[:n_a])], [specs[i] for i in sorted(order[n_a:])]
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
    traj_err = _trajectory_errors(cands, t_a, s) if "trajectory" in s.methods else None
    record = score_target(s, k, cands, t_a.results, t_b.results, prox_a, prox_b, traj_err)
    return record.model_copy(update={
        "target": getattr(target, "name", f"target-{k}"), "map": map_name, "tuning_agents": [a.label for a in tune],
        "heldout_agents": [a.label for a in held], "seed": seed_t, "episodes_run": t_a.ran + t_b.ran + sweep.ran})


def _trajectory_errors(cands: list[dict[str, float]], t_a: TargetRun, s: ValidateSettings) -> list[float]:
    """Per candidate: the mean distance [m] between the target's recorded tuning runs and their open-loop replays."""
    runs = _recorded_runs(t_a)
    if not runs:
        return [float("nan")] * len(cands)
    out = []
    for theta in cands:
        params = proxy_params(tuple(s.image_size), **theta)
        replays = replay_runs(t_a.map, params, [(t, pwm, pose, seed) for t, pwm, pose, seed, _ in runs], s.seconds)
        out.append(float(np.nanmean([validation.trajectory_error(rep, r[4]) for rep, r in zip(replays, runs,
                                                                                               strict=True)])))
    return out


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
    s = settings_for(cfg, quick)
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
