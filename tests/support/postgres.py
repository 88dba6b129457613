"""A throwaway PostgreSQL server on 127.0.0.1 for the server tests (trust auth, data in a temp folder).

Uses $PROXYBENCH_TEST_PG_URL when set (an existing server); otherwise starts one from the installed
PostgreSQL binaries (as the ``postgres`` user when the tests run as root, which PostgreSQL requires).
With $PROXYBENCH_REQUIRE_PG set (CI), a missing PostgreSQL fails the tests instead of skipping them.
"""

from __future__ import annotations

import glob
import os
import shutil
import socket
import subprocess
import tempfile
import uuid
from pathlib import Path

__all__ = ["PostgresServer", "find_bindir"]


def find_bindir() -> Path | None:
    pg_config = shutil.which("pg_config")
    if pg_config:
        out = subprocess.run([pg_config, "--bindir"], capture_output=True, text=True).stdout.strip()
        if out and Path(out, "initdb").exists():
            return Path(out)
    for cand in sorted(glob.glob("/usr/lib/postgresql/*/bin"), reverse=True):
        if Path(cand, "initdb").exists():
            return Path(cand)
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class PostgresServer:
    """Start with :meth:`start`, make a fresh database per test with :meth:`new_database`, :meth:`stop`."""

    def __init__(self) -> None:
        self.base_url = os.environ.get("PROXYBENCH_TEST_PG_URL")
        self.tmp: str | None = None
        self.bindir: Path | None = None

    def _as_owner(self, argv: list[str]) -> list[str]:
        return ["runuser", "-u", "postgres", "--", *argv] if os.geteuid() == 0 else argv

    def start(self) -> str | None:
        """Returns None when ready, else the reason PostgreSQL is unavailable."""
        if self.base_url:
            return None
        self.bindir = find_bindir()
        if self.bindir is None:
            return "PostgreSQL binaries not found (apt-get install postgresql)"
        self.tmp = tempfile.mkdtemp(prefix="pbpg-")
        os.chmod(self.tmp, 0o777)
        data, sock = Path(self.tmp, "data"), Path(self.tmp)
        if os.geteuid() == 0:
            shutil.chown(self.tmp, "postgres")
        port = _free_port()
        init = subprocess.run(self._as_owner([str(self.bindir / "initdb"), "-D", str(data), "-U", "postgres",
                                              "--auth=trust", "-E", "UTF8", "--no-sync"]),
                              capture_output=True, text=True)
        if init.returncode != 0:
            return f"initdb failed: {init.stderr.strip()[-300:]}"
        opts = f"-p {port} -k {sock} -c listen_addresses=127.0.0.1 -c fsync=off -c max_connections=300"
        run = subprocess.run(self._as_owner([str(self.bindir / "pg_ctl"), "-D", str(data), "-o", opts,
                                             "-l", str(Path(self.tmp, "log")), "-w", "start"]),
                             capture_output=True, text=True)
        if run.returncode != 0:
            return f"pg_ctl start failed: {run.stderr.strip()[-300:]}"
        self.base_url = f"postgresql+psycopg://postgres@127.0.0.1:{port}/postgres"
        return None

    def new_database(self) -> str:
        """A fresh, empty database; returns its SQLAlchemy URL."""
        from sqlalchemy import create_engine, text

        name = "t_" + uuid.uuid4().hex[:12]
        engine = create_engine(self.base_url, isolation_level="AUTOCOMMIT")
        with engine.connect() as conn:
            conn.execute(text(f'CREATE DATABASE "{name}"'))
        engine.dispose()
        return self.base_url.rsplit("/", 1)[0] + "/" + name

    def stop(self) -> None:
        if self.tmp and self.bindir:
            subprocess.run(self._as_owner([str(self.bindir / "pg_ctl"), "-D", str(Path(self.tmp, "data")),
                                           "-m", "immediate", "stop"]), capture_output=True)
            shutil.rmtree(self.tmp, ignore_errors=True)
