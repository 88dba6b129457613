"""The baselines beside every proxy in a predictivity report, and where each one disagrees with the target.

Three answers a researcher has without tuning a simulator (docs/targets.md, "Baselines"):

- **nominal θ**: the simulator at its nominal calibration (the proxy nobody tuned);
- **no simulator: agent classes**: the rule :data:`CLASS_RULE` (privileged ahead of camera ahead of agents that
  sense nothing; ties within a class), a prior anyone could write down;
- **no simulator: the target's first half**: the target's own first half of episodes per agent predicting its
  second half (what more target data, not a simulator, would say).

A proxy whose PRPV does not beat these has not shown it is useful for predicting this target. The per-pair
diagnosis (:func:`~proxybench.usefulness.diagnosis.pair_disagreements`) says which pairs each of them and the
best proxy order differently, and on which starts (the direction the start faces around the map).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from proxybench.agents.zoo import ZOO
from proxybench.targets.base import TargetRun
from proxybench.usefulness.baselines import class_predictor, half_split
from proxybench.usefulness.diagnosis import PairDisagreement, pair_disagreements
from proxybench.usefulness.intervals import Usefulness, usefulness
from proxybench.usefulness.metrics import PairedResults

__all__ = ["CLASS_RULE", "NOMINAL", "agent_class_ranks", "baselines", "diagnose", "start_groups"]

NOMINAL = "nominal θ"
#: agents that sense nothing (agents/simple.py): the bottom class of the rule
NO_SENSING = ("random", "straight")
CLASS_RULE = ("privileged agents (they read the true lane pose) ahead of camera agents (zoo vision agents, node "
              "agents, checkpoints and agents proxybench does not know) ahead of agents that sense nothing "
              f"({', '.join(NO_SENSING)}); agents of one class tie")


def agent_class_ranks(agents: Sequence[str]) -> dict[str, int]:
    """Each agent's class under :data:`CLASS_RULE`: 2 privileged, 1 camera (or unknown), 0 senses nothing."""
    return {a: 0 if a in NO_SENSING else 2 if a in ZOO and ZOO[a].privileged else 1 for a in agents}


def start_direction(pose: tuple[float, float, float] | None, centre: tuple[float, float]) -> str:
    """Whether a start faces clockwise or counter-clockwise around the map's centre (the sign of the cross
    product of the offset from the centre and the heading); "unknown start" without a pose."""
    if pose is None:
        return "unknown start"
    x, y, th = pose
    cross = (x - centre[0]) * math.sin(th) - (y - centre[1]) * math.cos(th)
    return "counter-clockwise start" if cross >= 0 else "clockwise start"


def start_groups(tgt: TargetRun, map_size: tuple[float, float]) -> dict[str, list[str]]:
    """Per agent, the start direction of each of its episodes, in the order of ``tgt.results``."""
    centre = (map_size[0] / 2, map_size[1] / 2)
    return {a: [start_direction(e.pose, centre) for e in tgt.episodes_of(a)] for a in tgt.results}


def baselines(tgt: TargetRun, nominal: Mapping[str, np.ndarray], higher: tuple[bool, ...], metrics: tuple[str, ...],
              *, n_boot: int, seed: int) -> dict[str, Usefulness]:
    """Every baseline's usefulness figures against the target, by name (the first-half one needs two target
    episodes per agent and is left out otherwise)."""
    out = {NOMINAL: usefulness(PairedResults(dict(nominal), tgt.results, higher, metrics), n_boot=n_boot, seed=seed)}
    ranks = agent_class_ranks(list(tgt.results))
    out["no simulator: agent classes"] = usefulness(
        PairedResults(class_predictor(tgt.results, ranks, higher), tgt.results, higher, metrics), n_boot=n_boot,
        seed=seed)
    if all(len(v) >= 2 for v in tgt.results.values()):
        first, second = half_split(tgt.results)
        out["no simulator: the target's first half"] = usefulness(PairedResults(first, second, higher, metrics),
                                                                  n_boot=n_boot, seed=seed)
    return out


def diagnose(predictors: Mapping[str, Mapping[str, np.ndarray]], tgt: TargetRun, higher: tuple[bool, ...],
             metrics: tuple[str, ...], map_size: tuple[float, float]) -> dict[str, list[PairDisagreement]]:
    """Per predictor (a proxy's or a baseline's results table), the pairs it orders differently from the target,
    with the order in each start direction."""
    groups = start_groups(tgt, map_size)
    return {name: pair_disagreements(res, tgt.results, higher, metrics, groups=groups)
            for name, res in predictors.items()}


def baseline_tables(tgt: TargetRun, nominal: Mapping[str, np.ndarray],
                    higher: tuple[bool, ...]) -> dict[str, Mapping[str, Any]]:
    """The results tables of the baselines that predict the target's own episodes (for the diagnosis)."""
    return {NOMINAL: nominal,
            "no simulator: agent classes": class_predictor(tgt.results, agent_class_ranks(list(tgt.results)), higher)}
