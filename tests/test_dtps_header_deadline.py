"""Issue 38 item 2, the rest: a deadline on request headers in front of the DTPS serve's HTTP server, so that a
client that sends half a request and stalls (a slow-loris) cannot hold a connection, while other clients are served.

The bridge's :class:`HeaderDeadline` is tried twice: on a plain aiohttp server in a process of its own (this
environment's aiohttp; always runs), and in the bridge itself (the SDK environment's dtps-http server; ``sdk``).
Every wait is bounded; no speed is asserted.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from proxybench.dtps.link import BRIDGE, BridgeLink
from support.dtps import free_port, sdk

#: a plain aiohttp server behind the bridge's HeaderDeadline (bridge.py loaded by path, as the SDK's Python does)
SERVER = f"""
import asyncio, importlib.util, sys
spec = importlib.util.spec_from_file_location("bridge", {str(BRIDGE)!r})
bridge = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bridge)
from aiohttp import web

async def main():
    bridge.HeaderDeadline(float(sys.argv[2]), float(sys.argv[3])).install()
    app = web.Application()
    app.router.add_get("/", lambda request: web.Response(text="ok"))
    runner = web.AppRunner(app)
    await runner.setup()
    await web.TCPSite(runner, "127.0.0.1", int(sys.argv[1])).start()
    print("ready", flush=True)
    await asyncio.sleep(300)

asyncio.run(main())
"""


def _get(port: int) -> bytes:
    """The first bytes of the answer to a whole GET / (b'': none within 5 s)."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
        s.sendall(b"GET / HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        try:
            return s.recv(64)
        except OSError:
            return b""


def _closed_by_server(sock: socket.socket, within: float = 20.0) -> bool:
    """Whether the server closes ``sock`` (EOF or reset) before ``within`` s have passed."""
    sock.settimeout(within)
    try:
        return sock.recv(1024) == b""
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False


def _slow_loris(port: int, idle_first: bool = False) -> socket.socket:
    """A connection that sends half a request line and stalls (after one whole request, with ``idle_first``)."""
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    if idle_first:
        s.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
        answer = b""
        while not answer.endswith(b"ok"):  # the whole answer (its body is "ok"), so that what comes next is EOF
            chunk = s.recv(1024)
            assert chunk, answer
            answer += chunk
        assert answer.startswith(b"HTTP/1.1 200")
    s.sendall(b"GET /robot/map_0/vehic")
    return s


@pytest.fixture
def plain_server():
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-c", SERVER, str(port), "1.0", "1.5"], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "ready\n"
        yield port
    finally:
        proc.kill()
        proc.wait()


def test_half_a_header_is_closed_and_others_are_served(plain_server: int) -> None:
    stalled = [_slow_loris(plain_server) for _ in range(3)]
    assert _get(plain_server).startswith(b"HTTP/1.1 200")  # served meanwhile
    for s in stalled:
        assert _closed_by_server(s), "a connection with half a header was held"
        s.close()
    assert _get(plain_server).startswith(b"HTTP/1.1 200")


def test_half_a_second_request_on_a_kept_alive_connection_is_closed(plain_server: int) -> None:
    s = _slow_loris(plain_server, idle_first=True)
    assert _closed_by_server(s), "a kept-alive connection with half a next request was held"
    s.close()
    assert _get(plain_server).startswith(b"HTTP/1.1 200")


@sdk
def test_the_dtps_bridge_closes_a_slow_loris_and_still_serves(tmp_path: Path) -> None:
    port = free_port()
    link = BridgeLink(["server", "--host", "127.0.0.1", "--port", str(port), "--name", "map_0/vehicle_0",
                       "--header-timeout", "1", "--idle-timeout", "2"], start_timeout=120)
    try:
        stalled = [_slow_loris(port) for _ in range(5)]
        assert _get(port).startswith(b"HTTP/1.1 "), "the robot did not answer beside the stalled clients"
        for s in stalled:
            assert _closed_by_server(s), "the robot's server held a connection with half a header"
            s.close()
        deadline = time.monotonic() + 10
        while not _get(port).startswith(b"HTTP/1.1 ") and time.monotonic() < deadline:
            time.sleep(0.1)
        assert _get(port).startswith(b"HTTP/1.1 ") and link.alive
        tail = "\n".join(link.stderr_tail())
        assert "request headers did not arrive within 1 s" in tail and "Traceback" not in tail, tail
    finally:
        link.close()
