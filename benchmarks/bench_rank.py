"""The ranking: speed of deciding every pair at scale, and its guarantee and savings in simulated worlds.

    .venv/bin/python benchmarks/bench_rank.py            # speed (20 agents, 1,000 + 10,000 episodes), 400 worlds a row
    .venv/bin/python benchmarks/bench_rank.py --quick    # 100 worlds a row
    taskset -c 0 .venv/bin/python benchmarks/bench_rank.py --speed-only   # one core, as the issue's target says

Speed: :func:`proxybench.usefulness.ranking.rank` on 20 agents × 2 metrics, 1,000 target episodes and 10,000
proxy-only episodes per agent (plus the 1,000 paired), fixed and anytime mode, best of 3, ppi_py imported before
(its first import takes ~1.4 s: statsmodels, scikit-learn) (the target: ≤ 2 s on
one core). Validity (:mod:`proxybench.usefulness.ranking_check`): the share of simulated worlds with any wrong
decision (Clopper–Pearson 95 %), fixed and anytime (a wrong decision at any episode count counts), for a good
proxy, an adversarial one (order inverted, starts anti-tracked) and none; beside it the pairs decided and what a
target episode is worth with the proxy, in target-alone episodes (median (width alone / width with)²).
"""

from __future__ import annotations

import argparse
import time
from functools import partial

import numpy as np


def _scores(k: int, n: int, big_n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    means = rng.normal(0, 1, (k, 2))
    s = rng.normal(0, 1, n + big_n)
    target, proxy = {}, {}
    for a in range(k):
        y = means[a] + s[:n, None] + rng.normal(0, 1, (n, 2))
        yh = means[a] + s[:, None] + rng.normal(0, 0.5, (n + big_n, 2))
        target[f"agent{a:02d}"] = {e: y[e] for e in range(n)}
        proxy[f"agent{a:02d}"] = {**{e: yh[e] for e in range(n)}, **{100_000 + e: yh[n + e] for e in range(big_n)}}
    return target, proxy


def speed() -> None:
    from proxybench.usefulness.ranking import rank

    target, proxy = _scores(20, 1000, 10_000)
    for sequential in (False, True):
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            r = rank(target, proxy, ["m1", "m2"], [True, True], [0.1, 0.1], 0.05, sequential=sequential)
            best = min(best, time.perf_counter() - t0)
        mode = "anytime" if sequential else "fixed"
        print(f"rank, 20 agents × 2 metrics, 1,000 target + 11,000 proxy episodes each, {mode}: {best:.2f} s "
              f"(best of 3); {r.decided()} of {len(r.pairs)} decided with the proxy, {r.decided(False)} alone")


def validity(runs: int) -> None:
    import proxybench.usefulness.ranking_check as rc

    print(f"\n{runs} worlds a row, α = 0.1, 5 agents, 30 target episodes, 1,000 proxy-only episodes\n")
    print("| ρ² | mode | proxy | worlds with a wrong decision [95 %] | pairs decided: with / alone "
          "| one target episode is worth |")
    print("| --- | --- | --- | --- | --- | --- |")
    world = rc.draw_world
    try:
        # ρ²: the squared correlation of a pair's episode differences on the proxy and on the target, in these
        # worlds E(β_i − β_j)² = 1/6 over (1/6 + 2σ²) and (1/6 + 2(0.3σ)²): 0.04 at σ = 1, 0.54 at σ = 0.25
        for noise, label in ((1.0, "0.04"), (0.25, "0.54")):
            rc.draw_world = partial(world, noise=noise)
            for mode in ("fixed", "anytime"):
                for proxy in ("good", "bad", "none"):
                    c = rc.coverage(k=5, n=30, big_n=1000, proxy=proxy, mode=mode, runs=runs, alpha=0.1)
                    lo, hi = c.interval
                    print(f"| {label} | {mode} | {proxy} | {c.wrong}/{c.runs} = {c.share:.3f} [{lo:.3f}, {hi:.3f}] "
                          f"| {c.decided_with:.2f} / {c.decided_alone:.2f} | {c.worth:.2f} |", flush=True)
    finally:
        rc.draw_world = world


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="100 worlds a row instead of 400")
    ap.add_argument("--speed-only", action="store_true")
    args = ap.parse_args()
    speed()
    if not args.speed_only:
        validity(100 if args.quick else 400)


if __name__ == "__main__":
    main()
