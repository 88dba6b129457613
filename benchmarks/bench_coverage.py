"""Interval coverage (not speed): how often PRPV's and PPV's 95 % intervals hold the true value.

    .venv/bin/python benchmarks/bench_coverage.py            # 100 simulated experiments per row (a few minutes)
    .venv/bin/python benchmarks/bench_coverage.py --quick    # 30 per row

Synthetic proxies and targets with known means (:mod:`proxybench.usefulness.coverage`): episodes are the
agent's mean + a start effect shared by the paired proxy and target episodes + independent noise. For
each scenario, agent count K and episode count n, the table gives the share of experiments whose
interval holds the truth, for PRPV's order range (now) and the percentile bootstrap (before), and for
PPV's BCa interval, with the mean widths. Prints a Markdown table (docs/usefulness.md quotes it).
"""

from __future__ import annotations

import argparse
import time

from proxybench.usefulness.coverage import coverage, scenarios


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="30 experiments per row instead of 100")
    ap.add_argument("--n-boot", type=int, default=300)
    args = ap.parse_args()
    reps = 30 if args.quick else 100
    print(f"{reps} simulated experiments per row, {args.n_boot} resamples, 95 % intervals\n")
    print("| scenario | K | n | true PRPV | order range: covers (width) | former percentile: covers (width) "
          "| former holds its point | true PPV | PPV BCa: covers (width) |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    t0 = time.perf_counter()
    for k in (6, 12):
        for name, scn in scenarios(k).items():
            for n in (3, 10):
                c = coverage(scn, n, reps, n_boot=args.n_boot)
                print(f"| {name} | {k} | {n} | {c['true_prpv']:g} | {c['prpv']:.2f} ({c['prpv_width']:.1f}) "
                      f"| {c['prpv_percentile']:.2f} ({c['prpv_percentile_width']:.1f}) "
                      f"| {c['prpv_percentile_contains_point']:.2f} | {c['true_ppv']:.2f} "
                      f"| {c['ppv']:.2f} ({c['ppv_width']:.2f}) |", flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
