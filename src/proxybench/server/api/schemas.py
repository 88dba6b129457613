"""What the API accepts (request bodies). Strict: unknown fields are refused with their name."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from proxybench.server.paths import PathSpec

__all__ = [
    "ArtifactRef", "BenchmarkUpload", "HeartbeatIn", "LeaseIn", "PathCreate", "ResultIn", "SubmissionCreate",
    "TokenCreate", "UserCreate",
]


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid")


class UserCreate(_In):
    name: str = Field(min_length=1, max_length=64)
    role: str = Field(description="superuser | developer | evaluator")
    daily_limit: int | None = Field(None, ge=0, description="submissions per 24 h; default: the server's")


class TokenCreate(_In):
    label: str = Field("", max_length=64)


class BenchmarkUpload(_In):
    yaml: str = Field(min_length=1, description="the benchmark file's text")
    features: list[str] = Field(default_factory=lambda: ["sim"], description="what an evaluator must offer")
    test_seed: int | None = Field(None, ge=0, lt=2**31, description="seed of the hidden test episodes")
    hidden_split: bool = Field(True, description="also run hidden test episodes (drawn seed if none given)")


class PathCreate(_In):
    name: str = Field(min_length=1, max_length=64)
    description: str = ""
    spec: PathSpec


class SubmissionCreate(_In):
    label: str = Field(min_length=1, max_length=64)
    description: str = ""
    agent: str = Field(min_length=1, description="a built-in agent name ('proxybench agent list')")
    benchmark: str | None = None
    path: str | None = None


class LeaseIn(_In):
    evaluator: str = Field(min_length=1, max_length=64, description="this evaluator's name (unique per token)")
    features: list[str] = Field(default_factory=lambda: ["sim"])
    version: str = ""


class HeartbeatIn(_In):
    lease_id: str = Field(min_length=1)
    evaluator: str = Field(min_length=1, max_length=64)
    progress: dict[str, Any] | None = None


class ArtifactRef(_In):
    name: str = Field(min_length=1, max_length=255)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    hidden: bool = False


class ResultIn(_In):
    lease_id: str = Field(min_length=1)
    evaluator: str = Field(min_length=1, max_length=64)
    status: str
    public_scores: dict[str, float | None] = Field(default_factory=dict)
    hidden_scores: dict[str, float | None] = Field(default_factory=dict)
    public_report: dict[str, Any] = Field(default_factory=dict)
    hidden_report: dict[str, Any] = Field(default_factory=dict)
    message: str = Field("", max_length=100_000)
    artifacts: list[ArtifactRef] = Field(default_factory=list, max_length=1000)
