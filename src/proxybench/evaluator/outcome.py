"""What a job's worker hands back to the evaluator loop: the outcome, its artifacts, and whose fault it was.

Statuses are the server's (AIDO's): ``success``; ``failed`` (the submission's fault); ``error`` (ours);
``host-error`` (this host cannot do it: the job goes back to the queue for another evaluator);
``aborted`` (the evaluator was stopped while working).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any, TextIO

__all__ = ["STATUSES", "Artifact", "Fault", "HostFault", "Outcome", "SubmissionFault"]

STATUSES = ("success", "failed", "error", "host-error", "aborted")


class Fault(Exception):
    """An ending of the job that is not a bug of ours; ``status`` says whose it is."""

    status = "error"


class SubmissionFault(Fault):
    status = "failed"


class HostFault(Fault):
    status = "host-error"


@dataclass
class Artifact:
    """A file to upload: ``name`` as the server lists it; ``hidden`` files are shown to operators only."""

    name: str
    path: str
    hidden: bool = False
    media_type: str = "application/octet-stream"


@dataclass
class Outcome:
    """What the worker hands back to the loop, through a pipe only the worker holds."""

    status: str
    message: str = ""
    public_scores: dict[str, float | None] = field(default_factory=dict)
    hidden_scores: dict[str, float | None] = field(default_factory=dict)
    public_report: dict[str, Any] = field(default_factory=dict)
    hidden_report: dict[str, Any] = field(default_factory=dict)
    artifacts: list[Artifact] = field(default_factory=list)

    def send(self, channel: TextIO) -> None:
        """Write as strict JSON (NaN and ±inf anywhere become null: the server accepts nothing else)."""
        channel.write(json.dumps(_strict(asdict(self)), allow_nan=False, default=str))

    @classmethod
    def parse(cls, text: str) -> Outcome:
        """The outcome a worker sent; ValueError if it is not a complete, well-formed one."""
        try:
            data = json.loads(text)
            data["artifacts"] = [Artifact(**a) for a in data.get("artifacts", [])]
            outcome = cls(**data)
        except (TypeError, KeyError, AttributeError, json.JSONDecodeError) as exc:
            raise ValueError(f"malformed outcome: {exc}") from None
        if outcome.status not in STATUSES:
            raise ValueError(f"unknown status {outcome.status!r}")
        if not all(isinstance(a.name, str) and isinstance(a.path, str) for a in outcome.artifacts):
            raise ValueError("artifact names and paths must be strings")
        return outcome


def _strict(value: Any) -> Any:
    if isinstance(value, dict):
        return {_strict(str(k)): _strict(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_strict(v) for v in value]
    if isinstance(value, str):
        return value.replace("\x00", "\ufffd")  # agent-written text (stderr) may hold NUL: no database takes it
    if isinstance(value, bool | int) or value is None:
        return value
    try:
        x = float(value)
    except (TypeError, ValueError):
        return str(value)
    return x if math.isfinite(x) else None
