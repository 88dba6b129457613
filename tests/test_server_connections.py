"""Connections that send nothing, or half a request, hold nothing for long (issue 23 §2): the server closes a
connection whose headers are not complete within ``header_timeout``, caps connections and request bodies
per client address, never counts requests without a body, and raises its open-file limit at start.

The soak runs a real ``proxybench serve`` started with the usual soft limit of 1,024 open files (as a
deployment starts it) against thousands of idle and half-header sockets from several processes, each on a
loopback address of its own; the latencies are printed, benchmarks/bench_soak.py measures them.
"""

from __future__ import annotations

import asyncio
import resource
import socket
import time

import httpx
import pytest

from proxybench.server.limits import BodyRules, RequestGate
from support.live_server import LiveServer
from support.soak import soak


def _run_gate(rules: BodyRules, requests: list[tuple[str, str, bytes | None]]) -> list[int | None]:
    """Requests (client address, method, body or None) through a RequestGate, the bodies of the first ones never
    finished; the status each got within a second (None: still waiting for its body)."""

    async def app(scope, receive, send) -> None:
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"ok"})

    gate = RequestGate(app, body=rules, concurrency=4)
    statuses: list[int | None] = [None] * len(requests)

    async def one(k: int, address: str, method: str, body: bytes | None) -> None:
        headers = [] if body is None else [(b"content-length", str(len(body) * 2).encode())]
        scope = {"type": "http", "method": method, "path": "/api/v1/x", "headers": headers,
                 "client": (address, 40000 + k)}
        stall = asyncio.Event()

        async def receive() -> dict:
            if body is not None and not stall.is_set():
                stall.set()
                return {"type": "http.request", "body": body, "more_body": True}
            if body is not None:
                await asyncio.sleep(3600)  # half a body, then nothing
            return {"type": "http.request", "body": b"", "more_body": False}

        async def send(message: dict) -> None:
            if message["type"] == "http.response.start":
                statuses[k] = message["status"]

        await gate(scope, receive, send)

    async def main() -> None:
        tasks = []
        for k, (address, method, body) in enumerate(requests):
            tasks.append(asyncio.create_task(one(k, address, method, body)))
            await asyncio.sleep(0.01)
        await asyncio.sleep(1.0)
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    asyncio.run(main())
    return statuses


def test_requests_without_a_body_never_wait_behind_stalled_bodies() -> None:
    rules = BodyRules(limits=[], default=1 << 20, timeout=30.0, max_readers=2)
    got = _run_gate(rules, [("10.0.0.1", "POST", b"x"), ("10.0.0.2", "POST", b"x"), ("10.0.0.1", "GET", None),
                            ("10.0.0.3", "GET", None)])
    assert got == [None, None, 200, 200]  # the two stalled bodies fill the readers; GETs are never counted


def test_request_bodies_are_capped_per_client_address() -> None:
    rules = BodyRules(limits=[], default=1 << 20, timeout=30.0, max_readers=100, max_readers_per_address=2)
    got = _run_gate(rules, [("10.0.0.1", "POST", b"x"), ("10.0.0.1", "POST", b"x"), ("10.0.0.1", "POST", b"x"),
                            ("10.0.0.2", "POST", b"x"), ("10.0.0.1", "GET", None)])
    assert got == [None, None, 503, None, 200]  # another address's body is still received


def _closed_within(s: socket.socket, seconds: float) -> tuple[bool, bytes]:
    s.settimeout(seconds)
    try:
        data = s.recv(4096)
    except TimeoutError:
        return False, b""
    except OSError:
        return True, b""
    return True, data


def test_idle_and_half_header_connections_are_closed_and_capped_per_address(tmp_path) -> None:
    data = tmp_path / "data"
    data.mkdir()
    env = {"PROXYBENCH_SERVER_HEADER_TIMEOUT": "2", "PROXYBENCH_SERVER_MAX_CONNECTIONS_PER_ADDRESS": "4"}
    server = LiveServer(data, workers=1, env=env).start()
    try:
        idle = socket.create_connection(("127.0.0.1", server.port), source_address=("127.0.0.2", 0))
        half = socket.create_connection(("127.0.0.1", server.port), source_address=("127.0.0.2", 0))
        half.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\n")
        kept = socket.create_connection(("127.0.0.1", server.port), source_address=("127.0.0.2", 0))
        kept.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\n\r\n")
        reply = b""
        while not reply.endswith(b"}"):
            reply += kept.recv(4096)
        assert reply.startswith(b"HTTP/1.1 200")  # then idle, kept alive
        fourth = socket.create_connection(("127.0.0.1", server.port), source_address=("127.0.0.2", 0))
        fifth = socket.create_connection(("127.0.0.1", server.port), source_address=("127.0.0.2", 0))
        closed, said = _closed_within(fifth, 2.0)
        assert closed and said.startswith(b"HTTP/1.1 503") and b"too many connections" in said, said
        assert httpx.get(server.url + "/api/v1/health", timeout=10).status_code == 200  # 127.0.0.1 is not capped
        t0 = time.monotonic()
        for s in (idle, half, kept, fourth):
            closed, said = _closed_within(s, 8.0)
            assert closed and said == b"", (closed, said)
        assert time.monotonic() - t0 < 8.0
        for s in (idle, half, kept, fourth, fifth):
            s.close()
    finally:
        server.stop()


@pytest.mark.slow
def test_thousands_of_idle_and_half_header_sockets_do_not_stop_the_server(tmp_path) -> None:
    if resource.getrlimit(resource.RLIMIT_NOFILE)[1] < 4096:  # the server cannot lift its limit past 1,024 here
        pytest.skip(f"this machine's hard RLIMIT_NOFILE is {resource.getrlimit(resource.RLIMIT_NOFILE)[1]} (< 4,096)")
    data = tmp_path / "data"
    data.mkdir()
    server = LiveServer(data, workers=2, open_files=1024, env={"PROXYBENCH_SERVER_HEADER_TIMEOUT": "8"}).start()
    try:  # the traffic runs while the sockets are open (they are closed 8 s after they were accepted)
        figures = soak(server.url, server.port, server.admin_token, processes=5, per_process=500, traffic_seconds=4.0,
                       hold=40.0)  # the hold leaves a loaded CI machine 32 s past the header timeout
    finally:
        server.stop()
    said = figures.line()
    print("\n" + said)
    assert figures.sockets >= 2000, (said, figures.floods)  # more than the 1,024 files the server started with
    assert figures.failures == [], (said, figures.failures[:5])
    assert len(figures.latencies["health"]) >= 5 and len(figures.latencies["leaderboard"]) >= 5, said
    assert all(f["open_at_end"] == 0 for f in figures.floods), (said, figures.floods)  # all closed, within the hold
