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

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from proxybench.server.benchmarks import benchmark_of, latest
from proxybench.server.errors import ServiceError
from proxybench.server.models import BenchmarkVersion, Result, Submission, User
from proxybench.tasks.scoring import leaderboard

__all__ = ["leaderboard_rows"]


def _version(session: Session, name: str, version: int | None) -> BenchmarkVersion:
    if version is None:
        return latest(session, name)
    row = session.scalar(select(BenchmarkVersion).where(BenchmarkVersion.name == name,
                                                        BenchmarkVersion.version == version))
    if row is None:
        raise ServiceError(404, f"benchmark {name!r} has no version {version}")
    return row


_CACHE_LOCK = threading.Lock()
_BOARD_CACHE: OrderedDict[tuple, dict[str, Any]] = OrderedDict()


def _json_number(v: float | None) -> float | None:
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else v


def _fingerprint(session: Session, bench_id: int) -> tuple:
    """Changes whenever the board can: a new success on this version, or a submission retired."""
    n, last = session.execute(select(func.count(Result.id), func.max(Result.id))
                              .where(Result.benchmark_id == bench_id, Result.status == "success")).one()
    retired = session.scalar(select(func.count(Submission.id)).where(Submission.status != "active"))
    return (n, last, retired)


def leaderboard_rows(session: Session, name: str, split: str = "public",
                     version: int | None = None) -> dict[str, Any]:
    """The ranked table as plain data: criteria, then one row per submission (best first).

    Boards are cached per (version, split) and rebuilt only when their fingerprint changes, so polling
    clients cost two small aggregate queries, not a scan of every result.
    """
    if split not in ("public", "hidden"):
        raise ServiceError(422, f"split must be 'public' or 'hidden', got {split!r}")
    row = _version(session, name, version)
    bind = session.get_bind()
    key = (id(bind), str(bind.url), row.id, split, _fingerprint(session, row.id))
    with _CACHE_LOCK:
        if key in _BOARD_CACHE:
            _BOARD_CACHE.move_to_end(key)
            return _BOARD_CACHE[key]
    board = _build(session, row, split)
    with _CACHE_LOCK:
        _BOARD_CACHE[key] = board
        while len(_BOARD_CACHE) > 64:
            _BOARD_CACHE.popitem(last=False)
    return board


def _build(session: Session, row: BenchmarkVersion, split: str) -> dict[str, Any]:
    criteria = benchmark_of(row).criteria()
    score_col = Result.public_scores if split == "public" else Result.hidden_scores
    results = session.execute(
        select(Result.id, Result.created_at, score_col, Submission.id, Submission.label, Submission.agent_name,
               Submission.manifest, User.name)
        .join(Submission, Result.submission_id == Submission.id).join(User, Submission.user_id == User.id)
        .where(Result.benchmark_id == row.id, Result.status == "success", Submission.status == "active")
        .order_by(Result.id)
    ).all()
    newest = {r[3]: r for r in results}  # the latest success per submission (a retried step replaces the older)
    # a metric the evaluator could not compute arrives as null: NaN ranks it worst, as in proxybench evaluate
    scores = {sid: {k: (math.nan if v is None else v) for k, v in r[2].items()} for sid, r in newest.items() if r[2]}
    ranks = leaderboard(scores, criteria) if scores else []  # Copeland: quadratic, hence the board cache
    rows = []
    for rank in ranks:
        rid, at, _, sid, label, agent, manifest, user = newest[rank.agent]
        rows.append({"rank": rank.rank, "submission_id": sid, "label": label, "user": user,
                     "agent": agent or (manifest or {}).get("name", "archive"),
                     "copeland": rank.copeland, "wins": rank.wins, "losses": rank.losses,
                     "scores": {c.metric: _json_number(scores[rank.agent].get(c.metric)) for c in criteria},
                     "result_id": rid, "at": at})
    return {"benchmark": row.name, "version": row.version, "split": split,
            "criteria": [{"metric": c.metric, "higher_is_better": c.higher_is_better, "tolerance": c.tolerance}
                         for c in criteria],
            "rows": rows}
