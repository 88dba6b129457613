"""Error rate and power (not speed) of the sequential stopping rule of `proxybench plan --sequential`.

    .venv/bin/python benchmarks/bench_stopping.py            # 200 simulated experiments per row (about half an hour)
    .venv/bin/python benchmarks/bench_stopping.py --quick    # 2 per row, budget 150 (the test suite runs it)

Six agents on one metric with known means and spread σ = 1, tolerance ε = σ
(:mod:`proxybench.usefulness.stopping_check`): a pilot of 3 episodes per agent, then batches of 6 episodes
where they settle most until every pair is ordered or tied within ε, or the budget is spent. For each scenario,
the rule with its level split over the looks (Bonferroni, the default) and without (one test per look). Prints
a Markdown table (docs/usefulness.md quotes it).
"""

from __future__ import annotations

import argparse
import time

from proxybench.usefulness.stopping_check import check, scenarios


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 experiments per row, budget 150, instead of 200, 600")
    ap.add_argument("--budget", type=int, default=None, help="episodes after the pilot, all agents together "
                    "(default: 600; --quick 150)")
    args = ap.parse_args(argv)
    reps = 2 if args.quick else 200
    args.budget = args.budget or (150 if args.quick else 600)
    print(f"{reps} simulated experiments per row; 6 agents, σ = 1, ε = 1; pilot 3 episodes per agent, batches of "
          f"6, budget {args.budget} episodes; α = 0.05 per pair, looks when the episodes have grown by half\n")
    print("| scenario | pairs with \\|d\\| > ε | rule | wrong order (per pair) | false tie | any error (FWER) | power "
          "| all settled | episodes per agent | pilot's range of n covers |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    t0 = time.perf_counter()
    for name, scn in scenarios().items():
        for correct in (True, False):
            c = check(scn, reps=reps, budget=args.budget, correct=correct, seed=0)
            rule = "split over looks" if correct else "no correction"
            print(f"| {name} | {c['pairs_far']} of {c['pairs']} | {rule} | {c['wrong_order']:.3f} | "
                  f"{c['false_tie']:.3f} | {c['fwer']:.2f} | {c['power']:.2f} | {c['settled']:.2f} | "
                  f"{c['episodes']:.1f} | {c['range_covers']:.2f} |", flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
