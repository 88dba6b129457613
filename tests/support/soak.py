"""Idle and half-header sockets against a live server, from several processes, while /health and a
leaderboard are read (issue 23 §2). Used by tests/test_server_connections.py and benchmarks/bench_soak.py.

Each flood process (``python soak.py flood PORT SOURCE COUNT HOLD``) binds its sockets to a loopback
address of its own (127.0.0.2, 127.0.0.3, …: one "client address" each, so the server's per-address cap
applies to it and not to the readers on 127.0.0.1), opens COUNT connections, sends nothing on half of them
and half a request line and headers on the others, then waits up to HOLD seconds for the server to close
them, and prints what happened as JSON.
"""

from __future__ import annotations

import json
import resource
import selectors
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

__all__ = ["SoakFigures", "soak"]

HALF_HEADER = b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: "


def flood(port: int, source: str, count: int, hold: float) -> dict:
    """Open ``count`` sockets from ``source``; what the server did with them (see the module's docstring)."""
    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
    connecting = selectors.DefaultSelector()  # two selectors: a socket the server already answered or closed must
    sel = selectors.DefaultSelector()  # not come back to the connect loop as if it were still connecting
    pending = {}
    for k in range(count):
        s = socket.socket()
        s.setblocking(False)
        s.bind((source, 0))
        s.connect_ex(("127.0.0.1", port))
        pending[s] = k
        connecting.register(s, selectors.EVENT_WRITE)
    opened, failed = [], 0
    deadline = time.monotonic() + 30  # a loaded machine (CI runs the suite beside this) connects slowly
    while pending and time.monotonic() < deadline:
        for key, _ in connecting.select(0.5):
            s = key.fileobj
            connecting.unregister(s)
            k = pending.pop(s)
            if s.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR):
                failed += 1
                s.close()
                continue
            try:
                if k % 2:
                    s.send(HALF_HEADER)
            except OSError:  # the server may already have refused it (503 and close)
                failed += 1
                s.close()
                continue
            opened.append(s)
            sel.register(s, selectors.EVENT_READ)
    for s in pending:
        failed += 1
        connecting.unregister(s)
        s.close()
    connecting.close()
    t0 = time.monotonic()
    print(json.dumps({"ready": len(opened)}), flush=True)
    refused = closed = 0
    last_close = 0.0
    left = set(opened)
    while left and time.monotonic() - t0 < hold:
        for key, _ in sel.select(0.2):
            s = key.fileobj
            try:
                data = s.recv(4096)
            except OSError:
                data = b""
            if data.startswith(b"HTTP/1.1 503"):
                refused += 1
            elif data:
                continue  # a reply on a half-header socket would mean it was served: not expected
            closed += 1
            last_close = time.monotonic() - t0
            sel.unregister(s)
            s.close()
            left.discard(s)
    for s in left:
        s.close()
    return {"source": source, "asked": count, "opened": len(opened), "failed": failed, "refused": refused,
            "closed": closed, "open_at_end": len(left), "last_close_s": round(last_close, 2)}


@dataclass
class SoakFigures:
    floods: list[dict] = field(default_factory=list)
    latencies: dict[str, list[float]] = field(default_factory=lambda: {"health": [], "leaderboard": []})
    failures: list[str] = field(default_factory=list)

    @property
    def sockets(self) -> int:
        return sum(f["opened"] for f in self.floods)

    def p(self, name: str, q: float) -> float:
        import numpy as np

        v = self.latencies[name]
        return float(np.percentile(np.array(v) * 1000, q)) if v else float("nan")

    def line(self) -> str:
        per = ", ".join(f"{name} {len(v)} requests p50 {self.p(name, 50):.1f} ms p99 {self.p(name, 99):.1f} ms"
                        for name, v in self.latencies.items())
        refused = sum(f["refused"] for f in self.floods)
        closed = sum(f["closed"] for f in self.floods)
        open_at_end = sum(f["open_at_end"] for f in self.floods)
        last = max((f["last_close_s"] for f in self.floods), default=0.0)
        return (f"{self.sockets} idle/half-header sockets from {len(self.floods)} processes ({refused} refused at the "
                f"per-address cap, {closed - refused} closed at the header deadline, last after {last:.1f} s, "
                f"{open_at_end} still open); while open: {per}; {len(self.failures)} failures")


def _fresh_get(port: int, path: str, token: str) -> int:
    """GET on a new connection (a new client must still get in), with a plain socket: the client's own cost
    stays out of the figure. The reply's status."""
    with socket.create_connection(("127.0.0.1", port), timeout=20) as s:
        s.sendall(f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {token}\r\n"
                  "Connection: close\r\n\r\n".encode())
        reply = b""
        while chunk := s.recv(65536):
            reply += chunk
    return int(reply.split(b" ", 2)[1]) if reply.startswith(b"HTTP/1.1 ") else 0


def _reader(url: str, port: int, token: str, until: float, figures: SoakFigures) -> None:
    import httpx

    with httpx.Client(base_url=url, timeout=20.0, headers={"Authorization": f"Bearer {token}"}) as kept:
        while time.monotonic() < until:
            for name in ("health", "leaderboard"):
                t0 = time.perf_counter()
                try:  # /health on a new connection each time; the leaderboard on a kept-alive one
                    status = _fresh_get(port, "/api/v1/health", token) if name == "health" else \
                        kept.get("/api/v1/leaderboards/aido_lf").status_code
                except (OSError, httpx.HTTPError) as exc:
                    status = repr(exc)
                figures.latencies[name].append(time.perf_counter() - t0)
                if status != 200:
                    figures.failures.append(f"{name}: {status}")


def soak(url: str, port: int, token: str, *, processes: int = 5, per_process: int = 500, traffic_seconds: float = 5.0,
         hold: float = 20.0, readers: int = 2, settle: float = 1.0) -> SoakFigures:
    """Flood a server on 127.0.0.1:``port`` while ``readers`` threads read /health and a leaderboard."""
    figures = SoakFigures()
    procs = [subprocess.Popen([sys.executable, __file__, "flood", str(port), f"127.0.0.{2 + i}", str(per_process),
                               str(hold)], stdout=subprocess.PIPE, text=True) for i in range(processes)]
    try:
        for p in procs:  # every flood's sockets are open before the traffic starts
            assert p.stdout is not None
            p.stdout.readline()
        time.sleep(settle)  # ... and the server has taken them from its accept queue
        until = time.monotonic() + traffic_seconds
        threads = [threading.Thread(target=_reader, args=(url, port, token, until, figures)) for _ in range(readers)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(traffic_seconds + 120)
        for p in procs:
            out, _ = p.communicate(timeout=hold + 60)
            figures.floods.append(json.loads(out.strip().splitlines()[-1]))
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    return figures


if __name__ == "__main__" and sys.argv[1:2] == ["flood"]:
    print(json.dumps(flood(int(sys.argv[2]), sys.argv[3], int(sys.argv[4]), float(sys.argv[5]))), flush=True)
