"""A small HTTP client for the challenges server, used by the CLI and by evaluators.

Connection failures and 5xx replies are retried with backoff (a server restart is a pause, not a lost
result); 4xx replies raise :class:`ServerError` carrying the server's message. The evaluators' calls
(lease, heartbeat, result) speak the shared models of :mod:`proxybench.contract`.

Tokens never travel on a command line (any user can read another's ``/proc/PID/cmdline``):
:func:`load_token` takes them from ``$PROXYBENCH_TOKEN``, a file named by ``$PROXYBENCH_TOKEN_FILE`` or
``--token-file``, or a default file.
"""

from __future__ import annotations

import hashlib
import os
import stat
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx

from proxybench.contract import Heartbeat, HeartbeatReply, Lease, LeaseRequest, ResultUpload

__all__ = ["TOKEN_ENV", "TOKEN_FILE_ENV", "ServerClient", "ServerError", "TokenError", "load_token"]

API = "/api/v1"
TOKEN_ENV = "PROXYBENCH_TOKEN"
TOKEN_FILE_ENV = "PROXYBENCH_TOKEN_FILE"


class TokenError(RuntimeError):
    """No usable token: the message says where one was looked for."""


def load_token(token_file: Path | None = None, default_file: Path | None = None) -> tuple[str, str]:
    """(token, where it came from): ``token_file`` when given, else ``$PROXYBENCH_TOKEN``, else the file
    named by ``$PROXYBENCH_TOKEN_FILE``, else ``default_file``. Raises :class:`TokenError` saying what was
    tried. A token file that other users can read is still used; the second element then says so."""
    if token_file is None:
        env = os.environ.get(TOKEN_ENV, "").strip()
        if env:
            return env, f"${TOKEN_ENV}"
    files = [("--token-file", token_file)] if token_file is not None else \
        [(f"${TOKEN_FILE_ENV}", Path(p)) for p in [os.environ.get(TOKEN_FILE_ENV)] if p] + \
        [("the default file", p) for p in [default_file] if p is not None]
    tried = []
    for where, path in files:
        try:
            text = path.read_text().strip()
            mode = path.stat().st_mode
        except OSError as exc:
            tried.append(f"{where} {path}: {exc.strerror or exc}")
            continue
        if not text:
            tried.append(f"{where} {path}: empty")
            continue
        if mode & (stat.S_IRGRP | stat.S_IROTH):
            return text, f"{path} (warning: other users can read it; chmod 600 {path})"
        return text, str(path)
    raise TokenError(f"no API token: set ${TOKEN_ENV}, or pass --token-file FILE (or set ${TOKEN_FILE_ENV})"
                     + (f"; tried {'; '.join(tried)}" if tried else ""))


class ServerError(RuntimeError):
    """A request the server refused (4xx) or that never got through; ``status`` is 0 for the latter."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(f"{status}: {message}" if status else message)
        self.status = status
        self.message = message


class ServerClient:
    """``ServerClient("http://127.0.0.1:8000", token)``; every method returns the decoded JSON reply."""

    def __init__(self, url: str, token: str, *, timeout: float = 30.0, retry_for: float = 60.0) -> None:
        self.url = url.rstrip("/")
        self.retry_for = retry_for
        self.http = httpx.Client(base_url=self.url + API, timeout=timeout,
                                 headers={"Authorization": f"Bearer {token.strip()}"})

    def close(self) -> None:
        self.http.close()

    def __enter__(self) -> ServerClient:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        """Send, retrying connection errors and 5xx for up to ``retry_for`` seconds; raise on 4xx."""
        deadline = time.monotonic() + self.retry_for
        delay = 0.2
        while True:
            try:
                r = self.http.request(method, path, **kwargs)
            except httpx.TransportError as exc:
                if time.monotonic() > deadline:
                    raise ServerError(0, f"cannot reach {self.url} ({exc})") from None
            else:
                if r.status_code < 500:
                    if r.status_code >= 400:
                        try:
                            detail = r.json().get("detail", r.text)
                        except ValueError:
                            detail = r.text
                        raise ServerError(r.status_code, str(detail))
                    return r
                if time.monotonic() > deadline:
                    raise ServerError(r.status_code, r.text[:500])
            time.sleep(delay)
            delay = min(delay * 2, 5.0)

    def get(self, path: str, **params: Any) -> Any:
        return self.request("GET", path, params={k: v for k, v in params.items() if v is not None}).json()

    def post(self, path: str, body: dict[str, Any] | None = None) -> Any:
        r = self.request("POST", path, json=body or {})
        return None if r.status_code == 204 else r.json()

    # -- developers --------------------------------------------------------------------------------

    def me(self) -> dict[str, Any]:
        return self.get("/me")

    def submit(self, agent: str, label: str, *, benchmark: str | None = None, path: str | None = None,
               description: str = "") -> dict[str, Any]:
        return self.post("/submissions", {"agent": agent, "label": label, "benchmark": benchmark, "path": path,
                                          "description": description})

    def submit_archive(self, archive: Path, label: str, *, benchmark: str | None = None, path: str | None = None,
                       description: str = "") -> dict[str, Any]:
        data = {"label": label, "description": description}
        data.update({k: v for k, v in (("benchmark", benchmark), ("path", path)) if v is not None})
        with archive.open("rb") as f:
            return self.request("POST", "/submissions/upload", data=data,
                                files={"archive": (archive.name, f, "application/octet-stream")}).json()

    def leaderboard(self, benchmark: str, split: str = "public", *, limit: int | None = None,
                    offset: int = 0) -> dict[str, Any]:
        """The ranked board (``rows`` [offset, offset + limit), ``total`` rows in all)."""
        return self.get(f"/leaderboards/{benchmark}", split=split, limit=limit, offset=offset or None)

    # -- evaluators --------------------------------------------------------------------------------

    def lease(self, evaluator: str, features: list[str], version: str = "") -> Lease | None:
        """The next job this evaluator can run, or None when there is none now."""
        body = LeaseRequest(evaluator=evaluator, features=features, version=version)
        reply = self.post("/jobs/lease", body.model_dump())
        return None if reply is None else Lease.model_validate(reply)

    def heartbeat(self, job_id: int, lease_id: str, evaluator: str,
                  progress: dict[str, Any] | None = None) -> HeartbeatReply:
        try:
            body = Heartbeat(lease_id=lease_id, evaluator=evaluator, progress=progress)
        except ValueError:  # progress the server would refuse (NaN, …): keep the lease, drop the progress
            body = Heartbeat(lease_id=lease_id, evaluator=evaluator)
        return HeartbeatReply.model_validate(self.post(f"/jobs/{job_id}/heartbeat", body.model_dump()))

    def put_artifact(self, data: bytes, media_type: str = "application/octet-stream", *,
                     lease: tuple[int, str] | None = None) -> str:
        """Upload bytes by their hash; ``lease`` (job id, lease id): the lease they belong to (a result may list
        only artifacts its own lease uploaded)."""
        sha = hashlib.sha256(data).hexdigest()
        params = {"job_id": lease[0], "lease_id": lease[1]} if lease is not None else None
        self.request("PUT", f"/artifacts/{sha}", content=data, headers={"content-type": media_type}, params=params)
        return sha

    def stream_artifact(self, sha256: str, chunk: int = 1 << 20) -> Iterator[bytes]:
        """The artifact's bytes as they arrive (a container image of a gigabyte is never held whole), its hash
        checked at the end: a corrupted transfer raises after the last chunk, so the caller must not use what it
        wrote until the iterator is exhausted."""
        digest = hashlib.sha256()
        try:
            with self.http.stream("GET", f"/artifacts/{sha256}") as r:
                if r.status_code >= 400:
                    r.read()
                    raise ServerError(r.status_code, r.text[:500])
                for part in r.iter_bytes(chunk):
                    digest.update(part)
                    yield part
        except httpx.TransportError as exc:
            raise ServerError(0, f"artifact {sha256[:12]}…: the download broke off ({exc})") from None
        if digest.hexdigest() != sha256:
            raise ServerError(0, f"artifact {sha256[:12]}…: downloaded bytes do not match their hash")

    def get_artifact(self, sha256: str) -> bytes:
        """Download and check the content hash (a corrupted transfer is an error, not an agent)."""
        data = self.request("GET", f"/artifacts/{sha256}").content
        if hashlib.sha256(data).hexdigest() != sha256:
            raise ServerError(0, f"artifact {sha256[:12]}…: downloaded bytes do not match their hash")
        return data

    def result(self, job_id: int, body: ResultUpload | dict[str, Any]) -> dict[str, Any]:
        """Upload a job's outcome (validated and cleaned as the server will: NaN refused, NUL bytes replaced)."""
        upload = body if isinstance(body, ResultUpload) else ResultUpload.model_validate(body)
        return self.post(f"/jobs/{job_id}/result", upload.model_dump(mode="json"))

    # -- tokens ------------------------------------------------------------------------------------

    def tokens(self, user: str | None = None) -> list[dict[str, Any]]:
        """Your tokens (super-users: ``user``'s), revoked ones included; never their text."""
        return self.get("/me/tokens" if user is None else f"/users/{user}/tokens")

    def new_token(self, label: str = "") -> dict[str, Any]:
        return self.post("/me/tokens", {"label": label})

    def revoke_token(self, token_id: int) -> dict[str, Any]:
        return self.post(f"/tokens/{token_id}/revoke")
