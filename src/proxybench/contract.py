"""The seam between the challenges server and its evaluators: what a lease carries and what a result holds.

One set of pydantic models, used by both sides: the server validates requests and builds replies with
them (``server/api/jobs.py``), the evaluator builds its uploads and reads its leases with them
(``client.py``, ``evaluator/loop.py``). Importable without FastAPI or SQLAlchemy (an evaluator's install
needs neither).

Text the agent controls (its stderr in a message, anything in a report) is cleaned here on both sides:
NUL bytes and lone surrogates become U+FFFD, so every database stores it. Scores must be finite numbers
(or null for "could not be computed"); NaN or ±inf anywhere in a result is refused, naming the field.

>>> up = ResultUpload(lease_id="ab", evaluator="lab-1", status="failed", message="agent said \\x00 bye",
...                   public_report={"episodes": [{"stderr": "\\x00"}]})
>>> up.message, up.public_report["episodes"][0]["stderr"]
('agent said \\ufffd bye', '\\ufffd')
>>> try:
...     ResultUpload(lease_id="ab", evaluator="e", status="success", public_scores={"x": float("inf")})
... except ValueError as exc:
...     print(exc.errors()[0]["loc"], exc.errors()[0]["type"])
('public_scores', 'x') finite_number
"""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StringConstraints, field_validator, model_validator

from proxybench.untrusted import clean_text, clean_tree, find_non_finite, nesting_depth

__all__ = [
    "REPORTABLE", "ArtifactRef", "Heartbeat", "HeartbeatReply", "Lease", "LeaseRequest", "LeasedBenchmark",
    "LeasedSubmission", "ResultUpload", "Score",
]

#: what an evaluator may report (AIDO's statuses): see server.queue
REPORTABLE = ("success", "failed", "error", "host-error", "aborted")
Status = Literal["success", "failed", "error", "host-error", "aborted"]

#: a name an evaluator gives itself: printable, no control characters
EvaluatorName = Annotated[str, StringConstraints(min_length=1, max_length=64, pattern=r"^[^\x00-\x1f\x7f]+$")]
Feature = Annotated[str, StringConstraints(min_length=1, max_length=32, pattern=r"^[A-Za-z0-9_.-]+$")]
LeaseId = Annotated[str, StringConstraints(min_length=1, max_length=64, pattern=r"^[0-9a-f]+$")]
Sha256 = Annotated[str, StringConstraints(pattern=r"^[0-9a-f]{64}$")]
#: a score: a finite number, or None when it could not be computed (ranks last)
Score = Annotated[float | None, Field(allow_inf_nan=False)]
#: how deep and how large a report may be (a report nested 300 deep was stored, then every read of its
#: submission failed); the evaluator's reports nest about 5 levels
MAX_REPORT_DEPTH = 32
MAX_REPORT_BYTES = 4 << 20


class _Request(BaseModel):
    """A request body: unknown fields are refused with their name."""

    model_config = ConfigDict(extra="forbid")


class _Reply(BaseModel):
    """A reply: fields a newer server adds are ignored by an older evaluator."""

    model_config = ConfigDict(extra="ignore")


class LeaseRequest(_Request):
    evaluator: EvaluatorName = Field(description="this evaluator's name (unique per token)")
    features: list[Feature] = Field(default_factory=lambda: ["sim"], max_length=32,
                                    description="what this evaluator offers (sim, target, gpu, …)")
    version: str = Field("", max_length=32, description="the evaluator's proxybench version")


class LeasedSubmission(_Reply):
    id: int
    label: str
    agent: str | None = Field(None, description="a built-in agent, or None for an archive")
    archive_sha256: str | None = Field(None, description="the agent package to download from /artifacts")
    manifest: dict[str, Any] | None = None


class LeasedBenchmark(_Reply):
    name: str
    version: int
    spec_yaml: str
    test_seed: int | None = Field(None, description="seed of the hidden test episodes (None: no hidden split)")
    simulated_seconds: float | None = Field(None, description="simulated time of one split: every episode [s]")
    wall_time_factor: float | None = Field(None, description="the job may take this multiple of its simulated time "
                                                             "(every split) in wall-clock time")

    @property
    def wall_budget(self) -> float | None:
        """Wall-clock seconds the job's episodes may take (every split), or None when the server did not say."""
        if self.simulated_seconds is None or self.wall_time_factor is None:
            return None
        return self.wall_time_factor * self.simulated_seconds * (2 if self.test_seed is not None else 1)


class Lease(_Reply):
    """A leased job: keep it with heartbeats every ``lease_seconds / 4``; a 409 means it was lost."""

    job_id: int
    lease_id: str
    lease_seconds: float
    attempt: int = 1
    step: str = "main"
    features: list[str] = Field(default_factory=list, description="what the job needs")
    submission: LeasedSubmission
    benchmark: LeasedBenchmark


class Heartbeat(_Request):
    lease_id: LeaseId
    evaluator: EvaluatorName
    progress: dict[str, Any] | None = Field(None, description="shown on the queue page, e.g. {done, total}")

    @field_validator("progress")
    @classmethod
    def _clean(cls, v: dict[str, Any] | None) -> dict[str, Any] | None:
        return None if v is None else _finite_tree(clean_tree(v), "progress")


class HeartbeatReply(_Reply):
    job_id: int
    lease_expires_at: float = Field(description="server clock [s]: when the lease lapses without a heartbeat")


class ArtifactRef(_Request):
    name: str = Field(min_length=1, max_length=255)
    sha256: Sha256
    hidden: bool = Field(False, description="shown to super-users only")

    @field_validator("name")
    @classmethod
    def _clean(cls, v: str) -> str:
        return clean_text(v)


def _finite_tree(value: Any, field: str) -> Any:
    """A report or progress tree: finite numbers only, nested at most MAX_REPORT_DEPTH, at most MAX_REPORT_BYTES."""
    depth = nesting_depth(value)
    if depth > MAX_REPORT_DEPTH:
        raise ValueError(f"{field} is nested {depth} levels deep; at most {MAX_REPORT_DEPTH}")
    bad = find_non_finite(value)
    if bad is not None:
        raise ValueError(f"{field}.{bad} is not a finite number (NaN and ±inf are not JSON; send null)")
    size = len(json.dumps(value, ensure_ascii=False, default=str).encode())
    if size > MAX_REPORT_BYTES:
        raise ValueError(f"{field} is {size} bytes as JSON; at most {MAX_REPORT_BYTES}")
    return value


class ResultUpload(_Request):
    """A job's outcome. Stored exactly once per lease; a repeat of the same upload is answered, not stored."""

    lease_id: LeaseId
    evaluator: EvaluatorName
    status: Status
    public_scores: dict[str, Score] = Field(default_factory=dict, max_length=1000,
                                            description="validation scores (what developers see)")
    hidden_scores: dict[str, Score] = Field(default_factory=dict, max_length=1000,
                                            description="test scores (super-users only)")
    public_report: dict[str, Any] = Field(default_factory=dict)
    hidden_report: dict[str, Any] = Field(default_factory=dict)
    message: str = Field("", max_length=100_000)
    artifacts: list[ArtifactRef] = Field(default_factory=list, max_length=1000)

    @model_validator(mode="before")
    @classmethod
    def _clean_text(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        out = dict(data)
        for key in ("message", "public_report", "hidden_report", "public_scores", "hidden_scores"):
            if key in out:
                out[key] = clean_tree(out[key])
        return out

    @field_validator("public_report", "hidden_report")
    @classmethod
    def _finite(cls, v: dict[str, Any], info) -> dict[str, Any]:  # type: ignore[no-untyped-def]
        return _finite_tree(v, info.field_name)
