"""Interval coverage (not speed) of PLV: fitted learning curves against the ladder rule, on known curves.

    .venv/bin/python benchmarks/bench_plv_coverage.py            # 200 simulated experiments per row (~20 min)
    .venv/bin/python benchmarks/bench_plv_coverage.py --quick    # 3 per row (what the test suite runs)

Known target-only and proxy learning curves on the full ladder (50 … 9,000 target samples) with seed noise like
the real runs' (:mod:`proxybench.usefulness.plv_coverage`); for 5 and 15 seeds, the share of experiments whose
95 % interval holds the true (continuous) PLV, for the fitted curves (now) and the ladder rule (before), with
mean widths, and the fitted estimate's bias and RMSE. Prints a Markdown table (docs/learning.md quotes it).
"""

from __future__ import annotations

import argparse
import time

from proxybench.usefulness.plv_coverage import check, scenarios


def _n(x: float | None) -> str:
    return "not reached" if x is None else f"{x:,.0f}"


def _w(x: float) -> str:
    return "–" if x != x else f"{x:,.0f}"  # NaN: no interval with two finite ends


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 experiments per row, 200 replicates")
    args = ap.parse_args(argv)
    reps, replicates = (3, 200) if args.quick else (200, 1000)
    print(f"{reps} simulated experiments per row, {replicates} bootstrap replicates, 95 % intervals\n")
    print("| scenario | true PLV | seeds | fitted: covers (width) | fitted: bias, RMSE | ladder rule: covers (width) |")
    print("| --- | --- | --- | --- | --- | --- |")
    t0 = time.perf_counter()
    for name, scn in scenarios().items():
        for seeds in (5, 15):
            c = check(scn, seeds=seeds, reps=reps, replicates=replicates)
            bias = "–" if c["true_plv"] is None else f"{c['curve_bias']:+,.0f}, {c['curve_rmse']:,.0f}"
            print(f"| {name} | {_n(c['true_plv'])} | {seeds} | {c['curve_covers']:.2f} ({_w(c['curve_width'])}) "
                  f"| {bias} | {c['ladder_covers']:.2f} ({_w(c['ladder_width'])}) |", flush=True)
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
