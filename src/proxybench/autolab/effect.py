"""What localisation does to the science: a target scored through the (simulated) watchtowers vs the truth.

A target made by ``proxybench localize`` from simulated runs keeps, per episode, the log it came from, and the log
keeps the simulator's true trajectory. Scoring both with the same metrics gives, over the paired episodes:

- the **bias** of each metric, localised − true (mean with a 95 % bootstrap interval over episodes): e.g. the
  survival time a target loses because the robot is first seen a few tenths of a second after the start;
- the **PRPV noise** localisation adds: PRPV of the localised scores taken as a proxy of the true ones (paired
  bootstrap interval, ``usefulness.intervals``), the part of a proxy's PRPV against this target that comes from
  the measurement rather than from the simulator.

The predictivity report states both for such a target (one call, ``effect_for_target``); targets of real runs
have no truth and get no such statement.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from proxybench.usefulness.intervals import usefulness
from proxybench.usefulness.metrics import Estimate, PairedResults

__all__ = ["LocalisationEffect", "effect_for_target", "localisation_effect"]


@dataclass
class LocalisationEffect:
    """Metric bias (localised − true) per metric and the PRPV of localised vs true scores, over ``episodes``."""

    episodes: int
    agents: int
    bias: dict[str, Estimate]
    prpv: Estimate

    @property
    def statement(self) -> str:
        parts = "; ".join(f"{m} {e.value:+.3g} [{e.low:+.3g}, {e.high:+.3g}]" for m, e in self.bias.items())
        return (f"Through the simulated watchtowers ({self.agents} agents × {self.episodes // max(self.agents, 1)} "
                f"episodes, scored from the localised and from the true trajectories): metric bias (localised − "
                f"true) {parts}; PRPV of the localised scores against the true ones {self.prpv.value:.1f} "
                f"[{self.prpv.low:.1f}, {self.prpv.high:.1f}], the ranking noise the localisation adds to this "
                "target.")


def _bias(diff: np.ndarray, n_boot: int, seed: int) -> Estimate:
    rng = np.random.default_rng(seed)
    means = diff[rng.integers(0, diff.size, (n_boot, diff.size))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return Estimate(float(diff.mean()), float(lo), float(hi))


def localisation_effect(root: str | Path, metrics: tuple[str, ...], n_boot: int = 300,
                        seed: int = 0) -> LocalisationEffect | None:
    """The effect for the localised target at ``root``; None when its runs have no true trajectories."""
    from proxybench.domain.maps import load_map
    from proxybench.targets.manifest import load_manifest
    from proxybench.targets.recorded import resolve_map
    from proxybench.tasks.metrics import METRICS
    from proxybench.tasks.trajectory import Trajectory

    root = Path(root)
    manifest = load_manifest(root)
    m = load_map(resolve_map(root, manifest.map))
    true: dict[str, list[list[float]]] = {}
    seen: dict[str, list[list[float]]] = {}
    for agent in manifest.agents:
        for e in manifest.episodes:
            info = root / "localization" / agent / str(e) / "run.json"
            truth = json.loads(info.read_text()).get("truth") if info.is_file() else None
            if not truth or not Path(truth).is_file():
                return None
            t_true = Trajectory.load(truth)
            t_true.meta["episode_seconds"] = manifest.seconds
            t_loc = Trajectory.from_file(root / manifest.pattern.format(agent=agent, episode=e), m)
            t_loc.meta["episode_seconds"] = manifest.seconds
            true.setdefault(agent, []).append([METRICS[k](t_true) for k in metrics])
            seen.setdefault(agent, []).append([METRICS[k](t_loc) for k in metrics])
    higher = tuple(METRICS[k].higher_is_better for k in metrics)
    pr = PairedResults({a: np.array(v) for a, v in seen.items()}, {a: np.array(v) for a, v in true.items()}, higher,
                       metrics)
    est = usefulness(pr, n_boot=n_boot, seed=seed)
    diff = np.concatenate([np.array(seen[a]) - np.array(true[a]) for a in manifest.agents])
    bias = {k: _bias(diff[:, j], n_boot, seed) for j, k in enumerate(metrics)}
    return LocalisationEffect(len(diff), len(manifest.agents), bias, est["prpv"])


def effect_for_target(target, metrics: tuple[str, ...], n_boot: int = 300, seed: int = 0) -> LocalisationEffect | None:
    """The effect for an experiment's target: a recorded target made by ``localize`` from simulated runs."""
    root = getattr(target, "root", None)
    if root is None or not (Path(root) / "localization").is_dir():
        return None
    return localisation_effect(root, metrics, n_boot, seed)
