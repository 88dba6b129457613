"""Challenges server under bounded load on 127.0.0.1: throughput, p50/p99 latency and errors.

    .venv/bin/python benchmarks/bench_server.py                 # 200 clients × 60 s, SQLite then PostgreSQL
    .venv/bin/python benchmarks/bench_server.py --quick         # 20 clients × 5 s
    .venv/bin/python benchmarks/bench_server.py --db sqlite --clients 100 --seconds 30 --workers 2

A real ``proxybench serve`` process serves (``--workers``: its uvicorn worker processes; default as
``serve`` chooses: 1 on SQLite, min(cores, 4) on PostgreSQL); this process runs the clients as asyncio
tasks on one aiohttp connection pool (httpx's async client saturated a core at ~60 requests/s and measured
itself, not the server). Each client loops over a mix like a busy challenge: 70 % leaderboard
reads, 10 % queue listings, 10 % submissions, 10 % lease + result (an evaluator with an instant "run").
By default the clients do not pause (closed loop: throughput is what the server can do, and the mean
latency is clients / throughput, Little's law); ``--rate R`` paces them to R operations/s together,
to measure the latency at that load. The server's CPU time per request is printed too: on a shared
machine it is steadier than throughput.
PostgreSQL is a throwaway server started from the installed binaries (or $PROXYBENCH_TEST_PG_URL).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import random
import sys
import tempfile
import time
from pathlib import Path

import aiohttp
import httpx
import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.live_server import LiveServer
from support.postgres import PostgresServer

SCORES = {"driven_lanedir_consec_median": 5.0, "survival_time_median": 60.0,
          "deviation_center_line_median": 0.1, "in_drivable_lane_median": 0.0}
OPS = ("leaderboard", "jobs", "submit", "lease+result", "health")
WEIGHTS = (0.7, 0.1, 0.1, 0.1, 0.0)  # the mix; --only OP runs one operation alone (to profile it)


async def _client(i: int, http: aiohttp.ClientSession, url: str, admin: dict, ev: dict, until: float,
                  lat: dict[str, list[float]], errors: dict[str, int], weights: tuple[float, ...],
                  period: float = 0.0) -> None:
    rng = random.Random(i)
    api = url + "/api/v1"
    n = 0
    due = time.perf_counter() + rng.uniform(0, period)  # paced clients start spread over one period
    while time.perf_counter() < until:
        if period:  # paced: one operation per period (never more; late ones go at once)
            wait = due - time.perf_counter()
            if wait > 0:
                await asyncio.sleep(wait)
            due = max(due + period, time.perf_counter() - period)
            if time.perf_counter() >= until:
                break
        op = rng.choices(OPS, weights)[0]
        t0 = time.perf_counter()
        try:
            if op == "health":
                async with http.get(f"{api}/health") as r:
                    await r.read()
                    ok = r.status == 200
            elif op == "leaderboard":
                async with http.get(f"{api}/leaderboards/aido_lf", headers=admin) as r:
                    await r.read()
                    ok = r.status == 200
            elif op == "jobs":
                async with http.get(f"{api}/jobs", params={"limit": 20}, headers=admin) as r:
                    await r.read()
                    ok = r.status == 200
            elif op == "submit":
                n += 1
                body = {"label": f"c{i}-{n}", "agent": "vision", "benchmark": "aido_lf"}
                async with http.post(f"{api}/submissions", headers=admin, json=body) as r:
                    await r.read()
                    ok = r.status == 201
            else:
                async with http.post(f"{api}/jobs/lease", headers=ev,
                                     json={"evaluator": f"e{i}", "features": ["sim"]}) as r:
                    job = await r.json() if r.status == 200 else None
                    ok = r.status in (200, 204)
                if job is not None:
                    body = {"evaluator": f"e{i}", "lease_id": job["lease_id"], "status": "success",
                            "public_scores": SCORES, "hidden_scores": SCORES}
                    async with http.post(f"{api}/jobs/{job['job_id']}/result", headers=ev, json=body) as r:
                        await r.read()
                        ok = r.status == 201
        except (TimeoutError, aiohttp.ClientError):
            ok = False
        lat[op].append(time.perf_counter() - t0)
        if not ok:
            errors[op] += 1


async def _load(url: str, admin_token: str, clients: int, seconds: float,
                weights: tuple[float, ...] = WEIGHTS, rate: float | None = None) -> tuple[dict, dict, float]:
    conn = aiohttp.TCPConnector(limit=clients)
    async with aiohttp.ClientSession(connector=conn, timeout=aiohttp.ClientTimeout(total=120)) as http:
        admin = {"Authorization": f"Bearer {admin_token}"}
        async with http.post(f"{url}/api/v1/users", headers=admin,
                             json={"name": f"bench-ev-{time.time_ns()}", "role": "evaluator"}) as r:
            ev = {"Authorization": f"Bearer {(await r.json())['token']}"}
        lat: dict[str, list[float]] = {op: [] for op in OPS}
        errors = dict.fromkeys(OPS, 0)
        t0 = time.perf_counter()
        period = clients / rate if rate else 0.0
        await asyncio.gather(*(_client(i, http, url, admin, ev, t0 + seconds, lat, errors, weights, period)
                               for i in range(clients)))
        return lat, errors, time.perf_counter() - t0


def _group_cpu_seconds(pgid: int) -> float:
    """CPU time (user + system) of every process in a process group: the server and its workers.

    On a shared machine wall-clock throughput depends on the neighbours; CPU per request does not."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid:  # field 5 of stat: the process group
            total += (int(fields[11]) + int(fields[12])) / tick  # utime, stime
    return total


def run_case(db: str, clients: int, seconds: float, console: Console, workers: int | None = None,
             weights: tuple[float, ...] = WEIGHTS, rate: float | None = None) -> list[tuple]:
    tmp = Path(tempfile.mkdtemp(prefix="pbbench-"))
    (tmp / "data").mkdir()
    pg = None
    url = None
    if db == "postgresql":
        pg = PostgresServer()
        reason = pg.start()
        if reason:
            console.print(f"[yellow]PostgreSQL skipped: {reason}[/yellow]")
            return []
        url = pg.new_database()
    server = LiveServer(tmp / "data", url, workers=workers).start()
    try:
        console.print(f"{db}: {clients} clients × {seconds:g} s on {server.url} ({workers or 'default'} workers) …")
        cpu0 = _group_cpu_seconds(server.proc.pid)
        lat, errors, wall = asyncio.run(_load(server.url, server.admin_token, clients, seconds, weights, rate))
        cpu = _group_cpu_seconds(server.proc.pid) - cpu0
        board = httpx.get(f"{server.url}/api/v1/leaderboards/aido_lf?limit=1", timeout=60,
                          headers={"Authorization": f"Bearer {server.admin_token}"}).json()
        served = sum(len(v) for v in lat.values())
        rows_total = board.get("total", len(board["rows"]))
        console.print(f"  the aido_lf board ended with {rows_total} rows; server CPU {cpu:.1f} s = "
                      f"{1000 * cpu / max(served, 1):.2f} ms per request ({cpu / wall:.2f} cores busy)")
    finally:
        server.stop()
        if pg:
            pg.stop()
    rows = []
    for op in OPS:
        a = np.array(lat[op]) * 1000
        if len(a):
            rows.append((db, op, len(a) / wall, np.percentile(a, 50), np.percentile(a, 99), errors[op]))
    total = sum(len(v) for v in lat.values())
    allv = np.concatenate([np.array(v) for v in lat.values() if v]) * 1000
    rows.append((db, "all", total / wall, np.percentile(allv, 50), np.percentile(allv, 99), sum(errors.values())))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--db", choices=("sqlite", "postgresql", "both"), default="both")
    ap.add_argument("--clients", type=int, default=200)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--workers", type=int, default=None, help="server worker processes [as serve chooses]")
    ap.add_argument("--only", choices=OPS, default=None, help="one operation alone instead of the mix")
    ap.add_argument("--rate", type=float, default=None,
                    help="offered load [operations/s over all clients]: each client paces itself, and the "
                         "latency is the server's at that load (default: closed loop, no pause between "
                         "operations, where the mean latency is clients / throughput by Little's law)")
    ap.add_argument("--quick", action="store_true", help="20 clients × 5 s")
    args = ap.parse_args()
    if args.quick:
        args.clients, args.seconds = 20, 5.0
    console = Console()
    rows = []
    for db in (("sqlite", "postgresql") if args.db == "both" else (args.db,)):
        weights = WEIGHTS if args.only is None else tuple(float(op == args.only) for op in OPS)
        rows += run_case(db, args.clients, args.seconds, console, args.workers, weights, args.rate)
    load = f"paced at {args.rate:g} operations/s" if args.rate else "closed loop"
    table = Table(title=f"proxybench server load — {args.clients} clients ({load}) × {args.seconds:g} s, "
                        f"{os.cpu_count()} cores, {args.workers or 'default'} uvicorn workers, clients on the same "
                        "machine")
    for col in ("database", "operation", "req/s", "p50 ms", "p99 ms", "errors"):
        table.add_column(col, justify="left" if col in ("database", "operation") else "right")
    for db, op, rps, p50, p99, err in rows:
        table.add_row(db, op, f"{rps:,.0f}", f"{p50:.1f}", f"{p99:.1f}", str(err))
    console.print(table)


if __name__ == "__main__":
    main()
