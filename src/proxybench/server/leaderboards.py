"""Leaderboards: successful results of active submissions on one benchmark version, ranked by the
benchmark's lexicographic semiorder (Copeland over pairwise comparisons, as ``proxybench evaluate``).

``split="public"`` ranks by validation scores (what developers see); ``split="hidden"`` by the
hidden test episodes (super-users only: the API refuses developers).

Boards are built when they change, not when they are read. Every change (a success result, a retired
submission) bumps its benchmark version's ``board_version`` in the same transaction; a board is built
once per version and kept, serialised, in the process (:class:`BoardCache`), so a read costs one small
query (the version) and a dictionary lookup. Builds are incremental: only the results that arrived since
the last build are read (all of them again after a retirement), then everything is re-ranked (a compiled
pair loop). A change asks for a rebuild in the background, right after its commit (the writing request
does not wait for it); a reader that finds a small board (at most ``SYNC_BUILD_ROWS`` rows) out of date
builds it on the spot, so a read after a result always shows it. A large board is rebuilt at most once
per ``max(MIN_INTERVAL_S, 8 × its build time)`` however fast results arrive, and readers get the
previous build meanwhile, marked ``"stale": true``. Each server process keeps (and builds) its own copy.

Beside the semiorder each board carries Bradley–Terry scores with 95 % intervals
(:mod:`proxybench.usefulness.bradley_terry`), built with the rest of the board: the results store aggregates only,
so the per-episode values come from each result's report (``public_report`` / ``hidden_report`` ``episodes``:
episode index, seed and per-episode scores, as the evaluator uploads them). Submissions are compared in every episode
(same index and seed) on the board's criteria in order, per episode, with their tolerances — the semiorder applied
episode by episode. ``bt`` on the board says whether first place is provisional and how many episodes it rests on;
``bt`` on a row is its score. A result without a per-episode report has no score (``null``). The bootstrap's cost
grows with the cube of the agents: large boards get fewer resamples, and none above :data:`BT_MAX_AGENTS`.

A result an Autolab measured (its report says ``measured_by: watchtowers``: scored from the trajectory its
watchtowers localised, not from the robot's own report) is marked on its row (``measured_by``, ``lab``), and
:func:`simulation_scores` finds the same agent's newest simulation result on another benchmark to show beside it
(read when the page is read: a result on another benchmark does not change this board).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from pydantic import BaseModel, ConfigDict
from sqlalchemy import Connection, bindparam, func, select
from sqlalchemy.orm import Session, sessionmaker

from proxybench.server.benchmarks import benchmark_of
from proxybench.server.errors import ServiceError
from proxybench.server.models import BenchmarkVersion, Result, Submission, User
from proxybench.tasks.scoring import Criterion, leaderboard
from proxybench.usefulness.bradley_terry import episode_metric

__all__ = ["BT_MAX_AGENTS", "MIN_INTERVAL_S", "SYNC_BUILD_ROWS", "Board", "BoardCache", "SimulationScore",
           "board_bradley_terry", "build_board", "resolve_version", "simulation_scores"]

log = logging.getLogger("proxybench.server")
SYNC_BUILD_ROWS = 100  # boards of at most this many rows are always built before they are served
MIN_INTERVAL_S = 1.0  # the shortest pause between background rebuilds of one large board [s]
INTERVAL_FACTOR = 8  # ... and at least this many times its build time: rebuilding takes ≤ 1/8 of a core
SPLITS = ("public", "hidden")
BT_MAX_AGENTS = 300  # boards with more scored submissions get no Bradley–Terry scores (a fit costs agents³)
MAX_REPORT_EPISODES = 10_000  # per-episode rows read from one result's report at most


_BV = BenchmarkVersion.__table__  # plain columns: no ORM annotations to adapt per execution
_NEWEST = (select(_BV.c.id, _BV.c.version, _BV.c.board_version).where(_BV.c.name == bindparam("name"))
           .order_by(_BV.c.version.desc()).limit(1))
_GIVEN = select(_BV.c.id, _BV.c.version, _BV.c.board_version).where(_BV.c.name == bindparam("name"),
                                                                     _BV.c.version == bindparam("version"))


def resolve_version(db: Session | Connection, name: str, version: int | None) -> tuple[int, int, int]:
    """(benchmark id, version, board_version) of a benchmark's newest or given version, in one query.

    The statements are built once (the leaderboard read runs this on every request): a statement object
    seen before skips SQLAlchemy's per-execution column matching; ``db`` may be a plain connection."""
    q, params = (_NEWEST, {"name": name}) if version is None else (_GIVEN, {"name": name, "version": version})
    row = db.execute(q, params).first()
    if row is None:
        raise ServiceError(404, f"no benchmark named {name!r}" if version is None else
                           f"benchmark {name!r} has no version {version}")
    return int(row[0]), int(row[1]), int(row[2])


def _json_number(v: float | None) -> float | None:
    return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v


@dataclass
class Entries:
    """What a board is built from: the newest success of each active submission, and how far it has read
    (the highest result id, and how many submissions were retired then: a retirement means reading all)."""

    # sid -> (rid, at, scores, label, agent, user, per-episode values: {(episode, seed): (one per criterion)},
    #         how it was measured: {"measured_by", "lab"} or {})
    by_submission: dict[int, tuple] = field(default_factory=dict)
    last_result: int = 0
    retired: int = -1


def _episode_values(report: Any, metrics: tuple[str, ...]) -> dict[tuple[str, str], tuple[float, ...]]:
    """{(episode, seed): the criteria's per-episode values} from an uploaded report (untrusted: anything malformed is
    left out; a missing or non-numeric value is NaN, which Bradley–Terry skips)."""
    rows = report.get("episodes") if isinstance(report, dict) else None
    if not isinstance(rows, list):
        return {}
    out: dict[tuple[str, str], tuple[float, ...]] = {}
    for row in rows[:MAX_REPORT_EPISODES]:
        if not isinstance(row, dict) or not isinstance(row.get("scores"), dict) or row.get("episode") is None:
            continue
        values = tuple(_nan_if_none(_number(row["scores"].get(m))) for m in metrics)
        if any(v == v for v in values):  # an episode with none of the criteria's values tells nothing
            out[(str(row["episode"]), str(row.get("seed")))] = values
    return out


def _measured(report: Any) -> dict[str, str]:
    """How a result was measured, from its report (untrusted: only short strings are kept): ``measured_by`` and
    the ``lab`` for a result an Autolab's watchtowers measured, else nothing."""
    if not isinstance(report, dict):
        return {}
    out = {k: report[k] for k in ("measured_by", "lab") if isinstance(report.get(k), str) and 0 < len(report[k]) <= 64}
    return out if "measured_by" in out else {}


def _number(v: Any) -> float | None:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None


def _read_entries(session: Session, bench_id: int, split: str, since: Entries | None,
                  metrics: tuple[str, ...] = ()) -> Entries:
    """The board's entries: only results newer than ``since`` when no submission was retired since."""
    retired = session.scalar(select(func.count(Submission.id)).where(Submission.status != "active")) or 0
    if since is None or since.retired != retired:
        since = Entries(retired=retired)
    out = Entries(dict(since.by_submission), since.last_result, retired)
    score_col = Result.public_scores if split == "public" else Result.hidden_scores
    report_col = Result.public_report if split == "public" else Result.hidden_report
    rows = session.execute(
        select(Result.id, Result.created_at, score_col, Submission.id, Submission.label, Submission.agent_name,
               Submission.manifest, User.name, report_col)
        .join(Submission, Result.submission_id == Submission.id).join(User, Submission.user_id == User.id)
        .where(Result.benchmark_id == bench_id, Result.status == "success", Submission.status == "active",
               Result.id > since.last_result)
        .order_by(Result.id)
    ).all()
    for rid, at, scores, sid, label, agent, manifest, user, report in rows:  # the latest success per submission wins
        out.by_submission[sid] = (rid, at, scores or {}, label, agent or (manifest or {}).get("name", "archive"),
                                  user, _episode_values(report, metrics), _measured(report))
        out.last_result = max(out.last_result, rid)
    return out


def _bt_effort(agents: int) -> tuple[int, int]:
    """(bootstrap resamples, fragility cap) for a board of this many agents: a fit costs about agents³, so larger
    boards get fewer (a board of ≤ 50 the module's defaults: 200 resamples, 50 removals)."""
    if agents <= 50:
        return 200, 50
    return (100, 20) if agents <= 150 else (50, 10)


def board_bradley_terry(criteria: list[Criterion], episodes: dict[int, dict[tuple[str, str], tuple[float, ...]]]
                        ) -> tuple[dict[str, Any] | None, dict[int, dict[str, Any]]]:
    """(the board's Bradley–Terry summary, each submission's score) from per-episode values; (None, {}) when no
    submission has any, or the board is too large (a note says so)."""
    from proxybench.usefulness.bradley_terry import EpisodeScores, bradley_terry_lexicographic

    sids = sorted(sid for sid, per in episodes.items() if per)  # a fixed order: incremental = full build
    if not sids:
        return None, {}
    compared_on = [episode_metric(c.metric) for c in criteria]
    if len(sids) > BT_MAX_AGENTS:
        return {"method": "bradley-terry", "episodes": None, "resamples": 0, "level": None, "alpha": None,
                "leader": None, "provisional": None, "fragility": None, "compared_on": compared_on,
                "notes": [f"{len(sids)} submissions: Bradley–Terry scores are computed for boards of at most "
                          f"{BT_MAX_AGENTS}"]}, {}
    per_metric = [EpisodeScores({sid: {e: v[k] for e, v in episodes[sid].items()} for sid in sids},
                                c.higher_is_better, c.tolerance) for k, c in enumerate(criteria)]
    resamples, cap = _bt_effort(len(sids))
    result = bradley_terry_lexicographic(per_metric, resamples=resamples, fragility_cap=cap)
    summary = {**result.to_json(), "compared_on": compared_on}
    by = result.by_agent()
    scores = {sid: {"score": by[sid].score, "lo": by[sid].lo, "hi": by[sid].hi, "contender": by[sid].contender}
              for sid in sids if by[sid].score is not None}
    return summary, scores


def build_board(session: Session, bench_id: int, split: str,
                since: Entries | None = None) -> tuple[int, dict[str, Any], Entries]:
    """(board_version it reflects, the ranked table as plain data: criteria, then rows best first, and the
    entries it was built from, to build the next one incrementally).

    The version is read first: everything it counts was committed before, so the results read after it
    include at least those (a board is never newer than it claims).
    """
    row = session.get(BenchmarkVersion, bench_id, populate_existing=True)  # read now, even if the session had it
    if row is None:
        raise ServiceError(404, f"no benchmark version {bench_id}")
    board_version = row.board_version
    criteria = benchmark_of(row).criteria()
    entries = _read_entries(session, bench_id, split, since, tuple(episode_metric(c.metric) for c in criteria))
    # a metric the evaluator could not compute arrives as null: NaN ranks it worst, as in proxybench evaluate
    scores = {sid: {c.metric: _nan_if_none(e[2].get(c.metric)) for c in criteria}
              for sid, e in entries.by_submission.items() if e[2]}
    ranks = leaderboard(scores, criteria) if scores else []
    bt, bt_rows = board_bradley_terry(criteria, {sid: entries.by_submission[sid][6] for sid in scores})
    rows = []
    for rank in ranks:
        rid, at, _, label, agent, user, _, measured = entries.by_submission[rank.agent]
        rows.append({"rank": rank.rank, "submission_id": rank.agent, "label": label, "user": user, "agent": agent,
                     "copeland": rank.copeland, "wins": rank.wins, "losses": rank.losses,
                     "scores": {c.metric: _json_number(scores[rank.agent].get(c.metric)) for c in criteria},
                     "bt": bt_rows.get(rank.agent), "result_id": rid, "at": at,
                     "measured_by": measured.get("measured_by"), "lab": measured.get("lab")})
    return board_version, {
        "benchmark": row.name, "version": row.version, "split": split,
        "criteria": [{"metric": c.metric, "higher_is_better": c.higher_is_better, "tolerance": c.tolerance}
                     for c in criteria],
        "bt": bt, "rows": rows}, entries


def _nan_if_none(v: Any) -> float:
    return math.nan if v is None else float(v)


@dataclass
class Board:
    """One built board: the data, when it was built and how long that took."""

    bench_id: int
    split: str
    board_version: int
    data: dict[str, Any]
    built_at: float
    build_seconds: float
    etag: str = ""
    entries: Entries | None = field(default=None, repr=False)
    _pages: dict[tuple[int, int, bool], bytes] = field(default_factory=dict, repr=False)

    def page(self, offset: int, limit: int | None, stale: bool) -> bytes:
        """The JSON reply for rows[offset : offset + limit], serialised once per page and build."""
        key = (offset, -1 if limit is None else limit, stale)
        cached = self._pages.get(key)
        if cached is None:
            rows = self.data["rows"]
            chosen = rows[offset:] if limit is None else rows[offset:offset + limit]
            body = {**self.data, "rows": chosen, "total": len(rows), "offset": offset,
                    "board_version": self.board_version, "built_at": self.built_at, "stale": stale}
            cached = json.dumps(body, separators=(",", ":"), allow_nan=False).encode()
            if len(self._pages) < 32:
                self._pages[key] = cached
        return cached


class BoardCache:
    """The boards this process has built, by (benchmark version id, split); thread-safe.

    Rebuilds asked for by changes run on one background thread, at most one per board at a time and no
    sooner than the board's :func:`interval` after its last build; a change during a build asks for one
    more. Readers build small out-of-date boards on the spot (so a read after a write shows it)."""

    def __init__(self, sessions: sessionmaker) -> None:
        self.sessions = sessions
        self._boards: dict[tuple[int, str], Board] = {}
        self._lock = threading.Lock()
        self._building: set[tuple[int, str]] = set()
        self._pending: set[tuple[int, str]] = set()
        self._again: set[tuple[int, str]] = set()
        self._asked: dict[tuple[int, str], float] = {}  # when a rebuild was last asked for, per board
        self._background = ThreadPoolExecutor(max_workers=1, thread_name_prefix="board-builder")

    def close(self) -> None:
        self._background.shutdown(wait=False, cancel_futures=True)

    # -- building ------------------------------------------------------------------------------------

    def _build(self, key: tuple[int, str]) -> Board:
        start = time.time()  # built_at − build_seconds: what :meth:`request` compares with when it asked
        previous = self._boards.get(key)
        with self.sessions() as session:
            version, data, entries = build_board(session, *key, since=previous.entries if previous else None)
        now = time.time()
        digest = hashlib.sha256(f"{key}{version}{now}".encode()).hexdigest()[:20]
        board = Board(key[0], key[1], version, data, now, now - start, etag=f'"{digest}"', entries=entries)
        with self._lock:
            old = self._boards.get(key)
            if old is None or old.board_version <= version:
                self._boards[key] = board
            return self._boards[key]

    def _build_once(self, key: tuple[int, str], wait: bool) -> Board | None:
        """Build unless this process is building it already (then wait for that build, or not)."""
        with self._lock:
            busy = key in self._building
            if not busy:
                self._building.add(key)
        if busy:
            if not wait:
                return None
            while True:
                time.sleep(0.002)
                with self._lock:
                    if key not in self._building:
                        return self._boards.get(key)
        try:
            return self._build(key)
        finally:
            with self._lock:
                self._building.discard(key)
                again = key in self._again
                self._again.discard(key)
            if again:
                self.request(key)  # changes arrived while it was being built

    def request(self, key: tuple[int, str]) -> None:
        """Ask for a rebuild in the background (coalesced; no sooner than the board's interval; skipped when a
        build that began after the latest request has run meanwhile, e.g. a reader's)."""
        asked = time.time()
        with self._lock:
            self._asked[key] = asked  # a request coalesced into a pending one still moves the time it must cover
            if key in self._building:
                self._again.add(key)
                return
            if key in self._pending:
                return
            self._pending.add(key)
        board = self._boards.get(key)
        delay = 0.0 if board is None else max(0.0, board.built_at + interval(board) - asked)

        def run() -> None:
            if delay:
                time.sleep(delay)
            with self._lock:
                self._pending.discard(key)
                latest, since = self._boards.get(key), self._asked.get(key, 0.0)
            if latest is not None and latest.built_at - latest.build_seconds >= since:
                return  # a build that began after the last change holds it already
            try:
                self._build_once(key, wait=False)
            except Exception as exc:  # a failed rebuild leaves the old board; the next change asks again
                log.warning("leaderboard rebuild of %s failed: %s", key, exc)

        self._background.submit(run)

    # -- reading -------------------------------------------------------------------------------------

    def cached(self, bench_id: int, split: str, board_version: int) -> tuple[Board, bool] | None:
        """(board, stale) as :meth:`get` would answer without building anything, or None when it must build.

        Cheap (no query, no build: for the event loop): a fresh board; or a large one that is out of date,
        whose rebuild is then asked for (served meanwhile, marked stale, as :meth:`get` does)."""
        key = (bench_id, split)
        board = self._boards.get(key)
        if board is None:
            return None
        if board.board_version >= board_version:
            return board, False
        if len(board.data["rows"]) <= SYNC_BUILD_ROWS:
            return None
        self.request(key)
        return board, True

    def get(self, bench_id: int, split: str, board_version: int) -> tuple[Board, bool]:
        """(the board to serve, whether it is older than ``board_version``)."""
        key = (bench_id, split)
        board = self._boards.get(key)
        if board is not None and board.board_version >= board_version:
            return board, False
        if board is None or len(board.data["rows"]) <= SYNC_BUILD_ROWS:
            built = self._build_once(key, wait=True)
            if built is not None and built.board_version >= board_version:
                return built, False
            board = built or board
        self.request(key)
        assert board is not None
        return board, board.board_version < board_version

    def changed(self, bench_ids: set[int] | list[int]) -> None:
        """After a commit that changed these boards: rebuild the ones this process serves, in the background
        (cheap to call: no query, no build here)."""
        ids = set(bench_ids)
        for key in [k for k in list(self._boards) if k[0] in ids]:
            self.request(key)


def interval(board: Board) -> float:
    """The shortest time between two background builds of this board."""
    return max(MIN_INTERVAL_S, INTERVAL_FACTOR * board.build_seconds)


def leaderboard_rows(session: Session, name: str, split: str = "public",
                     version: int | None = None, boards: BoardCache | None = None) -> dict[str, Any]:
    """The whole ranked table as plain data (the web pages' view), from ``boards`` when given."""
    if split not in SPLITS:
        raise ServiceError(422, f"split must be 'public' or 'hidden', got {split!r}")
    bench_id, _, board_version = resolve_version(session, name, version)
    if boards is None:
        return build_board(session, bench_id, split)[1]
    board, stale = boards.get(bench_id, split, board_version)
    return {**board.data, "total": len(board.data["rows"]), "stale": stale, "built_at": board.built_at}


MAX_SIMULATION_RESULTS = 500  # results of the measured agents read at most, newest first, to find their simulation
SIMULATION = "simulation"  # the report's domain_kind of a run in proxybench's simulator (domain.kinds.DomainKind)


class SimulationScore(BaseModel):
    """The same agent's newest simulation result on another benchmark: where, and its scores on this board's
    criteria (None where it has no such score)."""

    model_config = ConfigDict(frozen=True)

    benchmark: str
    version: int
    result_id: int
    same_submission: bool
    scores: dict[str, float | None]


def simulation_scores(session: Session, board: dict[str, Any]) -> dict[int, SimulationScore]:
    """By submission id, for each row of ``board`` measured by watchtowers: the same agent's newest successful
    simulation result on another benchmark (the same submission's first, else the same user's submission of the
    same agent: the same package by its hash, or the same built-in agent), in the board's split."""
    measured = [r["submission_id"] for r in board["rows"] if r.get("measured_by") == "watchtowers"]
    if not measured:
        return {}
    subs = session.execute(select(Submission.id, Submission.user_id, Submission.archive_sha256, Submission.agent_name)
                           .where(Submission.id.in_(measured))).all()
    agent_of = {sid: (user, sha or None, None if sha else name) for sid, user, sha, name in subs}
    by_agent: dict[tuple, list[int]] = {}  # (user, package hash, built-in agent) -> the measured submissions
    for sid, key in agent_of.items():
        if key[1:] != (None, None):
            by_agent.setdefault(key, []).append(sid)
    same = session.execute(select(Submission.id, Submission.user_id, Submission.archive_sha256, Submission.agent_name)
                           .where(Submission.status == "active",
                                  Submission.user_id.in_({a[0] for a in agent_of.values()}))).all()
    twins: dict[int, set[int]] = {sid: {sid} for sid in agent_of}
    for sid, user, sha, name in same:
        for mine in by_agent.get((user, sha or None, None if sha else name), ()):
            twins[mine].add(sid)
    candidates = set().union(*twins.values())
    score_col = Result.public_scores if board["split"] == "public" else Result.hidden_scores
    report_col = Result.public_report if board["split"] == "public" else Result.hidden_report
    rows = session.execute(
        select(Result.id, Result.submission_id, score_col, report_col, BenchmarkVersion.name, BenchmarkVersion.version)
        .join(BenchmarkVersion, Result.benchmark_id == BenchmarkVersion.id)
        .where(Result.status == "success", Result.submission_id.in_(candidates),
               BenchmarkVersion.name != board["benchmark"])
        .order_by(Result.id.desc()).limit(MAX_SIMULATION_RESULTS)).all()
    metrics = [c["metric"] for c in board["criteria"]]
    out: dict[int, SimulationScore] = {}
    for_whom: dict[int, list[int]] = {}  # a candidate submission -> the measured submissions it stands for
    for mine, ids in twins.items():
        for sid in ids:
            for_whom.setdefault(sid, []).append(mine)
    for rid, sid, scores, report, bench, version in rows:  # newest first
        if not isinstance(report, dict) or report.get("domain_kind") != SIMULATION:
            continue
        for mine in for_whom.get(sid, ()):
            if mine in out and (out[mine].same_submission or sid != mine):
                continue  # a newer one is kept, unless this is the measured submission's own
            values = {m: _json_number(_number((scores or {}).get(m))) for m in metrics}
            out[mine] = SimulationScore(benchmark=bench, version=version, result_id=rid, same_submission=sid == mine,
                                        scores=values)
    return out
