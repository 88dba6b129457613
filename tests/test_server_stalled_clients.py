"""Issue 15's "done when" for the server: 50 clients hold half-sent request bodies while normal traffic runs,
on a real ``proxybench serve`` process on 127.0.0.1 (SQLite: one process; PostgreSQL: several workers).

Health checks, leaderboard reads and writes (a submission each half second) must all keep answering while
the stalled bodies are open; then every stalled client gets 408 once its body has paused for
``body_timeout`` seconds, and the connection is closed. Latencies are printed (p50 / p99), not asserted:
the machine may be busy. Before the front door read bodies ahead of admission, eight such clients froze
the API, the web console and /health.
"""

from __future__ import annotations

import socket
import threading
import time

import httpx
import numpy as np
import pytest

from support.live_server import LiveServer

STALLED = 50
BODY_TIMEOUT = 8.0  # s: the server's body_timeout in this test
TRAFFIC_SECONDS = 5.0


def _stall(port: int, kind: int, ev_token: str, source: str) -> socket.socket:
    """Open a connection from ``source`` and send headers and half of a body, then nothing more."""
    s = socket.create_connection(("127.0.0.1", port), timeout=30, source_address=(source, 0))
    if kind == 0:  # unauthenticated JSON
        head, declared = b"POST /api/v1/submissions HTTP/1.1\r\nContent-Type: application/json\r\n", 20_000
    elif kind == 1:  # an evaluator's artifact upload that stops halfway
        head = (f"PUT /api/v1/artifacts/{'0' * 64} HTTP/1.1\r\nAuthorization: Bearer {ev_token}\r\n"
                "Content-Type: application/octet-stream\r\n").encode()
        declared = 4_000_000
    elif kind == 2:  # the web console's sign-in form
        head, declared = b"POST /login HTTP/1.1\r\nContent-Type: application/x-www-form-urlencoded\r\n", 4_000
    else:  # an archive upload (with a token: without one, large uploads are refused before their body)
        head = (f"POST /api/v1/submissions/upload HTTP/1.1\r\nAuthorization: Bearer {ev_token}\r\n"
                "Content-Type: multipart/form-data; boundary=xx\r\n").encode()
        declared = 3_000_000
    half = b"x" * min(declared // 2, 100_000)
    s.sendall(head + f"Host: 127.0.0.1\r\nContent-Length: {declared}\r\n\r\n".encode() + half)
    return s


def _reader(url: str, token: str, until: float, lat: dict[str, list[float]], failures: list[str]) -> None:
    headers = {"Authorization": f"Bearer {token}"}
    with httpx.Client(base_url=url, timeout=15.0) as c:
        while time.monotonic() < until:
            for name, path in (("health", "/api/v1/health"), ("leaderboard", "/api/v1/leaderboards/aido_lf")):
                t0 = time.perf_counter()
                try:
                    r = c.get(path, headers=headers)
                    ok = r.status_code == 200
                except httpx.HTTPError as exc:
                    ok, r = False, exc
                lat[name].append(time.perf_counter() - t0)
                if not ok:
                    failures.append(f"{name}: {r}")


def _writer(url: str, token: str, until: float, lat: dict[str, list[float]], failures: list[str]) -> None:
    with httpx.Client(base_url=url, timeout=15.0, headers={"Authorization": f"Bearer {token}"}) as c:
        n = 0
        while time.monotonic() < until:
            n += 1
            t0 = time.perf_counter()
            try:
                r = c.post("/api/v1/submissions", json={"label": f"w{n}", "agent": "vision", "benchmark": "aido_lf"})
                ok = r.status_code == 201
            except httpx.HTTPError as exc:
                ok, r = False, exc
            lat["submission"].append(time.perf_counter() - t0)
            if not ok:
                failures.append(f"submission: {r}")
            time.sleep(0.5)


def _p(values: list[float], q: float) -> float:
    return float(np.percentile(np.array(values) * 1000, q)) if values else float("nan")


@pytest.mark.slow
def test_stalled_bodies_do_not_freeze_the_server(tmp_path, database_url):
    data = tmp_path / "data"
    data.mkdir()
    server = LiveServer(data, None if database_url.startswith("sqlite") else database_url,
                        env={"PROXYBENCH_SERVER_BODY_TIMEOUT": str(BODY_TIMEOUT)}).start()
    try:
        admin = server.admin_token
        with httpx.Client(base_url=server.url, timeout=15.0) as c:
            ev = c.post("/api/v1/users", headers={"Authorization": f"Bearer {admin}"},
                        json={"name": "ev", "role": "evaluator"}).json()["token"]
        t_stall = time.monotonic()
        # from two addresses other than the traffic's (one address gets at most max_readers_per_address bodies)
        stalled = [_stall(server.port, k % 4, ev, f"127.0.0.{2 + k % 2}") for k in range(STALLED)]
        time.sleep(0.5)
        lat: dict[str, list[float]] = {"health": [], "leaderboard": [], "submission": []}
        failures: list[str] = []
        until = time.monotonic() + TRAFFIC_SECONDS
        threads = [threading.Thread(target=_reader, args=(server.url, admin, until, lat, failures)) for _ in range(4)]
        threads.append(threading.Thread(target=_writer, args=(server.url, admin, until, lat, failures)))
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        traffic_end = time.monotonic()
        assert traffic_end - t_stall < BODY_TIMEOUT, "the traffic outlasted the stalls; the test proves nothing"
        # every stalled client is answered 408 once its body has paused for body_timeout, then closed
        answers = []
        for s in stalled:
            s.settimeout(BODY_TIMEOUT + 20)
            try:
                answers.append(s.recv(4096).split(b"\r\n", 1)[0].decode())
            except OSError as exc:
                answers.append(f"no answer ({exc})")
            finally:
                s.close()
        waited = time.monotonic() - t_stall
    finally:
        server.stop()
    kind = "sqlite" if database_url.startswith("sqlite") else "postgresql"
    print(f"\n{kind}: {STALLED} stalled bodies; while they were open: "
          + ", ".join(f"{name} {len(v)} requests p50 {_p(v, 50):.1f} ms p99 {_p(v, 99):.1f} ms max {_p(v, 100):.1f} ms"
                      for name, v in lat.items())
          + f"; all stalled clients answered after {waited:.1f} s")
    assert failures == [], failures[:5]
    assert len(lat["health"]) > 20 and len(lat["leaderboard"]) > 20 and len(lat["submission"]) >= 3
    assert all(a.startswith("HTTP/1.1 408") for a in answers), sorted(set(answers))
