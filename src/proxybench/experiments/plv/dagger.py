"""DAgger: collect target frames while the *learner* drives, label them with the expert, retrain on all data.

Behaviour cloning only sees states the expert visits; the learner's own mistakes lead it to states
nobody labelled. DAgger (Ross et al., 2011) closes that gap by aggregating on-policy data. On a real
robot an on-policy sample costs more than an expert-driven one (the learner must be trusted to drive,
the expert must label afterwards), which is why the generalised PLV weighs them with η_on and η_off.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from proxybench.experiments.plv.config import DaggerConfig
from proxybench.learning.agent import torch_policy
from proxybench.learning.collection import CollectConfig, collect
from proxybench.learning.dataset import Dataset
from proxybench.learning.domains import Domain
from proxybench.learning.model import PilotNet
from proxybench.learning.training import TrainConfig, TrainResult, train
from proxybench.runner.plants import PlantPool

__all__ = ["DaggerConfig", "dagger"]


def dagger(
    model: PilotNet,
    domain: Domain,
    data: Dataset | None,
    on_samples: int,
    collect_cfg: CollectConfig,
    train_cfg: TrainConfig,
    cfg: DaggerConfig | None = None,
    progress: Callable[[int, int], None] | None = None,
    pool: PlantPool | None = None,
) -> tuple[Dataset, list[TrainResult]]:
    """Run DAgger on ``model`` (in place): ``on_samples`` on-policy samples spread over the rounds.

    ``data`` is the aggregate so far (off-policy expert data, may be None); each round appends its
    on-policy samples and continues training ``model`` on the whole aggregate. Returns the final
    aggregate and each round's training record. A robot domain's node comes from ``pool``.
    """
    cfg = cfg or DaggerConfig()
    results: list[TrainResult] = []
    per_round = [on_samples // cfg.rounds + (1 if r < on_samples % cfg.rounds else 0) for r in range(cfg.rounds)]
    for r, n in enumerate(per_round):
        if n == 0:
            continue
        ccfg = replace(collect_cfg, samples=n, seed=collect_cfg.seed * 1000 + 17 + r)
        fresh = collect(domain, ccfg, policy=torch_policy(model), beta=cfg.beta * cfg.beta_decay ** r, pool=pool)
        data = fresh if data is None else Dataset.concat([data, fresh])
        results.append(train(model, data, replace(train_cfg, seed=train_cfg.seed + 101 * (r + 1))))
        if progress:
            progress(r + 1, cfg.rounds)
    if data is None:
        raise ValueError("DAgger got no data: on_samples is 0 and no off-policy data was given")
    return data, results
