"""A real ``proxybench serve`` process on 127.0.0.1 (a free port), for tests that kill and restart it."""

from __future__ import annotations

import os
import resource
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

__all__ = ["LiveServer", "free_port"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class LiveServer:
    def __init__(self, data_dir: Path, database_url: str | None = None, lease_seconds: float = 120.0,
                 evaluators: int = 0, workers: int | None = None, env: dict[str, str] | None = None,
                 open_files: int | None = None) -> None:
        self.data_dir = data_dir
        self.database_url = database_url
        self.lease_seconds = lease_seconds
        self.evaluators = evaluators
        self.workers = workers
        self.env = env or {}
        self.open_files = open_files  # the soft RLIMIT_NOFILE it starts with (the usual 1,024: as deployed)
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None

    def start(self, timeout: float = 60.0) -> LiveServer:
        cmd = [sys.executable, "-m", "proxybench.cli", "serve", "--port", str(self.port), "--data-dir",
               str(self.data_dir), "--lease-seconds", str(self.lease_seconds), "--evaluators", str(self.evaluators)]
        if self.database_url:
            cmd += ["--database-url", self.database_url]
        if self.workers is not None:
            cmd += ["--workers", str(self.workers)]
        log = open(self.data_dir.parent / f"server-{self.port}.log", "ab")  # noqa: SIM115 - lives with the process
        self.proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                                     env={**os.environ, **self.env}, preexec_fn=self._limits)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}; see {log.name}")
            try:
                if httpx.get(self.url + "/api/v1/health", timeout=1.0).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        raise TimeoutError(f"server on {self.url} not up after {timeout} s")

    def _limits(self) -> None:
        if self.open_files is not None:
            _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
            resource.setrlimit(resource.RLIMIT_NOFILE, (self.open_files, hard))

    @property
    def admin_token(self) -> str:
        return (self.data_dir / "admin.token").read_text().strip()

    def kill(self, sig: int = signal.SIGKILL) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, sig)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:  # a graceful stop that hangs must not hang the caller
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(15)

    def stop(self) -> None:
        self.kill(signal.SIGTERM)
