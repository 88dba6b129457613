"""The job queue raced on PostgreSQL (issue 23 §3): results posted around their lease's expiry, evaluators and
the server killed -9 during load; counts trials, lost and duplicated results, status/leaderboard
disagreements.

    .venv/bin/python benchmarks/bench_queue_races.py                    # 3 runs × 60 s
    .venv/bin/python benchmarks/bench_queue_races.py --runs 1 --seconds 20 --evaluators 6

The machinery is ``tests/support/queue_race.py`` (see there); PostgreSQL is a throwaway server started from the
installed binaries (or $PROXYBENCH_TEST_PG_URL). Run it beside the same command on another checkout
(``PYTHONPATH=…/src``) to compare.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.postgres import PostgresServer
from support.queue_race import race


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--evaluators", type=int, default=4)
    p.add_argument("--lease-seconds", type=float, default=1.0)
    p.add_argument("--kill-every", type=float, default=3.0)
    args = p.parse_args()
    pg = PostgresServer()
    reason = pg.start()
    if reason is not None:
        sys.exit(f"PostgreSQL unavailable: {reason}")
    totals = {"acknowledged": 0, "late": 0, "posted_late": 0, "lost": 0, "duplicated": 0, "disagreements": 0}
    try:
        for run in range(args.runs):
            with tempfile.TemporaryDirectory(prefix="bench-race-") as tmp:
                f = race(pg.new_database(), Path(tmp), seconds=args.seconds, evaluators=args.evaluators,
                         lease_seconds=args.lease_seconds, kill_every=args.kill_every, seed=run)
            print(f"run {run + 1}: {f.line()}")
            for what in ("lost", "duplicated", "disagreements"):
                for line in getattr(f, what)[:5]:
                    print(f"    {what}: {line}")
            totals["acknowledged"] += f.acknowledged
            totals["late"] += f.late
            totals["posted_late"] += f.posted_late
            totals["lost"] += len(f.lost)
            totals["duplicated"] += len(f.duplicated)
            totals["disagreements"] += len(f.disagreements)
    finally:
        pg.stop()
    print(f"total over {args.runs} runs: {totals['acknowledged']} results acknowledged; {totals['posted_late']} posted "
          f"after their lease lapsed ({totals['late']} of them acknowledged); lost {totals['lost']}, duplicated "
          f"{totals['duplicated']}, disagreements {totals['disagreements']}")


if __name__ == "__main__":
    main()
