"""Leaderboards: successful results of active submissions on one benchmark version, ranked by the
benchmark's lexicographic semiorder (Copeland over pairwise comparisons, as ``proxybench evaluate``).

``split="public"`` ranks by validation scores (what developers see); ``split="hidden"`` by the
hidden test episodes (super-users only: the API refuses developers).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from proxybench.server.benchmarks import benchmark_of, latest
from proxybench.server.errors import ServiceError
from proxybench.server.models import BenchmarkVersion, Result, Submission
from proxybench.tasks.scoring import Rank, leaderboard

__all__ = ["leaderboard_rows"]


def _version(session: Session, name: str, version: int | None) -> BenchmarkVersion:
    if version is None:
        return latest(session, name)
    row = session.scalar(select(BenchmarkVersion).where(BenchmarkVersion.name == name,
                                                        BenchmarkVersion.version == version))
    if row is None:
        raise ServiceError(404, f"benchmark {name!r} has no version {version}")
    return row


_RANK_CACHE: OrderedDict[tuple, list[Rank]] = OrderedDict()
_RANK_CACHE_LOCK = threading.Lock()


def _ranked(bench_id: int, split: str, key_rows: tuple, scores: dict, criteria: list) -> list[Rank]:
    """Copeland ranking is quadratic in the entries: compute it once per set of (submission, result)."""
    if not scores:
        return []
    key = (bench_id, split, key_rows)
    with _RANK_CACHE_LOCK:
        if key in _RANK_CACHE:
            _RANK_CACHE.move_to_end(key)
            return _RANK_CACHE[key]
    ranks = leaderboard(scores, criteria)
    with _RANK_CACHE_LOCK:
        _RANK_CACHE[key] = ranks
        while len(_RANK_CACHE) > 64:
            _RANK_CACHE.popitem(last=False)
    return ranks


def _json_number(v: float | None) -> float | None:
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else v


def leaderboard_rows(session: Session, name: str, split: str = "public",
                     version: int | None = None) -> dict[str, Any]:
    """The ranked table as plain data: criteria, then one row per submission (best first)."""
    if split not in ("public", "hidden"):
        raise ServiceError(422, f"split must be 'public' or 'hidden', got {split!r}")
    row = _version(session, name, version)
    criteria = benchmark_of(row).criteria()
    results = session.execute(
        select(Result, Submission).join(Submission, Result.submission_id == Submission.id)
        .where(Result.benchmark_id == row.id, Result.status == "success", Submission.status == "active")
        .order_by(Result.id)
    ).all()
    newest: dict[int, tuple[Result, Submission]] = {}
    for result, sub in results:
        newest[sub.id] = (result, sub)  # the latest success per submission (a retried step replaces the older)
    scores = {sid: (r.public_scores if split == "public" else r.hidden_scores) for sid, (r, _) in newest.items()}
    # a metric the evaluator could not compute arrives as null: NaN ranks it worst, as in proxybench evaluate
    scores = {sid: {k: (math.nan if v is None else v) for k, v in s.items()} for sid, s in scores.items() if s}
    ranks = _ranked(row.id, split, tuple(sorted((sid, r.id) for sid, (r, _) in newest.items())), scores, criteria)
    rows = []
    for rank in ranks:
        result, sub = newest[rank.agent]
        rows.append({"rank": rank.rank, "submission_id": sub.id, "label": sub.label, "user": sub.user.name,
                     "agent": sub.agent_name or (sub.manifest or {}).get("name", "archive"),
                     "copeland": rank.copeland, "wins": rank.wins, "losses": rank.losses,
                     "scores": {c.metric: _json_number(scores[rank.agent].get(c.metric)) for c in criteria},
                     "result_id": result.id, "at": result.created_at})
    return {"benchmark": row.name, "version": row.version, "split": split,
            "criteria": [{"metric": c.metric, "higher_is_better": c.higher_is_better, "tolerance": c.tolerance}
                         for c in criteria],
            "rows": rows}
