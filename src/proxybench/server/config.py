"""Server settings: typed, read from the environment (``PROXYBENCH_SERVER_*``) or given in code.

Built in a factory, never at import, so tests and the CLI can run several servers side by side.
"""

from __future__ import annotations

import os
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["Settings"]

_ENV_PREFIX = "PROXYBENCH_SERVER_"


class Settings(BaseModel):
    """Everything a challenges server needs to know. Sizes in bytes, times in seconds."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    data_dir: Path = Field(Path("proxybench-server"), description="artifacts, SQLite file and the admin token")
    database_url: str | None = Field(None, description="SQLAlchemy URL; default: SQLite in data_dir")
    lease_seconds: float = Field(120.0, gt=0, description="a job lease lapses this long after the last heartbeat")
    max_attempts: int = Field(3, ge=1, description="leases a job may take before it is given up")
    daily_submission_limit: int = Field(20, ge=0, description="submissions per developer per 24 h (0: no limit)")
    archive_max_bytes: int = Field(64 << 20, gt=0, description="largest agent package accepted")
    image_max_bytes: int = Field(2 << 30, gt=0, description="largest container image (OCI archive or docker save "
                                 "tarball) accepted; AIDO submissions are hundreds of MB")
    artifact_max_bytes: int = Field(256 << 20, gt=0, description="largest artifact accepted")
    max_concurrent_requests: int = Field(8, ge=1, le=200, description="requests in progress at once; "
                                         "the rest queue (one process has one GIL: more only adds switching)")
    json_max_bytes: int = Field(8 << 20, gt=0, description="largest JSON or YAML request body accepted")
    max_queued_requests: int = Field(2048, ge=1, description="requests waiting for a turn; beyond: 503")
    body_timeout: float = Field(30.0, gt=0, description="longest pause in a request body (and the grace period "
                                "before body_min_rate applies); slower: 408")
    body_min_rate: float = Field(16_384.0, gt=0, description="bytes/s a request body must average after "
                                 "body_timeout seconds")
    send_timeout: float = Field(60.0, gt=0, description="a client that reads none of its reply for this long "
                                "is disconnected")
    header_timeout: float = Field(10.0, gt=0, le=3600, description="a connection whose request headers are not "
                                  "complete this long after it opened (or after its last reply) is closed")
    idle_timeout: float = Field(15.0, gt=0, le=3600, description="a kept-alive connection idle this long between "
                                "requests is closed")
    max_connections_per_address: int = Field(256, ge=0, description="open connections per client address and "
                                             "worker process; beyond: 503 and closed (0: no cap, e.g. behind a "
                                             "front that limits them itself)")
    max_readers_per_address: int = Field(32, ge=1, description="request bodies being received at once from one "
                                         "client address; beyond: 503 (requests without a body never count)")
    token_cache_seconds: float = Field(2.0, ge=0, description="a process remembers a checked token this long "
                                       "(a revoked one is refused at once by the process that revoked it, by "
                                       "the others within this time; 0: check every request)")
    session_seconds: float = Field(8 * 3600.0, gt=0, description="how long a web console sign-in lasts")
    workers: int = Field(1, ge=1, le=64, description="server processes (uvicorn workers) sharing the port")

    @property
    def url(self) -> str:
        """The database URL in effect (SQLite in ``data_dir`` unless one was given)."""
        return self.database_url or f"sqlite:///{(self.data_dir / 'server.sqlite3').resolve()}"

    @property
    def artifact_dir(self) -> Path:
        return self.data_dir / "artifacts"

    @classmethod
    def from_env(cls, **overrides: object) -> Settings:
        """Settings from ``PROXYBENCH_SERVER_<FIELD>`` variables, then ``overrides`` (those not None)."""
        values: dict[str, object] = {}
        for name in cls.model_fields:
            raw = os.environ.get(_ENV_PREFIX + name.upper())
            if raw is not None:
                values[name] = raw
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls.model_validate(values)
