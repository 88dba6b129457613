"""Canned inputs for the studies' :meth:`~proxybench.experiments.study.Study.example`: a made-up target and
proxies (per-agent score tables), so a report can be written and checked without running an episode.

Nothing here is a result: the target says it is a canned example in every report that shows it.
"""

from __future__ import annotations

import numpy as np

from proxybench.domain.kinds import DomainKind
from proxybench.experiments.baselines import NOMINAL
from proxybench.experiments.config import Experiment, SearchConfig
from proxybench.runner.jobs import AgentSpec
from proxybench.targets.base import Target, TargetEpisode, TargetInfo, TargetRun

__all__ = ["AGENTS", "CANNED", "MEANS", "CannedTarget", "canned_experiment", "canned_proxies", "canned_target"]

#: five zoo agents (names only: nothing runs them)
AGENTS = ("straight", "pid", "pid-fast", "pure-pursuit", "vision")
#: each agent's mean driven_lanedir_consec [m] and survival_time [s] on the canned target (20 s episodes)
MEANS = {"straight": (2.0, 6.0), "pid": (9.0, 20.0), "pid-fast": (11.0, 19.0), "pure-pursuit": (8.0, 20.0),
         "vision": (5.0, 14.0)}
#: what a canned target is, in the words every report that shows it prints
CANNED = TargetInfo(DomainKind.RECORDED, None, "canned example",
                    "a canned example: made-up scores, no robot and no simulator ran")


class CannedTarget(Target):
    """The target of a canned case, where a ``Target`` is asked for: it says it is canned and runs nothing."""

    kind = DomainKind.RECORDED

    def info(self) -> TargetInfo:
        return CANNED


def canned_experiment(episodes: int = 3) -> Experiment:
    """An experiment of the five agents, two metrics and a three-value trim sweep."""
    return Experiment(command="predictivity", target_text="canned", agents=[AgentSpec(a) for a in AGENTS],
                      map="loop_3x3", episodes=episodes, seconds=20.0,
                      metrics=("driven_lanedir_consec", "survival_time"), image_size=(160, 120), proxy={},
                      sweep={"trim": (-0.1, 0.0, 0.1)}, search=SearchConfig(), trials=0, n_boot=50, pod_seconds=0.0,
                      seed=0)


def canned_target(exp: Experiment, seed: int = 0) -> TargetRun:
    """Made-up target scores: each agent's episodes around its own means (a canned example, no episode ran)."""
    rng = np.random.default_rng(seed)
    n = int(exp.episodes) if isinstance(exp.episodes, int) else len(exp.episodes)
    results = {a: np.column_stack([rng.normal(m, 0.8, n) for m in MEANS[a]]) for a in AGENTS}
    episodes = [TargetEpisode(a, e, 1000 + e, None) for a in AGENTS for e in range(n)]
    return TargetRun(CANNED, exp.map, exp.seconds, exp.metrics, episodes, results)


def canned_proxies(tgt: TargetRun, names: list[str], seed: int = 1) -> dict[str, dict[str, np.ndarray]]:
    """A proxy table per name (and the nominal θ's): the target's scores, shifted more the further down the list,
    so the proxies order the agents less and less like the target."""
    rng = np.random.default_rng(seed)
    out = {}
    for k, name in enumerate([NOMINAL, *names]):
        out[name] = {a: v + rng.normal(0.0, 0.5 + 1.5 * k, v.shape) for a, v in tgt.results.items()}
    return out
