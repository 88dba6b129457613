"""What the API accepts and what it answers: one model per request body and per reply, so the OpenAPI
schema (``/api/v1/openapi.json``) describes both. Requests are strict (unknown fields are refused with
their name); text in them is cleaned of NUL bytes. The job lease and the result upload are the models of
:mod:`proxybench.contract`, shared with the evaluators.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from proxybench.contract import (
    ArtifactRef,
    Heartbeat,
    HeartbeatReply,
    Lease,
    LeaseRequest,
    ResultUpload,
    Score,
)
from proxybench.server.paths import PathSpec
from proxybench.untrusted import clean_tree

__all__ = [
    "ArtifactRef",
    "ArtifactStored",
    "BTBoardOut",
    "BTFragilityOut",
    "BTScoreOut",
    "BenchmarkOut",
    "BenchmarkUpload",
    "CriterionOut",
    "EvaluatorOut",
    "Health",
    "Heartbeat",
    "HeartbeatReply",
    "HostErrorRecorded",
    "JobDetail",
    "JobEventOut",
    "JobOut",
    "LeaderboardOut",
    "LeaderboardRow",
    "Lease",
    "LeaseRequest",
    "PathCreate",
    "PathOut",
    "ResultOut",
    "ResultRecorded",
    "ResultUpload",
    "Retired",
    "SubmissionCreate",
    "SubmissionOut",
    "TokenCreate",
    "TokenCreated",
    "TokenOut",
    "UserCreate",
    "UserCreated",
    "UserOut",
]

#: a database id: refused beyond the 32-bit range the columns hold (PostgreSQL would answer 500)
MAX_ID = 2**31 - 1
Count = Annotated[int, Field(ge=0, le=MAX_ID)]


class _In(BaseModel):
    """A request body: unknown fields refused; NUL bytes and lone surrogates in text replaced."""

    model_config = ConfigDict(extra="forbid")

    @model_validator(mode="before")
    @classmethod
    def _clean(cls, data: Any) -> Any:
        return clean_tree(data) if isinstance(data, dict) else data


class _Out(BaseModel):
    model_config = ConfigDict(extra="ignore")


# -- requests -------------------------------------------------------------------------------------------


class UserCreate(_In):
    name: str = Field(min_length=1, max_length=64)
    role: str = Field(description="superuser | developer | evaluator")
    daily_limit: Count | None = Field(None, description="submissions per 24 h; default: the server's")


class TokenCreate(_In):
    label: str = Field("", max_length=64)


class BenchmarkUpload(_In):
    yaml: str = Field(min_length=1, max_length=1 << 20, description="the benchmark file's text")
    features: list[str] = Field(default_factory=lambda: ["sim"], max_length=32,
                                description="what an evaluator must offer")
    test_seed: int | None = Field(None, ge=0, lt=2**31, description="seed of the hidden test episodes")
    hidden_split: bool = Field(True, description="also run hidden test episodes (drawn seed if none given)")


class PathCreate(_In):
    name: str = Field(min_length=1, max_length=64)
    description: str = Field("", max_length=10_000)
    spec: PathSpec


class SubmissionCreate(_In):
    label: str = Field(min_length=1, max_length=64)
    description: str = Field("", max_length=10_000)
    agent: str = Field(min_length=1, max_length=64, description="a built-in agent name ('proxybench agent list')")
    benchmark: str | None = Field(None, max_length=64)
    path: str | None = Field(None, max_length=64)


# -- replies --------------------------------------------------------------------------------------------


class Health(_Out):
    status: str
    version: str


class UserOut(_Out):
    name: str
    role: str
    daily_limit: int | None
    created_at: float


class UserCreated(UserOut):
    token: str = Field(description="the new user's first API token: shown this once")


class TokenOut(_Out):
    id: int
    user: str
    prefix: str = Field(description="the token's first characters, to tell tokens apart")
    label: str
    created_at: float
    revoked: bool
    revoked_at: float | None


class TokenCreated(TokenOut):
    token: str = Field(description="the token itself: shown this once")


class BenchmarkOut(_Out):
    name: str
    version: int
    description: str
    features: list[str]
    spec_yaml: str
    spec_hash: str
    created_at: float
    has_hidden_split: bool
    invalid_retries: int | None = Field(None, description="Autolab benchmarks (feature autolab): how many times an "
                                        "episode the watchtowers' measurement made invalid is run again in one job")
    test_seed: int | None = Field(None, description="super-users only")
    created: bool | None = Field(None, description="uploads: whether this made a new version")


class PathOut(_Out):
    name: str
    description: str = ""
    spec: PathSpec


class CriterionOut(_Out):
    metric: str
    higher_is_better: bool
    tolerance: float


class BTScoreOut(_Out):
    """A submission's Bradley–Terry score: log-strength, mean 0 over the board (exp(a − b) is the odds that a beats
    b in an episode), with its bootstrap interval over episodes."""

    score: float
    lo: float | None
    hi: float | None
    contender: bool = Field(description="its interval reaches the leader's: it could be first")


class BTFragilityOut(_Out):
    episodes: int | None = Field(description="fewest episodes whose removal changes first place (greedy); "
                                 "null: more than ``cap``")
    cap: int
    text: str = Field(description='"3", or "> 50" when the search stopped at its cap')


class BTBoardOut(_Out):
    """Bradley–Terry scores of a board: submissions compared episode by episode (same index and seed) on the
    criteria in order, with their tolerances; intervals by bootstrap over episodes."""

    method: str = "bradley-terry"
    episodes: int | None = None
    resamples: int | None = None
    level: float | None = None
    alpha: float | None = None
    leader: int | None = Field(None, description="the submission with the highest score")
    provisional: bool | None = Field(None, description="the leader's interval overlaps the runner-up's")
    fragility: BTFragilityOut | None = None
    compared_on: list[str] = Field(default_factory=list, description="the per-episode metrics, in order")
    notes: list[str] = Field(default_factory=list)


class LeaderboardRow(_Out):
    rank: int
    submission_id: int
    label: str
    user: str
    agent: str | None
    copeland: int
    wins: int
    losses: int
    scores: dict[str, Score]
    bt: BTScoreOut | None = Field(None, description="null: no per-episode report, or no episode shared with others")
    result_id: int
    at: float


class LeaderboardOut(_Out):
    benchmark: str
    version: int
    split: str
    criteria: list[CriterionOut]
    bt: BTBoardOut | None = Field(None, description="null: no result on the board has a per-episode report")
    rows: list[LeaderboardRow]
    total: int = Field(description="rows on the whole board (``rows`` is the page asked for)")
    offset: int = 0
    board_version: int = Field(description="changes whenever the board does")
    built_at: float
    stale: bool = Field(description="true while a newer board is being built (large boards only)")


class JobOut(_Out):
    id: int
    submission_id: int
    step: str
    benchmark: str
    benchmark_version: int
    features: list[str]
    status: str
    attempts: int
    max_attempts: int
    message: str
    evaluator: str | None
    lease_expires_at: float | None = Field(description="server clock (monotonic, on the UNIX scale)")
    progress: dict[str, Any] | None
    created_at: float
    started_at: float | None
    finished_at: float | None


class JobEventOut(_Out):
    at: float
    kind: str
    evaluator_id: int | None
    message: str


class JobDetail(JobOut):
    events: list[JobEventOut]


class ArtifactLinkOut(_Out):
    name: str
    sha256: str
    hidden: bool


class ResultOut(_Out):
    id: int
    job_id: int
    status: str
    public_scores: dict[str, Score]
    public_report: dict[str, Any]
    message: str
    created_at: float
    artifacts: list[ArtifactLinkOut]
    hidden_scores: dict[str, Score] | None = Field(None, description="super-users only")
    hidden_report: dict[str, Any] | None = Field(None, description="super-users only")


class ResultRecorded(ResultOut):
    recorded: bool = Field(description="false when this upload repeated one already stored")
    opened_jobs: list[int] = Field(description="jobs of the next path steps this result opened")


class HostErrorRecorded(_Out):
    job_id: int
    status: str
    requeued: bool


class SubmissionOut(_Out):
    id: int
    label: str
    description: str
    user: str
    status: str
    agent: str | None
    archive_sha256: str | None
    manifest: dict[str, Any] | None
    benchmark: str | None
    path: str | None
    created_at: float
    jobs: list[JobOut]
    results: list[ResultOut] | None = Field(None, description="single submissions only")


class Retired(_Out):
    id: int
    status: str
    aborted_jobs: int


class EvaluatorOut(_Out):
    name: str
    owner_id: int
    features: list[str]
    version: str
    last_seen_at: float = Field(description="server clock (monotonic, on the UNIX scale)")
    jobs_done: int
    healthy: bool


class ArtifactStored(_Out):
    sha256: str
    size: int
