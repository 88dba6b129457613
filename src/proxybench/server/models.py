"""What the challenges server stores (SQLAlchemy 2 ORM). Times are UNIX seconds (floats): portable.

Users hold hashed API tokens; benchmarks are versioned YAML texts; a benchmark *path* is a DAG of
benchmark steps whose edges carry conditions; a submission (built-in agent or archive) gets one job per
step it reaches; evaluators lease jobs; each job's outcome is one ``Result`` row (``job_id`` is unique, so
a retried upload can never store a second one). Artifacts are files kept by content hash; ``ArtifactLink``
says which submission a file belongs to and whether it is hidden from its developer.
"""

from __future__ import annotations

from typing import Any, ClassVar

from sqlalchemy import JSON, Boolean, Float, ForeignKey, Integer, String, Text, UniqueConstraint
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship

__all__ = [
    "FINAL_STATUSES", "JOB_STATUSES", "ROLES", "ApiToken", "Artifact", "ArtifactLink", "Base", "BenchmarkPath",
    "BenchmarkVersion", "Evaluator", "Job", "JobEvent", "LeaseArtifact", "Result", "Submission", "User", "WebSession",
]

ROLES = ("superuser", "developer", "evaluator")
#: AIDO's job statuses; ``queued`` waits for a lease, ``evaluating`` holds one
JOB_STATUSES = ("queued", "evaluating", "success", "failed", "error", "host-error", "timeout", "aborted")
FINAL_STATUSES = frozenset(JOB_STATUSES) - {"queued", "evaluating"}


class Base(DeclarativeBase):
    type_annotation_map: ClassVar[dict[Any, Any]] = {dict[str, Any]: JSON, list[Any]: JSON}


class User(Base):
    __tablename__ = "users"
    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    role: Mapped[str] = mapped_column(String(16))
    created_at: Mapped[float] = mapped_column(Float)
    daily_limit: Mapped[int | None] = mapped_column(Integer, nullable=True)
    tokens: Mapped[list[ApiToken]] = relationship(back_populates="user")


class ApiToken(Base):
    __tablename__ = "api_tokens"
    id: Mapped[int] = mapped_column(primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id"), index=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    prefix: Mapped[str] = mapped_column(String(16))  # shown in listings so a user can tell tokens apart
    label: Mapped[str] = mapped_column(String(64), default="")
    created_at: Mapped[float] = mapped_column(Float)
    revoked: Mapped[bool] = mapped_column(Boolean, default=False)
    revoked_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    user: Mapped[User] = relationship(back_populates="tokens")


class WebSession(Base):
    """A signed-in browser: its own random secret (hashed here), expiring, ended by signing out or by revoking
    the API token it was opened with. The cookie never holds the API token itself."""

    __tablename__ = "web_sessions"
    id: Mapped[int] = mapped_column(primary_key=True)
    secret_hash: Mapped[str] = mapped_column(String(64), unique=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id"), index=True)
    token_id: Mapped[int] = mapped_column(ForeignKey("api_tokens.id"), index=True)
    created_at: Mapped[float] = mapped_column(Float)
    expires_at: Mapped[float] = mapped_column(Float)


class BenchmarkVersion(Base):
    __tablename__ = "benchmarks"
    __table_args__ = (UniqueConstraint("name", "version"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(64), index=True)
    version: Mapped[int] = mapped_column(Integer)
    spec_yaml: Mapped[str] = mapped_column(Text)
    spec_hash: Mapped[str] = mapped_column(String(64))
    description: Mapped[str] = mapped_column(Text, default="")
    features: Mapped[list[Any]] = mapped_column(default=list)  # what an evaluator must offer, e.g. ["sim"]
    test_seed: Mapped[int | None] = mapped_column(Integer, nullable=True)  # hidden split; never shown to developers
    created_at: Mapped[float] = mapped_column(Float)
    # bumped in the transaction of every change to its leaderboards (a success result, a retirement)
    board_version: Mapped[int] = mapped_column(Integer, default=0, server_default="0")


class BenchmarkPath(Base):
    __tablename__ = "benchmark_paths"
    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    description: Mapped[str] = mapped_column(Text, default="")
    spec: Mapped[dict[str, Any]] = mapped_column()  # PathSpec as JSON: steps and conditional edges
    created_at: Mapped[float] = mapped_column(Float)


class Submission(Base):
    __tablename__ = "submissions"
    id: Mapped[int] = mapped_column(primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id"), index=True)
    label: Mapped[str] = mapped_column(String(64))
    description: Mapped[str] = mapped_column(Text, default="")
    agent_name: Mapped[str | None] = mapped_column(String(64), nullable=True)  # a built-in agent
    archive_sha256: Mapped[str | None] = mapped_column(String(64), nullable=True)  # or an agent package
    manifest: Mapped[dict[str, Any] | None] = mapped_column(nullable=True)
    path_name: Mapped[str | None] = mapped_column(String(64), nullable=True)
    benchmark_name: Mapped[str | None] = mapped_column(String(64), nullable=True)
    status: Mapped[str] = mapped_column(String(16), default="active")  # active | retired
    created_at: Mapped[float] = mapped_column(Float, index=True)
    user: Mapped[User] = relationship()
    jobs: Mapped[list[Job]] = relationship(back_populates="submission", order_by="Job.id")


class Evaluator(Base):
    __tablename__ = "evaluators"
    __table_args__ = (UniqueConstraint("user_id", "name"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id"))
    name: Mapped[str] = mapped_column(String(64))
    features: Mapped[list[Any]] = mapped_column(default=list)
    version: Mapped[str] = mapped_column(String(32), default="")
    created_at: Mapped[float] = mapped_column(Float)
    last_seen_at: Mapped[float] = mapped_column(Float)
    jobs_done: Mapped[int] = mapped_column(Integer, default=0)


class Job(Base):
    __tablename__ = "jobs"
    id: Mapped[int] = mapped_column(primary_key=True)
    submission_id: Mapped[int] = mapped_column(ForeignKey("submissions.id"), index=True)
    benchmark_id: Mapped[int] = mapped_column(ForeignKey("benchmarks.id"))
    step: Mapped[str] = mapped_column(String(64))
    features: Mapped[list[Any]] = mapped_column(default=list)
    status: Mapped[str] = mapped_column(String(16), default="queued", index=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    max_attempts: Mapped[int] = mapped_column(Integer)
    lease_id: Mapped[str | None] = mapped_column(String(32), nullable=True)
    evaluator_id: Mapped[int | None] = mapped_column(ForeignKey("evaluators.id"), nullable=True)
    lease_expires_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    excluded: Mapped[list[Any]] = mapped_column(default=list)  # evaluator ids that had a host-error on it
    progress: Mapped[dict[str, Any] | None] = mapped_column(nullable=True)
    message: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[float] = mapped_column(Float)
    started_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    finished_at: Mapped[float | None] = mapped_column(Float, nullable=True)
    submission: Mapped[Submission] = relationship(back_populates="jobs")
    benchmark: Mapped[BenchmarkVersion] = relationship()
    evaluator: Mapped[Evaluator | None] = relationship()


class JobEvent(Base):
    """The job's history (leases, heartbeats lost, host errors, results): what the operator view shows."""

    __tablename__ = "job_events"
    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[int] = mapped_column(ForeignKey("jobs.id"), index=True)
    at: Mapped[float] = mapped_column(Float)
    kind: Mapped[str] = mapped_column(String(32))
    evaluator_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    message: Mapped[str] = mapped_column(Text, default="")


class Result(Base):
    __tablename__ = "results"
    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[int] = mapped_column(ForeignKey("jobs.id"), unique=True)
    submission_id: Mapped[int] = mapped_column(ForeignKey("submissions.id"), index=True)
    benchmark_id: Mapped[int] = mapped_column(ForeignKey("benchmarks.id"), index=True)
    lease_id: Mapped[str] = mapped_column(String(32))  # the lease that uploaded it: a retried upload matches it
    evaluator_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    status: Mapped[str] = mapped_column(String(16))
    public_scores: Mapped[dict[str, Any]] = mapped_column(default=dict)
    hidden_scores: Mapped[dict[str, Any]] = mapped_column(default=dict)
    public_report: Mapped[dict[str, Any]] = mapped_column(default=dict)
    hidden_report: Mapped[dict[str, Any]] = mapped_column(default=dict)
    message: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[float] = mapped_column(Float)
    job: Mapped[Job] = relationship()


class Artifact(Base):
    __tablename__ = "artifacts"
    sha256: Mapped[str] = mapped_column(String(64), primary_key=True)
    size: Mapped[int] = mapped_column(Integer)
    media_type: Mapped[str] = mapped_column(String(128), default="application/octet-stream")
    created_at: Mapped[float] = mapped_column(Float)
    uploaded_by: Mapped[int | None] = mapped_column(Integer, nullable=True)


class ArtifactLink(Base):
    """A named use of an artifact by a submission (its archive) or a result (a trajectory, video, log)."""

    __tablename__ = "artifact_links"
    id: Mapped[int] = mapped_column(primary_key=True)
    sha256: Mapped[str] = mapped_column(ForeignKey("artifacts.sha256"), index=True)
    submission_id: Mapped[int] = mapped_column(ForeignKey("submissions.id"), index=True)
    result_id: Mapped[int | None] = mapped_column(ForeignKey("results.id"), nullable=True)
    name: Mapped[str] = mapped_column(String(255))
    hidden: Mapped[bool] = mapped_column(Boolean, default=False)


class LeaseArtifact(Base):
    """An artifact uploaded under a job's lease: the only artifacts that lease's result may name (an evaluator
    cannot hand a developer another job's files, or their own archive's, by naming a hash)."""

    __tablename__ = "lease_artifacts"
    __table_args__ = (UniqueConstraint("job_id", "lease_id", "sha256"),)
    id: Mapped[int] = mapped_column(primary_key=True)
    job_id: Mapped[int] = mapped_column(ForeignKey("jobs.id"))
    lease_id: Mapped[str] = mapped_column(String(32))
    sha256: Mapped[str] = mapped_column(ForeignKey("artifacts.sha256"))
    created_at: Mapped[float] = mapped_column(Float)
