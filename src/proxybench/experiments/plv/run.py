"""The PLV experiment (thesis §3.7.2, Table 3.1, Figure 3.6) as an importable function.

1. **Target-only learning curve.** The expert drives the target (the reality model: a *simulated*
   stand-in for a real Duckiebot) with noise injection; a network is trained from scratch on n of
   those samples for every n of a ladder and every training seed, and scored by the lane score on
   evaluation episodes in the target. The score at the largest n is the converged score; the reference
   P is that score less a tolerance, and |D_target| is the smallest n from which the mean score over
   seeds *stays* at or above P (:func:`proxybench.usefulness.plv.settled_rung`).
2. **Each proxy.** The expert drives the proxy (an instance θ or a randomised family) for
   ``proxy_samples`` frames; one network per seed is pre-trained on them (zero-shot score: that network
   in the target, rung 0), then fine-tuned on n target samples up the same ladder until the mean over
   seeds has stayed at or above P for ``confirm`` rungs after the first that reached it.
3. PLV = |D_target| − |D_proxy→target| (weighted by η_on / η_off with DAgger), or "not reached";
   intervals come from a bootstrap over seeds (:mod:`proxybench.usefulness.plv_intervals`).

Every unit of work (a dataset, a pre-training, a training run and its evaluation) is cached in the
output folder under a hash of the settings it depends on, so an interrupted run resumes and a longer
ladder or more seeds reuse the work already done. :func:`target_arm` and :func:`proxy_arm` are the two
halves, used apart by the PLV objective (:mod:`proxybench.experiments.plv.objective`).
"""

from __future__ import annotations

import copy
import hashlib
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.experiments.plv.config import THESIS_PROXIES, PLVConfig
from proxybench.experiments.plv.dagger import dagger
from proxybench.learning.collection import collect
from proxybench.learning.dataset import Dataset
from proxybench.learning.domains import Domain, parse_domain
from proxybench.learning.evaluation import evaluate_expert, evaluate_policy
from proxybench.learning.model import configure_threads, default_device
from proxybench.learning.training import TrainConfig, build_model, save_checkpoint, train
from proxybench.runner.plants import PlantPool
from proxybench.usefulness.plv import ladder_done

__all__ = ["THESIS_PROXIES", "PLVConfig", "PLVResult", "Workspace", "fitted_reference", "proxy_arm", "run_plv",
           "target_arm", "target_domain", "target_label"]

@dataclass
class PLVResult:
    """Every training run (``runs``), each proxy's pre-training record (``proxies``), the expert's score."""

    config: PLVConfig
    runs: list[dict[str, Any]]
    proxies: dict[str, dict[str, Any]]
    expert_score: float
    wall_s: float = 0.0
    stage_s: dict[str, float] = field(default_factory=dict)
    cached: int = 0  # units of work (training runs, pre-trainings) taken from the cache, not recomputed

    def frame(self):
        import pandas as pd

        return pd.DataFrame(self.runs)


Progress = Callable[[str, int, int], None]


class Workspace:
    """Caching and bookkeeping shared by the stages of one run (``OUT/cache/<work key>/``)."""

    def __init__(self, cfg: PLVConfig, out: str | Path, progress: Progress | None = None):
        self.cfg, self.out, self.progress = cfg, Path(out), progress
        self.root = self.out / "cache" / cfg.work_key()
        self.device = default_device()
        self.target = target_domain(cfg)
        self.pool = PlantPool()  # a robot target's node, started once for the whole run
        self.eval_cfg = cfg.eval
        self.stage_s: dict[str, float] = {}
        self.cached = 0
        self._pool: Dataset | None = None

    def tick(self, stage: str, done: int, total: int) -> None:
        if self.progress:
            self.progress(stage, done, total)

    def add_time(self, stage: str, t0: float) -> None:
        self.stage_s[stage] = self.stage_s.get(stage, 0.0) + time.perf_counter() - t0

    def dataset(self, name: str, domain: Domain, samples: int, seed: int) -> Dataset:
        folder = self.root / "data" / name
        if (folder / "dataset.json").exists():
            return Dataset.load(folder)
        t0 = time.perf_counter()
        data = collect(domain, replace(self.cfg.collect, samples=samples, seed=seed),
                       progress=lambda d, t: self.tick(f"data: {name}", d, t), pool=self.pool)
        data.save(folder)
        self.add_time("data", t0)
        return data

    @property
    def data_pool(self) -> Dataset:
        """The target data every rung draws its seeded subsets from (expert-driven, off-policy)."""
        if self._pool is None:
            size = max(self.cfg.split(n).off_policy for n in self.cfg.ladder)
            self._pool = self.dataset("target", self.target, max(size, 1), self.cfg.seed)
        return self._pool

    def run(self, arm: str, n: int, seed: int, make: Callable[[int], Any], tcfg: TrainConfig) -> dict[str, Any]:
        """One rung: train (``make`` gives the starting network), DAgger if asked, evaluate on the target."""
        cfg = self.cfg
        path = self.root / "runs" / _slug(arm) / f"n{n}-s{seed}.json"
        if path.exists():
            self.cached += 1
            return json.loads(path.read_text())
        t0 = time.perf_counter()
        cost = cfg.split(n)
        model = make(seed)
        off = self.data_pool.take(cost.off_policy, seed) if cost.off_policy else None
        losses = train(model, off, replace(tcfg, seed=seed)).losses if off is not None else []
        if cost.on_policy:
            ccfg = replace(cfg.collect, seed=10_000 + 97 * seed + n)
            _, rounds = dagger(model, self.target, off, cost.on_policy, ccfg, replace(tcfg, seed=seed), cfg.dagger,
                               pool=self.pool)
            losses += [x for r in rounds for x in r.losses]
        t1 = time.perf_counter()
        ev = self.evaluate(_policy(model))
        ckpt = save_checkpoint(self.root / "models" / _slug(arm) / f"n{n}-s{seed}.pt", model,
                               {"arm": arm, "target_samples": asdict(cost), "seed": seed, "score": ev.mean,
                                "domain": self.target.describe()})
        row = {"arm": arm, "n": n, "seed": seed, "off_policy": cost.off_policy, "on_policy": cost.on_policy,
               "cost": cost.weighted(cfg.eta_on, cfg.eta_off), "score": ev.mean, "scores": ev.scores,
               "terminations": ev.terminations, "final_loss": losses[-1], "train_s": t1 - t0,
               "eval_s": time.perf_counter() - t1, "checkpoint": str(ckpt)}
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(row, indent=1))
        return row


    def evaluate(self, policy) -> Any:
        """A network's score on the target (the evaluation episodes, on the target's plant)."""
        return evaluate_policy(policy, self.target, self.eval_cfg, pool=self.pool)

    def close(self) -> None:
        self.pool.close()


def target_domain(cfg: PLVConfig) -> Domain:
    """The experiment's target at its image size: the reality model, or a robot node."""
    return parse_domain(cfg.target, cfg.width, cfg.height)


def target_label(cfg: PLVConfig) -> str:
    """Short words for the target, for titles: it says when a result is simulated."""
    if cfg.target == "reality":
        return "reality model, simulated"
    return f"robot node `{cfg.target.removeprefix('robot:')}`"


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in name).strip("-")


def _policy(model):
    from proxybench.learning.agent import torch_policy

    return torch_policy(model)


def _rung_mean(rows: list[dict[str, Any]]) -> float:
    return float(np.mean([r["score"] for r in rows]))


def _ladder(work: Workspace, arm: str, make: Callable[[int], Any], tcfg: TrainConfig, reference: float | None,
            zero_shot: float | None = None) -> list[dict[str, Any]]:
    """Every seed on each rung; with a ``reference``, stop once the mean has settled above it.

    Settled: the last ``confirm + 1`` rungs tried (the zero-shot score counting as rung 0) all have a
    mean at or above the reference, so the "reach and stay" rule is decided whatever came before.
    """
    cfg, rows = work.cfg, []
    means = [] if zero_shot is None else [zero_shot]
    total = len(cfg.ladder) * len(cfg.seeds)
    for k, n in enumerate(cfg.ladder):
        rung = []
        for j, seed in enumerate(cfg.seeds):
            rung.append(work.run(arm, n, seed, make, tcfg))
            work.tick(f"train: {arm}", k * len(cfg.seeds) + j + 1, total)
        rows += rung
        means.append(_rung_mean(rung))
        if reference is not None and cfg.stop_when_reached and ladder_done(means, reference, cfg.confirm):
            work.tick(f"train: {arm}", total, total)
            break
    return rows


def _domain(spec: str | Domain, cfg: PLVConfig) -> Domain:
    domain = parse_domain(spec, cfg.width, cfg.height) if isinstance(spec, str) else spec
    if domain.image_size != (cfg.width, cfg.height):
        raise ValueError(f"proxy {domain.name!r}: images are {domain.image_size}, the experiment's network takes "
                         f"{(cfg.width, cfg.height)}")
    return domain


def _pretrain(work: Workspace, name: str, spec: str | Domain, data_seed: int,
              ) -> tuple[dict[str, Any], dict[int, Any]]:
    """Proxy data, one pre-trained network per seed, each one's zero-shot score on the target and in the proxy."""
    from proxybench.learning.training import load_checkpoint

    cfg = work.cfg
    domain = _domain(spec, cfg)
    data = work.dataset(_slug(name), domain, cfg.proxy_samples, data_seed)
    models, per_seed = {}, {}
    for j, seed in enumerate(cfg.seeds):
        ckpt = work.root / "models" / _slug(name) / f"pretrained-s{seed}.pt"
        record_path = ckpt.with_name(f"pretrained-s{seed}-record.json")
        if record_path.exists():
            models[seed], _ = load_checkpoint(ckpt, work.device)
            per_seed[seed] = json.loads(record_path.read_text())
            work.cached += 1
            continue
        t0 = time.perf_counter()
        model = build_model(cfg.model, seed, work.device)
        res = train(model, data, replace(cfg.pretrain, seed=seed),
                    progress=lambda s, t, j=j: work.tick(f"pre-train: {name}", j * t + s, t * len(cfg.seeds)))
        zero = work.evaluate(_policy(model))
        own = evaluate_policy(_policy(model), domain, work.eval_cfg)
        save_checkpoint(ckpt, model, {"arm": name, "domain": domain.describe(), "pretrain": asdict(cfg.pretrain),
                                      "seed": seed, "proxy_samples": cfg.proxy_samples, "zero_shot": zero.mean})
        rec = {"seed": seed, "zero_shot": zero.mean, "zero_shot_scores": zero.scores, "in_proxy": own.mean,
               "pretrain_losses": res.losses, "pretrain_s": time.perf_counter() - t0,
               "samples_per_s": res.samples_per_s, "checkpoint": str(ckpt)}
        record_path.write_text(json.dumps(rec, indent=1))
        models[seed], per_seed[seed] = model, rec
        work.add_time("pretrain", t0)
    record = {"spec": spec if isinstance(spec, str) else domain.name, "domain": domain.describe(),
              "data_seed": data_seed,
              "zero_shot": float(np.mean([r["zero_shot"] for r in per_seed.values()])),
              "in_proxy": float(np.mean([r["in_proxy"] for r in per_seed.values()])),
              "zero_shot_by_seed": {str(k): r["zero_shot"] for k, r in per_seed.items()},
              "in_proxy_by_seed": {str(k): r["in_proxy"] for k, r in per_seed.items()}, "seeds": per_seed}
    return record, models


def target_arm(work: Workspace) -> tuple[list[dict[str, Any]], float, float]:
    """The target-only curve over the whole ladder: its runs, the expert's score and the reference P."""

    cfg = work.cfg
    _ = work.data_pool
    expert = evaluate_expert(work.target, work.eval_cfg, pool=work.pool).mean
    t1 = time.perf_counter()
    runs = _ladder(work, "target-only", lambda seed: build_model(cfg.model, seed, work.device), cfg.train, None)
    work.add_time("target-only", t1)
    return runs, expert, fitted_reference(runs, cfg)


def fitted_reference(runs: list[dict[str, Any]], cfg: PLVConfig) -> float:
    """P: the fitted target-only curve at the largest rung, less the tolerance (the proxies' ladders stop on it)."""
    from proxybench.usefulness.plv import reference_score
    from proxybench.usefulness.plv_curve import fit, rung_weights
    from proxybench.usefulness.plv_intervals import curves_from_runs

    curve = curves_from_runs(runs, "target-only", cfg.ladder)
    f = fit(curve.costs, curve.means(), rung_weights(curve.scores), float(cfg.ladder[0]))
    return reference_score(float(f.at(float(curve.costs.max()))[0]), cfg.tolerance)


def proxy_arm(work: Workspace, name: str, spec: str | Domain, reference: float,
              data_seed: int | None = None) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Pre-train on proxy ``spec`` (one network per seed) and fine-tune up the ladder until settled above P.

    ``spec``: a domain spec (``parse_domain``) or a ``Domain`` at the experiment's image size; ``name``
    keys its cache. ``data_seed`` seeds the proxy data; by default a stable hash of ``name``, so the
    same proxy gets the same data in every experiment.
    """
    cfg = work.cfg
    if data_seed is None:
        data_seed = cfg.seed + 1 + int(hashlib.sha256(name.encode()).hexdigest()[:6], 16)
    record, pre = _pretrain(work, name, spec, data_seed)
    t2 = time.perf_counter()
    record["reached_zero_shot"] = record["zero_shot"] >= reference
    runs = _ladder(work, name, lambda seed: copy.deepcopy(pre[seed]), cfg.finetune, reference,
                   zero_shot=record["zero_shot"])
    work.add_time("fine-tune", t2)
    return record, runs


def run_plv(cfg: PLVConfig, out: str | Path, progress: Progress | None = None) -> PLVResult:
    """Run (or resume) the whole experiment; caches and checkpoints go under ``out/cache``."""
    t0 = time.perf_counter()
    configure_threads()
    work = Workspace(cfg, out, progress)
    try:
        runs, expert, reference = target_arm(work)
        proxies: dict[str, dict[str, Any]] = {}
        for k, (name, spec) in enumerate(cfg.proxies.items()):
            proxies[name], arm_runs = proxy_arm(work, name, spec, reference, data_seed=cfg.seed + 1 + k)
            runs += arm_runs
    finally:
        work.close()
    return PLVResult(cfg, runs, proxies, expert, time.perf_counter() - t0, work.stage_s, work.cached)
