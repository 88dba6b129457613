"""rank-check: on each target of a family, rank's decisions from a few episodes judged by many more.

Per target: ``rank`` (fixed sample, the nominal proxy) on ``episodes`` per agent; the same decisions with an
adversarial proxy (:func:`~proxybench.usefulness.ranking_check.inverted`: the proxy's episodes of each agent given
to its mirror in the proxy's order) and with none; the anytime-valid decisions after every episode count
3 … ``episodes`` (a wrong decision at any of them counts); then ``truth_episodes`` more per agent on other ids,
whose own 95 % interval judges each decision (:func:`~proxybench.usefulness.ranking_check.contradicted`). Every
episode is cached under ``OUT/targets/K/runs``: a run that stopped resumes.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from proxybench.experiments.rank.run import RankResult, measure_rank, run_rank, scores_of_target
from proxybench.experiments.rank_check.config import RankCheckConfig
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.tasks.metrics import METRICS
from proxybench.usefulness.ranking import PairDecision
from proxybench.usefulness.ranking_check import contradicted, inverted

__all__ = ["RankCheckResult", "TargetCheck", "canned_rank_check", "measure_target", "run_rank_check",
           "summary_lines", "write_rank_check"]

#: gym-duckietown targets' θ ranges (gym's names), as the validation study's gym family draws them
GYM_DRAW = {"trim": (-0.15, 0.35), "delay": (0.02, 0.3)}


@dataclass(frozen=True)
class TargetCheck:
    """One target: decisions made and contradicted, fixed and anytime, with the proxy, an adversarial one, none."""

    target: str
    pairs: int
    decided_with: int
    decided_alone: int
    decided_bad: int
    wrong_with: int  # fixed sample: decisions the truth episodes contradict
    wrong_alone: int
    wrong_bad: int
    anytime_wrong_with: int  # anytime: decisions contradicted at any episode count
    anytime_wrong_alone: int
    anytime_wrong_bad: int
    worth: float  # one target episode with the proxy, in target-alone episodes (median over pairs)
    median_weight: float
    target_episodes: int
    proxy_episodes: int
    truth_episodes: int


@dataclass
class RankCheckResult:
    """Every target's check, the settings, and what the targets are (in words)."""

    config: RankCheckConfig
    rows: list[TargetCheck]
    statement: str
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        """Shares of targets with any contradicted decision (Clopper–Pearson 95 %), decisions, worth."""
        n = len(self.rows)
        out: dict[str, Any] = {"targets": n, "alpha": self.config.alpha, "statement": self.statement}
        for key in ("wrong_with", "wrong_alone", "wrong_bad", "anytime_wrong_with", "anytime_wrong_alone",
                    "anytime_wrong_bad"):
            k = sum(getattr(r, key) > 0 for r in self.rows)
            out[f"targets_{key}"] = {"count": k, "share": k / n if n else float("nan"), "interval": _cp(k, n)}
        for key in ("decided_with", "decided_alone", "decided_bad", "pairs"):
            out[key] = sum(getattr(r, key) for r in self.rows)
        worth = np.array([r.worth for r in self.rows if np.isfinite(r.worth)])
        out["worth_median"] = float(np.median(worth)) if len(worth) else float("nan")
        out["worth_interval"] = _boot_median(worth)
        return out


def _cp(k: int, n: int) -> list[float]:
    if n == 0:
        return [float("nan"), float("nan")]
    lo = stats.beta.ppf(0.025, k, n - k + 1) if k else 0.0
    hi = stats.beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return [float(lo), float(hi)]


def _boot_median(x: np.ndarray, reps: int = 2000) -> list[float]:
    if len(x) == 0:
        return [float("nan"), float("nan")]
    rng = np.random.default_rng(0)
    meds = np.median(rng.choice(x, (reps, len(x))), axis=1)
    return [float(np.percentile(meds, 2.5)), float(np.percentile(meds, 97.5))]


def _targets(cfg: RankCheckConfig, out: Path) -> list[Any]:
    if cfg.family == "gym":
        from proxybench.experiments.study import ConfigError
        from proxybench.gym.environment import check_environment
        from proxybench.targets.gym import gym_targets

        env = check_environment(render=False)
        if env.problems:
            raise ConfigError("family gym: gym-duckietown's environment is not ready (run `proxybench gym setup`): "
                              + "; ".join(env.problems))
        return gym_targets(cfg.targets or 1, cfg.seed, GYM_DRAW, out / "secret" / "gym", nodes=2)
    from proxybench.targets.heldout import heldout_targets

    return heldout_targets(cfg.targets or 1, cfg.seed)


def run_rank_check(cfg: RankCheckConfig, out: str | Path, backend: Backend | None = None,
                   progress: Any = None) -> RankCheckResult:
    """Run (or resume) every target's episodes and check rank on each (``cfg`` with its mode's defaults)."""
    from proxybench.experiments.rank.config import RankConfig

    t0, out, backend = time.perf_counter(), Path(out), backend or InlineBackend()
    rows, statement = [], ""
    targets = _targets(cfg, out)
    if progress:  # the clock of the targets' ETA starts now, not when the first one is done
        progress("targets", 0, len(targets))
    for k, target in enumerate(targets):
        folder = out / "targets" / str(k)
        rc = RankConfig(agents=cfg.agents, episodes=cfg.episodes, seconds=cfg.seconds, alpha=cfg.alpha,
                        proxy_episodes=cfg.proxy_episodes, seed=cfg.seed * 1000 + k)
        res = run_rank(rc, folder, backend, target=target)
        exp = res.experiment
        ids = tuple(range(exp.episode_count, exp.episode_count + (cfg.truth_episodes or 2)))
        truth = target.run(exp.agents, map_name=exp.map, seconds=exp.seconds, episodes=ids, seed=exp.seed,
                           metrics=exp.metrics, image_size=exp.image_size, run_dir=folder / "runs", backend=backend)
        rows.append(measure_target(getattr(target, "name", f"target-{k}"), res, scores_of_target(truth)))
        statement = res.target.statement
        if progress:
            progress("targets", k + 1, len(targets))
    return RankCheckResult(cfg, rows, statement, time.perf_counter() - t0)


def measure_target(name: str, res: RankResult, truth: dict[str, dict[int, np.ndarray]]) -> TargetCheck:
    """One target's check from its rank result and the truth episodes (runs no episode)."""
    exp, r = res.experiment, res.ranking
    higher = [METRICS[m].higher_is_better for m in exp.metrics]
    tol, alpha = res.tolerances, r.alpha

    def wrong(pairs: tuple[PairDecision, ...]) -> int:
        return contradicted(pairs, truth, exp.metrics, tol, higher)

    bad_proxy = inverted(res.proxy_table, 0, higher[0]) if res.proxy_table else None
    bad = measure_rank(exp, res.target_table, bad_proxy, tol, alpha) if bad_proxy else r
    n = min(len(v) for v in res.target_table.values())
    seen: dict[str, set[tuple[str, str, str]]] = {"with": set(), "alone": set(), "bad": set()}
    for t in range(3, n + 1):
        first = {a: dict(sorted(eps.items())[:t]) for a, eps in res.target_table.items()}
        now = measure_rank(exp, first, res.proxy_table or None, tol, alpha, sequential=True, horizon=n)
        now_bad = measure_rank(exp, first, bad_proxy, tol, alpha, sequential=True, horizon=n) if bad_proxy else now
        for key, pairs in (("with", now.pairs), ("alone", now.target_only), ("bad", now_bad.pairs)):
            seen[key] |= {(p.a, p.b, p.metric) for p in pairs if contradicted([p], truth, exp.metrics, tol, higher)}
    return TargetCheck(name, len(r.pairs), r.decided(), r.decided(False), bad.decided(), wrong(r.pairs),
                       wrong(r.target_only), wrong(bad.pairs), len(seen["with"]), len(seen["alone"]),
                       len(seen["bad"]), r.episode_worth(), float(np.median([p.weight for p in r.pairs])),
                       sum(res.target_episodes.values()), res.proxy_paired + res.proxy_only,
                       sum(len(v) for v in truth.values()))


def summary_lines(res: RankCheckResult) -> list[str]:
    """The terminal view: what the targets are, then the guarantee and the savings over them."""
    s, c = res.summary(), res.config
    def share(key: str) -> str:
        v = s[f"targets_{key}"]
        return f"{v['count']}/{s['targets']} [{v['interval'][0]:.2f}, {v['interval'][1]:.2f}]"

    return [f"targets: {s['targets']} of the {c.family} family — {res.statement}",
            f"each: {len(c.agents or [])} agents × {c.episodes} target episodes of {c.seconds:g} s, "
            f"{c.proxy_episodes} proxy-only episodes each, judged by {c.truth_episodes} more; α = {c.alpha:g}",
            f"targets with a decision the further episodes contradict — fixed: with the proxy {share('wrong_with')}, "
            f"alone {share('wrong_alone')}, adversarial proxy {share('wrong_bad')}; anytime: with "
            f"{share('anytime_wrong_with')}, alone {share('anytime_wrong_alone')}, adversarial "
            f"{share('anytime_wrong_bad')}",
            f"pairs decided: {s['decided_with']} with the proxy, {s['decided_alone']} alone, {s['decided_bad']} with "
            f"the adversarial proxy, of {s['pairs']}",
            f"one target episode is worth {s['worth_median']:.2f} [{s['worth_interval'][0]:.2f}, "
            f"{s['worth_interval'][1]:.2f}] target-alone episodes (median over targets, bootstrap 95 %)"]


def write_rank_check(res: RankCheckResult, out: str | Path) -> list[Path]:
    """targets.csv (one row a target) and summary.json in ``out``."""
    import pandas as pd

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    pd.DataFrame([asdict(r) for r in res.rows]).to_csv(out / "targets.csv", index=False)
    data = {**res.summary(), "config": res.config.model_dump(), "wall_s": round(res.wall_s, 1), "notes": res.notes}
    (out / "summary.json").write_text(json.dumps(data, indent=1, default=float))
    return [out / "targets.csv", out / "summary.json"]


def canned_rank_check() -> RankCheckResult:
    """Three made-up targets' rows (a canned example: nothing ran)."""
    rows = [TargetCheck(f"canned-{k}", 56, 30 + k, 28 + k, 27, 0, 0, int(k == 2), 0, 0, 0, 1.0 + 0.05 * k, 0.1,
                        80, 880, 480) for k in range(3)]
    cfg = RankCheckConfig().filled(False)
    return RankCheckResult(cfg, rows, "a canned example: made-up rows, no robot and no simulator ran")
