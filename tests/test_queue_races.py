"""The job queue under races on PostgreSQL (issue 23 §3): every state change is a conditional UPDATE checked by
the rows it changed, and the daily limit is counted under a lock of the user's row.

Two transactions are interleaved by hand where the bug was (a result stored while the reaper had read its
lease as lapsed: acknowledged, then overwritten, the job leased again and ended ``timeout`` while its
``success`` still ranked), then a live server is raced: results posted across lease expiry, evaluators and
the server killed -9 during load.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from proxybench.client import ServerClient, ServerError
from proxybench.contract import ResultUpload
from proxybench.server import clock
from proxybench.server.benchmarks import register_builtins
from proxybench.server.db import make_engine, migrate
from proxybench.server.errors import ServiceError
from proxybench.server.models import Evaluator, Job, JobEvent, Result, User
from proxybench.server.queue import finish, install_board_bumps, lease, requeue_expired
from proxybench.server.security import create_user
from proxybench.server.submissions import create_submission
from support.live_server import LiveServer
from support.queue_race import race

SCORES = {"driven_lanedir_consec_median": 5.0, "survival_time_median": 60.0,
          "deviation_center_line_median": 0.1, "in_drivable_lane_median": 0.0}


@pytest.fixture
def factory(postgres):
    engine = make_engine(postgres.new_database())
    migrate(engine)
    made = sessionmaker(engine, expire_on_commit=False)
    install_board_bumps(made)
    with made() as s:
        register_builtins(s)
        create_user(s, "dev", "developer")
        create_user(s, "ev", "evaluator")
        s.commit()
    yield made
    engine.dispose()


def _user(s: Session, name: str) -> User:
    return s.scalar(select(User).where(User.name == name))


def _leased_job(factory) -> tuple[int, str]:
    """A submission's job, leased by evaluator e1 (a lease of one second)."""
    with factory() as s:
        create_submission(s, _user(s, "dev"), label="a", agent_name="vision", benchmark="aido_lf", daily_limit=0)
        ev = Evaluator(user_id=_user(s, "ev").id, name="e1", features=["sim"], created_at=0.0, last_seen_at=0.0,
                       jobs_done=0)
        s.add(ev)
        s.flush()
        job = lease(s, ev, 1.0)
        s.commit()
        return job.id, job.lease_id


def _upload(lease_id: str) -> ResultUpload:
    return ResultUpload(lease_id=lease_id, evaluator="e1", status="success", public_scores=SCORES,
                        hidden_scores=SCORES)


def _later(work, delay: float = 0.5):
    """Run ``work`` in a thread (it blocks on the other transaction's row lock); its outcome."""
    out: dict = {}

    def run() -> None:
        try:
            out["value"] = work()
        except Exception as exc:
            out["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    time.sleep(delay)
    return t, out


def test_a_result_stored_as_its_lease_lapses_is_never_overwritten_by_the_reaper(factory) -> None:
    job_id, lease_id = _leased_job(factory)
    first = factory()
    ev = first.scalar(select(Evaluator).where(Evaluator.name == "e1"))
    _, created = finish(first, job_id, _upload(lease_id), ev)  # the job row is now locked by this
    assert created

    def reap() -> int:
        with factory() as second:  # read the lease as lapsed before the result was committed
            n = requeue_expired(second, now=clock.now() + 3600)
            second.commit()
            return n

    thread, out = _later(reap)
    first.commit()
    first.close()
    thread.join(30)
    assert out.get("value") == 0, out
    with factory() as s:
        job = s.get(Job, job_id)
        assert job.status == "success" and job.lease_id is None
        assert s.scalar(select(Result.status).where(Result.job_id == job_id)) == "success"
        kinds = s.scalars(select(JobEvent.kind).where(JobEvent.job_id == job_id).order_by(JobEvent.id)).all()
        assert "lease-lapsed" not in kinds, kinds


def test_a_result_arriving_after_the_reaper_took_the_lease_is_refused_not_stored(factory) -> None:
    job_id, lease_id = _leased_job(factory)
    reaper = factory()
    assert requeue_expired(reaper, now=clock.now() + 3600) == 1  # not committed yet: the row is locked

    def post() -> tuple:
        with factory() as s:
            ev = s.scalar(select(Evaluator).where(Evaluator.name == "e1"))
            got = finish(s, job_id, _upload(lease_id), ev)
            s.commit()
            return got

    thread, out = _later(post)
    reaper.commit()
    reaper.close()
    thread.join(30)
    assert isinstance(out.get("error"), ServiceError) and out["error"].status == 409, out
    with factory() as s:
        assert s.get(Job, job_id).status == "queued"
        assert s.scalar(select(Result).where(Result.job_id == job_id)) is None


def test_the_daily_limit_holds_under_concurrent_submissions(factory) -> None:
    first = factory()
    create_submission(first, _user(first, "dev"), label="one", agent_name="vision", benchmark="aido_lf",
                      daily_limit=1)  # not committed yet

    def second() -> None:
        with factory() as s:
            create_submission(s, _user(s, "dev"), label="two", agent_name="vision", benchmark="aido_lf",
                              daily_limit=1)
            s.commit()

    thread, out = _later(second)
    first.commit()
    first.close()
    thread.join(30)
    assert isinstance(out.get("error"), ServiceError) and out["error"].status == 429, out


def test_sixteen_concurrent_submissions_with_a_limit_of_three(tmp_path, postgres) -> None:
    data = tmp_path / "data"
    data.mkdir()
    server = LiveServer(data, postgres.new_database(), workers=1).start()  # its threads run the requests at once
    try:
        with ServerClient(server.url, server.admin_token) as admin:
            token = admin.post("/users", {"name": "dev", "role": "developer", "daily_limit": 3})["token"]

        def submit(k: int) -> int:
            with ServerClient(server.url, token, retry_for=10) as c:
                try:
                    c.submit("vision", f"l{k}", benchmark="aido_lf")
                    return 201
                except ServerError as exc:
                    return exc.status

        with ThreadPoolExecutor(16) as pool:
            codes = list(pool.map(submit, range(16)))
    finally:
        server.stop()
    assert sorted(codes) == [201] * 3 + [429] * 13, codes


@pytest.mark.slow
def test_kill_9_and_lease_expiry_during_load_lose_and_duplicate_nothing(tmp_path, postgres) -> None:
    figures = race(postgres.new_database(), tmp_path, seconds=15.0, evaluators=4, lease_seconds=1.0, kill_every=2.5)
    print("\n" + figures.line())
    assert figures.acknowledged >= 10 and figures.late > 0 and figures.evaluator_kills > 2 and figures.server_kills == 1
    assert figures.lost == [], figures.lost[:5]
    assert figures.duplicated == [], figures.duplicated[:5]
    assert figures.disagreements == [], figures.disagreements[:5]
    assert figures.open_jobs == 0, figures.jobs
