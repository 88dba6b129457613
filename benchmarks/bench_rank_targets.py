"""What the simulator is worth in target episodes, over many targets — and whether rank's guarantee held on them.

    .venv/bin/python benchmarks/bench_rank_targets.py --out out/rank-targets          # 12 targets (~30 min, 2 cores)
    .venv/bin/python benchmarks/bench_rank_targets.py --quick --out out/rank-targets  # 3 small targets

Each target is the built-in reality model (a *simulated* stand-in, never a robot) with its own hidden θ drawn
from a prior (trim ~ U(−0.2, 0.2), command delay ~ U(0.05, 0.2) s) and its own episode seed. On each,
``proxybench rank`` (the nominal proxy, α = 0.05) decides the pairs of 8 zoo agents from 10 target episodes each,
with and without the proxy; then 60 more target episodes per agent (other ids) estimate the truth, and a decision
is counted wrong when that estimate's own 95 % interval (Welch) excludes it. Prints one row per target and the
summary (median over targets with a bootstrap interval), and writes ``targets.csv`` to ``--out`` (README's
figures: docs/results/rank_targets.csv is that file).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

AGENTS = ["straight", "bang-bang", "pid", "pid-fast", "pid-twitchy", "pure-pursuit", "vision", "vision-fast"]


def _truth_contradicts(decision: str, a: np.ndarray, b: np.ndarray, eps: float, higher: bool) -> bool:
    """Does the 60-episode estimate's 95 % interval for mean(a) − mean(b) exclude ``decision``?"""
    from scipy import stats

    diff = a.mean() - b.mean()
    se = np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b))
    lo, hi = diff - stats.norm.ppf(0.975) * se, diff + stats.norm.ppf(0.975) * se
    if not higher:
        lo, hi = -hi, -lo
    if decision == "a>b":
        return hi <= eps
    if decision == "b>a":
        return lo >= -eps
    if decision == "tie":
        return lo > eps or hi < -eps
    return False


def one_target(k: int, out: Path, episodes: int, truth: int, seconds: float, proxy_only: int) -> dict:
    from proxybench.experiments.rank.config import RankConfig
    from proxybench.experiments.rank.run import run_rank
    from proxybench.runner.backends import LocalBackend
    from proxybench.tasks.metrics import METRICS

    rng = np.random.default_rng([2026, k])
    theta = {"trim": round(float(rng.uniform(-0.2, 0.2)), 3),
             "command_delay": round(float(rng.uniform(0.05, 0.2)), 3)}
    common = dict(target="reality", target_params=theta, agents=AGENTS, seconds=seconds, seed=1000 + k)
    backend = LocalBackend(2)
    res = run_rank(RankConfig(**common, episodes=episodes, proxy_episodes=proxy_only), out / f"t{k}", backend)
    ids = f"{episodes}-{episodes + truth - 1}"
    ref = run_rank(RankConfig(**common, episodes=ids, proxy_episodes=0), out / f"t{k}-truth", backend)
    tab = {a: np.asarray(list(v.values())) for a, v in ref.target_table.items()}
    r = res.ranking
    wrong = {}
    for label, pairs in (("with", r.pairs), ("alone", r.target_only)):
        wrong[label] = sum(_truth_contradicts(p.decision, tab[p.a][:, m], tab[p.b][:, m], res.tolerances[m],
                                              METRICS[p.metric].higher_is_better)
                           for p in pairs for m in [r.metrics.index(p.metric)])
    return {"target": k, **theta, "decided_with": r.decided(), "decided_alone": r.decided(False),
            "pairs": len(r.pairs), "worth": r.episode_worth(), "wrong_with": wrong["with"],
            "wrong_alone": wrong["alone"], "median_weight": float(np.median([p.weight for p in r.pairs])),
            "target_episodes": episodes * len(AGENTS), "proxy_episodes": res.proxy_paired + res.proxy_only,
            "wall_s": round(res.wall_s + ref.wall_s, 1)}


def main() -> None:
    import pandas as pd

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 targets, 4 + 12 episodes of 6 s")
    ap.add_argument("--targets", type=int, default=None)
    ap.add_argument("--out", type=Path, default=Path("out/rank-targets"))
    args = ap.parse_args()
    n, episodes, truth, seconds, proxy_only = (3, 4, 12, 6.0, 16) if args.quick else (12, 10, 60, 10.0, 100)
    n = args.targets or n
    rows = []
    t0 = time.perf_counter()
    for k in range(n):
        row = one_target(k, args.out, episodes, truth, seconds, proxy_only)
        rows.append(row)
        print(row, flush=True)
    frame = pd.DataFrame(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    frame.to_csv(args.out / "targets.csv", index=False)
    rng = np.random.default_rng(0)
    boot = [np.median(rng.choice(frame["worth"].to_numpy(), len(frame))) for _ in range(2000)]
    print(f"\n{n} reality-model targets (simulated), 8 agents × {episodes} target episodes of {seconds:g} s, "
          f"{proxy_only} proxy-only episodes each; {time.perf_counter() - t0:.0f} s")
    print(f"one target episode is worth (median over targets): {frame['worth'].median():.2f} "
          f"[{np.percentile(boot, 2.5):.2f}, {np.percentile(boot, 97.5):.2f}] target-alone episodes")
    print(f"pairs decided: {frame['decided_with'].sum()} with the proxy, {frame['decided_alone'].sum()} alone, of "
          f"{frame['pairs'].sum()}; decisions the {truth}-episode truth contradicts: {frame['wrong_with'].sum()} "
          f"with, {frame['wrong_alone'].sum()} alone; targets with any: {(frame['wrong_with'] > 0).sum()} with, "
          f"{(frame['wrong_alone'] > 0).sum()} alone")


if __name__ == "__main__":
    main()
