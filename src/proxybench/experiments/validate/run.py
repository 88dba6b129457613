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
from typing import Any

import numpy as np

from proxybench.experiments.agent_args import AgentArgError, parse_agents
from proxybench.experiments.config import ConfigError
from proxybench.experiments.proxies import proxy_params
from proxybench.experiments.validate.config import FAMILIES, PYTHON, ValidateConfig, ValidateSettings, settings_for
from proxybench.experiments.validate.measures import (
    QUALITIES,
    CriteriaCheck,
    HitRate,
    MeasureSummary,
    MethodSummary,
    Pick,
    Primary,
    Quality,
    TargetRecord,
    ValidationSummary,
    oracle_steps,
    regrets,
)
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
from proxybench.runner.replay import replay_runs
from proxybench.runner.sweep import run_jobs
from proxybench.targets.base import Target, TargetRun, by_agent
from proxybench.tasks.metrics import METRICS as TASK_METRICS
from proxybench.usefulness import validation
from proxybench.usefulness.validation import METHODS, minimum_detectable_effect, pick, quality, selection_scores

#: the files whose code scores the study (hashed into criteria.json)
SCORING_FILES = (validation.__file__,)

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


def write_criteria(s: ValidateSettings, draw_seed: int, out: Path) -> Path:
    """``criteria.json``: endpoints, test, minimum detectable effect, commit and scoring-code hash, the settings,
    and only a hash of the draw seed. Kept when a resumed study has the same settings."""
    from proxybench.experiments.reporting import source_commit

    path = out / "criteria.json"
    seed_hash = hashlib.sha256(str(draw_seed).encode()).hexdigest()
    try:
        old = json.loads(path.read_text())
        if old.get("settings") == s.model_dump(mode="json") and old.get("draw_seed_sha256") == seed_hash:
            return path
    except (OSError, ValueError):
        pass
    n = s.targets
    doc = {
        "written": time.strftime("%Y-%m-%d %H:%M:%S %z"), "commit": source_commit(), "scoring_sha256": scoring_hash(),
        "draw_seed_sha256": seed_hash, "settings": s.model_dump(mode="json"),
        "unit": "the target (each with its own episode seeds and tuning/held-out split of the agents)",
        "primary_endpoint": "regret of the picked θ on the held-out agents B over fresh target episodes E2: "
                            "PRPV/K(K−1) of the pick minus that of the oracle θ (the candidate lowest on it in "
                            "hindsight)",
        "secondary_endpoints": ["regret in 1 − Kendall τ_b (first metric)", "regret of picking the top agent (first "
                                "metric, its unit)", f"regret of picking the top {s.top_k}", "hit rate: the pick "
                                "within one grid step of the oracle, beside the nominal pick's"],
        "primary_comparison": "PRPV's regret minus the nominal θ's, per target",
        "test": f"one-sided Wilcoxon signed-rank test of the paired differences (H1: PRPV's regret is lower), "
                f"alpha {s.alpha}; a one-sided paired t-test and a percentile bootstrap interval of the mean "
                "difference beside it; every other method against the nominal θ the same way (secondary, no "
                "multiplicity correction: read them as descriptive)",
        "minimum_detectable_effect": {"d_z": minimum_detectable_effect(n, s.alpha, s.power), "targets": n,
                                      "power": s.power, "meaning": "mean paired difference in standard deviations "
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

    settings: ValidateSettings
    criteria_file: Path
    records: list[TargetRecord]
    targets: list[Any]
    episodes_run: int = 0
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    indices: list[int] = field(default_factory=list)  # the target index of each record (an interim look skips some)


@dataclass
class ValidationResult:
    """A run of the study and what it concludes (the report reads both)."""

    run: ValidationRun
    summary: ValidationSummary


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


def score_target(s: ValidateSettings, k: int, cands: list[dict[str, float]], target_a, target_b, prox_a: list,
                 prox_b: list, traj_err: list[float] | None) -> TargetRecord:
    """Each method's pick from the tuning agents, and the quality of every candidate on the held-out agents."""
    higher = tuple(TASK_METRICS[m].higher_is_better for m in s.metrics)
    qualities = [Quality(**quality(p, target_b, higher, k=s.top_k).as_dict()) for p in prox_b]
    nominal = proxy_params(tuple(s.image_size))
    nominal_index = next(c for c, theta in enumerate(cands)
                         if all(abs(theta[n] - float(getattr(nominal, n))) < 1e-9 for n in theta))
    tol = [s.tolerances[m] for m in s.metrics]
    picks, scores = {}, {}
    for method in s.methods:
        if method == "nominal":
            values = np.array([0.0 if c == nominal_index else 1.0 for c in range(len(cands))])
        elif method == "trajectory":
            values = np.asarray(traj_err if traj_err is not None else [np.nan] * len(cands), float)
        else:
            values = selection_scores(method, prox_a, target_a, higher, tolerances=tol, n_boot=s.n_boot,
                                      seed=s.seed + k)
        if not np.isfinite(values).any():
            continue
        index, ties = pick(np.where(np.isfinite(values), values, np.inf),
                           np.random.default_rng([s.seed, k, METHODS.index(method)]))
        picks[method] = Pick(index=index, ties=ties)
        scores[method] = [float(v) for v in values]
    return TargetRecord(candidates=cands, nominal_index=nominal_index, quality=qualities, picks=picks, scores=scores)


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
            agents = [a.replace(PYTHON, shlex.quote(sys.executable)) for a in s.agents]
            specs = parse_agents([*agents, *train_bc_agents(s, out / "agents", progress)], out / "agents")
        except AgentArgError as exc:
            raise ConfigError(f"agents: {exc}") from None
    backend = backend or InlineBackend()
    targets = _family_targets(s, draw_seed, out)
    folder = out / "targets"
    folder.mkdir(exist_ok=True)
    key = hashlib.sha256(json.dumps(s.model_dump(mode="json"), sort_keys=True).encode()).hexdigest()[:16]
    records, indices, ran = [], [], 0
    for k, target in enumerate(targets):
        path = folder / f"{k:03d}.json"
        try:
            rec = TargetRecord.model_validate_json(path.read_text())
            if rec.settings_key == key:
                records.append(rec)
                indices.append(k)
                continue
        except (OSError, ValueError):  # none yet, or another version's: run it (again)
            pass
        if finished_only:
            continue
        rec = run_target(k, target, s, specs, out / "runs", backend, progress).model_copy(update={"settings_key": key})
        path.write_text(json.dumps(rec.model_dump(), indent=1))
        records.append(rec)
        indices.append(k)
        ran += rec.episodes_run
        if progress:
            progress("targets", k + 1, len(targets))
    if finished_only and len(records) < 2:
        raise ConfigError(f"{out}: {len(records)} target(s) finished; an interim look needs at least 2")
    return ValidationRun(s, criteria, records, targets, ran, time.perf_counter() - t0, indices=indices)


def _check_criteria(s: ValidateSettings, out: Path) -> None:
    """An interim look reads a study that exists, with these settings (it must not start or redefine one)."""
    path = out / "criteria.json"
    try:
        written = json.loads(path.read_text()).get("settings")
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: no study to look at ({exc.__class__.__name__}); run it first") from None
    now, written = s.model_dump(mode="json"), written or {}
    if written != now:
        diff = sorted(k for k in set(written) | set(now) if written.get(k) != now.get(k))
        raise ConfigError(f"{path}: the study was started with other settings ({', '.join(diff)} differ); give the "
                          "same options as when it was started")


# -- the summary -------------------------------------------------------------------------------------------------

def summarize(run: ValidationRun, criteria: dict[str, Any] | None = None) -> ValidationSummary:
    """summary.json: per method, the regrets over targets (primary and secondary), each paired against the nominal
    θ, hit rates beside the nominal pick's; the criteria (``run.criteria_file``'s unless given) with their commit
    and scoring hash checked against this code."""
    from proxybench.experiments.reporting import source_commit
    from proxybench.usefulness.heldout_scoring import wilson
    from proxybench.usefulness.validation import compare

    s, recs = run.settings, run.records
    criteria = criteria if criteria is not None else json.loads(run.criteria_file.read_text())
    check = CriteriaCheck(written=criteria["written"], commit=criteria["commit"], commit_now=source_commit(),
                          scoring_unchanged=criteria["scoring_sha256"] == scoring_hash(),
                          minimum_detectable_effect=criteria["minimum_detectable_effect"])
    methods = [m for m in s.methods if any(m in r.picks for r in recs)]
    nominal = {m: [regrets(r, "nominal", m) for r in recs] for m in QUALITIES}
    out: dict[str, MethodSummary] = {}
    for method in methods:
        measures = {}
        for measure in QUALITIES:
            rg = [regrets(r, method, measure) for r in recs]
            finite = np.asarray(rg, float)[np.isfinite(rg)]
            measures[measure] = MeasureSummary(
                mean_regret=float(finite.mean()) if finite.size else float("nan"),
                vs_nominal=compare(method, "nominal", rg, nominal[measure], seed=s.seed))
        hits = [oracle_steps(r, r.picks[method].index, s.grid) <= 1 for r in recs if method in r.picks]
        lo, hi = wilson(sum(hits), len(hits)) if hits else (float("nan"), float("nan"))
        out[method] = MethodSummary(**measures, hit_rate=HitRate(hits=int(sum(hits)), targets=len(hits), low=lo,
                                                                 high=hi),
                                    ties=float(np.mean([r.picks[method].ties for r in recs if method in r.picks])))
    interim = len(recs) < s.targets
    primary = None
    if "prpv" in out:
        first = out["prpv"].prpv_norm.vs_nominal
        mde = check.d_z
        if interim:  # what the targets finished so far can detect, not what the full study will
            mde = minimum_detectable_effect(len(recs), s.alpha, s.power)
        primary = Primary(**first.as_dict(), alpha=s.alpha, rejected=bool(first.p_wilcoxon < s.alpha), d_z=mde,
                          minimum_detectable_difference=float(mde * first.sd) if np.isfinite(first.sd)
                          else float("nan"))
    indices = run.indices or list(range(len(recs)))
    reveal = [getattr(run.targets[i], "reveal", dict)() for i in indices]
    truths = [{k: v for k, v in tr.items() if k in s.grid or k in s.draw} for tr in reveal]
    return ValidationSummary(settings=s, targets=len(recs), interim=interim, methods=out, criteria=check,
                             primary=primary, truths=truths, wall_s=run.wall_s)
