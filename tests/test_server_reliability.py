"""The server under load, killed and restarted: no accepted submission or acknowledged result is lost,
and no job gets two results (SQLite and PostgreSQL)."""

from __future__ import annotations

import threading
import time

import pytest
from sqlalchemy import create_engine, text

from proxybench.client import ServerClient, ServerError
from support.live_server import LiveServer

SCORES = {"driven_lanedir_consec_median": 5.0, "survival_time_median": 60.0,
          "deviation_center_line_median": 0.1, "in_drivable_lane_median": 0.0}


def _submitter(server: LiveServer, token: str, stop: threading.Event, accepted: list[int], errors: list[str]):
    with ServerClient(server.url, token, retry_for=60.0) as c:
        n = 0
        while not stop.is_set():
            n += 1
            try:
                accepted.append(c.submit("vision", f"s{threading.get_ident()}-{n}", benchmark="aido_lf")["id"])
            except ServerError as exc:
                errors.append(str(exc))


def _evaluator(server: LiveServer, token: str, name: str, stop: threading.Event, recorded: list[int],
               errors: list[str]):
    with ServerClient(server.url, token, retry_for=60.0) as c:
        while not stop.is_set():
            try:
                job = c.lease(name, ["sim"])
                if job is None:
                    time.sleep(0.05)
                    continue
                body = {"evaluator": name, "lease_id": job.lease_id, "status": "success",
                        "public_scores": SCORES, "hidden_scores": SCORES}
                c.result(job.job_id, body)  # retried through a restart: the same lease, stored once
                recorded.append(job.job_id)
            except ServerError as exc:
                errors.append(str(exc))


@pytest.mark.slow
def test_restart_under_load_loses_nothing(tmp_path, database_url):
    data = tmp_path / "data"
    data.mkdir()
    server = LiveServer(data, database_url).start()
    admin = server.admin_token
    with ServerClient(server.url, admin) as c:
        ev_token = c.post("/users", {"name": "ev", "role": "evaluator"})["token"]
    stop = threading.Event()
    accepted: list[int] = []
    recorded: list[int] = []
    errors: list[str] = []
    threads = [threading.Thread(target=_submitter, args=(server, admin, stop, accepted, errors)) for _ in range(3)]
    threads += [threading.Thread(target=_evaluator, args=(server, ev_token, f"e{i}", stop, recorded, errors))
                for i in range(2)]
    for t in threads:
        t.start()
    try:
        time.sleep(2.0)
        server.kill()  # SIGKILL mid-traffic
        before = len(accepted)
        server.start()
        time.sleep(5.0)  # clients come back from their retry back-off (up to 5 s) and carry on
    finally:
        stop.set()
        for t in threads:
            t.join(90)
        server.stop()
    assert before > 0 and len(accepted) > before and recorded, (len(accepted), len(recorded), errors[:3])
    assert errors == [] or all("already" in e or "no longer held" in e for e in errors), errors[:5]
    engine = create_engine(database_url)
    with engine.connect() as conn:
        stored = {r[0] for r in conn.execute(text("SELECT id FROM submissions"))}
        results = [r[0] for r in conn.execute(text("SELECT job_id FROM results"))]
    engine.dispose()
    assert set(accepted) <= stored  # every 201 the clients saw is in the database
    assert set(recorded) <= set(results)  # every acknowledged result too
    print(f"{len(accepted)} submissions accepted ({before} before the kill), {len(recorded)} results")
    assert len(results) == len(set(results))  # and never twice for one job
