"""Idle and half-header sockets against a real server on 127.0.0.1: /health and leaderboard latency while
they are open (issue 23 §2).

    .venv/bin/python benchmarks/bench_soak.py                       # 5 processes × 600 sockets, SQLite
    .venv/bin/python benchmarks/bench_soak.py --processes 8 --per-process 500 --workers 2

A real ``proxybench serve`` is started with the usual soft limit of 1,024 open files (as a deployment
starts it: it raises its own); flood processes (``tests/support/soak.py``), each on a loopback address of
its own (127.0.0.2, …), open their sockets and send nothing or half a request; then reader threads on
127.0.0.1 fetch /health (a new connection each time) and a leaderboard (kept alive) while the sockets are
open. Prints the sockets opened, refused at the per-address cap and closed at the header deadline, and
p50 / p99 / max latency of each read. Run it beside the same command on another checkout
(``PYTHONPATH=…/src``) to compare.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.live_server import LiveServer
from support.soak import soak


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--processes", type=int, default=5)
    p.add_argument("--per-process", type=int, default=600)
    p.add_argument("--seconds", type=float, default=6.0, help="traffic while the sockets are open")
    p.add_argument("--header-timeout", type=float, default=10.0, help="the server's (sockets close after it)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--readers", type=int, default=2)
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-soak-") as tmp:
        data = Path(tmp) / "data"
        data.mkdir()
        server = LiveServer(data, workers=args.workers, open_files=1024,
                            env={"PROXYBENCH_SERVER_HEADER_TIMEOUT": str(args.header_timeout)}).start()
        try:  # the same reads without the flood first, on the same server: the machine's own figure
            quiet = soak(server.url, server.port, server.admin_token, processes=0, traffic_seconds=args.seconds,
                         readers=args.readers)
            figures = soak(server.url, server.port, server.admin_token, processes=args.processes,
                           per_process=args.per_process, traffic_seconds=args.seconds,
                           hold=args.header_timeout + 30, readers=args.readers)
        finally:
            server.stop()
    print(figures.line())
    for name in figures.latencies:
        for label, f in (("no flood", quiet), ("flood", figures)):
            print(f"  {name:12s} {label:9s} n={len(f.latencies[name]):4d}  p50 {f.p(name, 50):7.1f} ms  "
                  f"p99 {f.p(name, 99):7.1f} ms  max {f.p(name, 100):7.1f} ms")
    for f in figures.floods:
        print(f"  flood {f['source']}: {f['opened']} opened ({f['failed']} failed to connect), {f['refused']} refused "
              f"at the cap, {f['closed'] - f['refused']} closed at the deadline, {f['open_at_end']} still open, "
              f"last close after {f['last_close_s']} s")
    for failure in figures.failures[:10]:
        print(f"  failure: {failure}")


if __name__ == "__main__":
    main()
