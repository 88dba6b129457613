"""The challenges server's API on SQLite and PostgreSQL: roles, benchmarks, submissions, the job queue,
results exactly once, leaderboards, artifacts and refusals of bad input with the right status codes."""

from __future__ import annotations

import io
import time
import zipfile
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from proxybench.server.app import create_app
from proxybench.server.config import Settings

SCORES = {"driven_lanedir_consec_median": 5.0, "survival_time_median": 60.0,
          "deviation_center_line_median": 0.1, "in_drivable_lane_median": 0.0}


class Api:
    """A test client with one token per role."""

    def __init__(self, tmp: Path, url: str, **settings) -> None:
        self.app = create_app(Settings(data_dir=tmp / "data", database_url=url, **settings))
        self.c = TestClient(self.app)
        self.admin = {"Authorization": f"Bearer {self.app.state.admin_token}"}
        self.dev = self.user("dev", "developer")
        self.dev2 = self.user("dev2", "developer")
        self.ev = self.user("ev", "evaluator")

    def user(self, name: str, role: str, **extra) -> dict[str, str]:
        r = self.c.post("/api/v1/users", headers=self.admin, json={"name": name, "role": role, **extra})
        assert r.status_code == 201, r.text
        return {"Authorization": f"Bearer {r.json()['token']}"}

    def submit(self, who, label="a", agent="vision", benchmark="aido_lf", **kw):
        return self.c.post("/api/v1/submissions", headers=who,
                           json={"label": label, "agent": agent, "benchmark": benchmark, **kw})

    def lease(self, name="e1", features=("sim",)):
        return self.c.post("/api/v1/jobs/lease", headers=self.ev, json={"evaluator": name, "features": list(features)})

    def finish(self, lease, status="success", name="e1", scores=SCORES, **extra):
        body = {"evaluator": name, "lease_id": lease["lease_id"], "status": status, "public_scores": scores,
                "hidden_scores": {k: None if v is None else v + 1 for k, v in scores.items()}, **extra}
        return self.c.post(f"/api/v1/jobs/{lease['job_id']}/result", headers=self.ev, json=body)


@pytest.fixture
def api(tmp_path, database_url):
    return Api(tmp_path, database_url)


def test_roles_and_tokens(api):
    assert api.c.get("/api/v1/me", headers=api.dev).json()["role"] == "developer"
    assert api.c.get("/api/v1/me").status_code == 401
    r = api.c.get("/api/v1/me", headers={"Authorization": "Bearer pbt_wrong"})
    assert r.status_code == 401 and "invalid" in r.json()["detail"]
    r = api.c.post("/api/v1/users", headers=api.dev, json={"name": "x", "role": "developer"})
    assert r.status_code == 403 and "superuser" in r.json()["detail"]
    assert api.c.post("/api/v1/users", headers=api.admin, json={"name": "dev", "role": "developer"}).status_code == 409
    r = api.c.post("/api/v1/users", headers=api.admin, json={"name": "z", "role": "king"})
    assert r.status_code == 422 and "role" in r.json()["detail"]
    # tokens are stored hashed: the plain token appears nowhere in the database
    from sqlalchemy import text

    with api.app.state.engine.connect() as conn:
        hashes = [row[0] for row in conn.execute(text("SELECT token_hash FROM api_tokens"))]
    assert api.dev["Authorization"][7:] not in hashes and len(hashes[0]) == 64


def test_openapi_schema_published(api):
    schema = api.c.get("/api/v1/openapi.json").json()
    assert "/api/v1/jobs/lease" in schema["paths"] and "/api/v1/leaderboards/{name}" in schema["paths"]


def test_job_lifecycle_result_exactly_once_and_leaderboard(api):
    sub = api.submit(api.dev).json()
    assert [j["status"] for j in sub["jobs"]] == ["queued"]
    lease = api.lease().json()
    assert lease["submission"]["agent"] == "vision" and lease["benchmark"]["name"] == "aido_lf"
    assert api.lease().status_code == 204  # nothing else queued
    hb = api.c.post(f"/api/v1/jobs/{lease['job_id']}/heartbeat", headers=api.ev,
                    json={"evaluator": "e1", "lease_id": lease["lease_id"], "progress": {"done": 1, "total": 5}})
    assert hb.status_code == 200
    first = api.finish(lease)
    again = api.finish(lease)  # the evaluator retries its upload (lost reply): stored once
    assert first.status_code == 201 and again.status_code == 200 and again.json()["recorded"] is False
    assert first.json()["id"] == again.json()["id"]
    other = api.c.post(f"/api/v1/jobs/{lease['job_id']}/result", headers=api.ev,
                       json={"evaluator": "e1", "lease_id": "0" * 32, "status": "failed"})
    assert other.status_code == 409
    board = api.c.get("/api/v1/leaderboards/aido_lf", headers=api.dev).json()
    assert [r["label"] for r in board["rows"]] == ["a"]
    assert board["rows"][0]["scores"]["survival_time_median"] == 60.0
    assert api.c.get("/api/v1/leaderboards/aido_lf?split=hidden", headers=api.dev).status_code == 403
    hidden = api.c.get("/api/v1/leaderboards/aido_lf?split=hidden", headers=api.admin).json()
    assert hidden["rows"][0]["scores"]["survival_time_median"] == 61.0
    view = api.c.get(f"/api/v1/submissions/{sub['id']}", headers=api.dev).json()
    assert "hidden_scores" not in view["results"][0] and view["jobs"][0]["status"] == "success"
    assert "hidden_scores" in api.c.get(f"/api/v1/submissions/{sub['id']}", headers=api.admin).json()["results"][0]


def test_leaderboard_ranks_by_semiorder(api):
    for label, lanedir in (("slow", 2.0), ("fast", 9.0), ("mid", 5.0)):
        api.submit(api.dev, label=label)
        assert api.finish(api.lease().json(), scores={**SCORES, "driven_lanedir_consec_median": lanedir}).is_success
    rows = api.c.get("/api/v1/leaderboards/aido_lf", headers=api.dev).json()["rows"]
    assert [r["label"] for r in rows] == ["fast", "mid", "slow"]


def episodes_report(lanedir: list[float], seeds=(11, 12, 13, 14, 15)) -> dict:
    """A per-episode report as the evaluator uploads it: episode index, seed, per-episode scores."""
    return {"episodes": [{"episode": k, "seed": seed, "termination": "timeout",
                          "scores": {"driven_lanedir_consec": v, "survival_time": 60.0, "deviation_center_line": 0.1,
                                     "in_drivable_lane": 0.0}}
                         for k, (seed, v) in enumerate(zip(seeds, lanedir, strict=True))]}


def test_leaderboard_has_bradley_terry_scores_from_the_per_episode_reports(api, monkeypatch):
    """Each row's BT score and 95 % interval, and the board's provisional flag and fragility, from the results'
    per-episode reports (episodes paired by index and seed), computed when the board is built, not on reads; a
    result without a report, or with a malformed one, has no score and breaks nothing."""
    from proxybench.server import leaderboards

    calls = []
    real = leaderboards.board_bradley_terry
    monkeypatch.setattr(leaderboards, "board_bradley_terry", lambda *a: calls.append(1) or real(*a))
    runs = {"fast": [9.0, 9.5, 8.8, 9.1, 9.9], "mid": [5.0, 5.5, 9.0, 5.2, 4.9], "slow": [2.0, 2.5, 1.0, 2.2, 1.9],
            "no report": None, "garbage": "bad"}
    sids = {}
    for label, lanedir in runs.items():
        sids[label] = api.submit(api.dev, label=label).json()["id"]
        report = (episodes_report(lanedir) if isinstance(lanedir, list) else
                  {} if lanedir is None else {"episodes": [1, {"episode": 0}, {"episode": 1, "scores": {"x": "y"}}]})
        med = sorted(lanedir)[2] if isinstance(lanedir, list) else 0.5
        assert api.finish(api.lease().json(), scores={**SCORES, "driven_lanedir_consec_median": med},
                          public_report=report).status_code == 201
    board = api.c.get("/api/v1/leaderboards/aido_lf", headers=api.dev).json()
    built = len(calls)
    for _ in range(3):
        assert api.c.get("/api/v1/leaderboards/aido_lf", headers=api.dev).json() == board
    assert len(calls) == built  # once per change: reads reuse the built board
    bt = board["bt"]
    assert bt["method"] == "bradley-terry" and bt["episodes"] == 5 and bt["resamples"] == 200
    assert bt["compared_on"][:2] == ["driven_lanedir_consec", "survival_time"]
    assert bt["leader"] == sids["fast"] and bt["fragility"]["text"] == str(bt["fragility"]["episodes"] or "")
    rows = {r["label"]: r for r in board["rows"]}
    assert rows["no report"]["bt"] is None and rows["garbage"]["bt"] is None
    fast, mid, slow = (rows[k]["bt"] for k in ("fast", "mid", "slow"))
    assert fast["score"] > mid["score"] > slow["score"]
    assert all(b["lo"] <= b["score"] <= b["hi"] for b in (fast, mid, slow))
    assert bt["provisional"] == (mid["hi"] >= fast["lo"]) and fast["contender"]
    # fast beat mid in 4 of 5 episodes (episode 2 ties within 0.62 m): the lead rests on a few episodes
    assert 1 <= bt["fragility"]["episodes"] <= 4
    hidden = api.c.get("/api/v1/leaderboards/aido_lf?split=hidden", headers=api.admin).json()
    assert hidden["bt"] is None and all(r["bt"] is None for r in hidden["rows"])  # no hidden reports uploaded
    schema = api.c.get("/api/v1/openapi.json").json()["components"]["schemas"]
    assert "bt" in schema["LeaderboardOut"]["properties"] and "BTScoreOut" in schema


def test_a_board_too_large_for_bradley_terry_says_so(api, monkeypatch):
    from proxybench.server import leaderboards

    monkeypatch.setattr(leaderboards, "BT_MAX_AGENTS", 1)
    for label, lanedir in (("a", [1.0] * 5), ("b", [2.0] * 5)):
        api.submit(api.dev, label=label)
        assert api.finish(api.lease().json(), public_report=episodes_report(lanedir)).status_code == 201
    board = api.c.get("/api/v1/leaderboards/aido_lf", headers=api.dev).json()
    assert board["bt"]["provisional"] is None and "at most 1" in board["bt"]["notes"][0]
    assert all(r["bt"] is None for r in board["rows"])


def test_lapsed_lease_is_requeued_then_given_up(tmp_path, database_url):
    api = Api(tmp_path, database_url, lease_seconds=0.2, max_attempts=2)
    api.submit(api.dev)
    first = api.lease("e1").json()
    time.sleep(0.3)
    second = api.lease("e2").json()  # e1 went silent: the job is leased again
    assert second["job_id"] == first["job_id"] and second["attempt"] == 2
    assert api.finish(first, name="e1").status_code == 409  # the stale lease may not report
    time.sleep(0.3)
    assert api.lease("e3").status_code == 204
    job = api.c.get(f"/api/v1/jobs/{first['job_id']}", headers=api.admin).json()
    assert job["status"] == "timeout" and [e["kind"] for e in job["events"]].count("lease-lapsed") == 2
    retried = api.c.post(f"/api/v1/jobs/{first['job_id']}/retry", headers=api.admin)
    assert retried.status_code == 201 and retried.json()["status"] == "queued"


def test_host_error_requeues_elsewhere_and_features_match(api):
    api.submit(api.dev)
    lease = api.lease("e1").json()
    r = api.finish(lease, status="host-error", name="e1", message="no GPU")
    assert r.status_code == 202 and r.json()["requeued"]
    assert api.lease("e1").status_code == 204  # e1 is excluded from this job
    assert api.lease("e2", features=("gpu",)).status_code == 204  # offers no 'sim'
    assert api.lease("e2", features=("sim", "gpu")).json()["job_id"] == lease["job_id"]


def test_submission_limits_and_retiring(tmp_path, database_url):
    api = Api(tmp_path, database_url, daily_submission_limit=2)
    old = api.submit(api.dev, label="same").json()
    new = api.submit(api.dev, label="same").json()
    r = api.submit(api.dev, label="other")
    assert r.status_code == 429 and "limit" in r.json()["detail"]
    olds = api.c.get(f"/api/v1/submissions/{old['id']}", headers=api.dev).json()
    assert olds["status"] == "retired" and olds["jobs"][0]["status"] == "aborted"
    assert api.c.get(f"/api/v1/submissions/{new['id']}", headers=api.dev).json()["status"] == "active"
    assert api.c.get(f"/api/v1/submissions/{new['id']}", headers=api.dev2).status_code == 403
    assert api.submit(api.dev, agent="no-such-agent", label="x").status_code in (422, 429)


def test_privileged_agent_refused_on_camera_only_benchmark(api):
    r = api.submit(api.dev, agent="pid")
    assert r.status_code == 422 and "privileged" in r.json()["detail"] and "aido_lf" in r.json()["detail"]
    assert api.submit(api.dev, agent="pid", benchmark="thesis_loop").status_code == 201


def test_bad_input_refused_with_clear_messages(api):
    r = api.c.post("/api/v1/submissions", headers={**api.dev, "content-type": "application/json"}, content=b"{oops")
    assert r.status_code == 422 and "JSON" in r.json()["detail"]
    r = api.c.post("/api/v1/submissions", headers=api.dev, json={"label": "a", "agent": "pid", "benchmark": "x",
                                                                 "colour": "red"})
    assert r.status_code == 422 and "colour" in r.json()["detail"]
    r = api.submit(api.dev, benchmark="nope")
    assert r.status_code == 404 and "nope" in r.json()["detail"]
    r = api.c.post("/api/v1/benchmarks", headers=api.admin, json={"yaml": "name: [x"})
    assert r.status_code == 422 and "YAML" in r.json()["detail"]
    r = api.c.post("/api/v1/benchmarks", headers=api.admin, json={"yaml": "name: x\nmap: loop_3x3\n"})
    assert r.status_code == 422 and "duration" in r.json()["detail"]
    r = api.c.post("/api/v1/benchmarks", headers=api.admin, json={"yaml": "name: x\nmap: ../../etc/passwd\n"})
    assert r.status_code == 422 and "built-in map" in r.json()["detail"]
    r = api.c.post("/api/v1/users", headers=api.admin, content=b"x" * (9 << 20))
    assert r.status_code == 413


def _zip(files: dict[str, bytes], links: dict[str, str] | None = None) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in files.items():
            zf.writestr(name, data)
        for name, target in (links or {}).items():
            info = zipfile.ZipInfo(name)
            info.external_attr = (0o120777 << 16)
            zf.writestr(info, target)
    return buf.getvalue()


MANIFEST = b"name: mine\nprotocol: aido-z2\ncommand: [python3, agent.py]\n"


def test_archive_submissions_checked_and_artifacts_scoped(api):
    def upload(data: bytes, label: str = "pkg"):
        return api.c.post("/api/v1/submissions/upload", headers=api.dev, data={"label": label, "benchmark": "aido_lf"},
                          files={"archive": ("agent.zip", data, "application/zip")})

    r = upload(_zip({"proxybench-agent.yaml": MANIFEST, "../evil.py": b"x"}))
    assert r.status_code == 422 and "evil.py" in r.json()["detail"]
    r = upload(_zip({"proxybench-agent.yaml": MANIFEST}, links={"link": "/etc/passwd"}))
    assert r.status_code == 422 and "link" in r.json()["detail"]
    r = upload(_zip({"agent.py": b"print()"}))
    assert r.status_code == 422 and "proxybench-agent.yaml" in r.json()["detail"]
    r = upload(_zip({"proxybench-agent.yaml": MANIFEST, "agent.py": b"print()"}))
    assert r.status_code == 201, r.text
    sha = r.json()["archive_sha256"]
    assert api.c.get(f"/api/v1/artifacts/{sha}", headers=api.dev).status_code == 200
    r = api.c.get(f"/api/v1/artifacts/{sha}", headers=api.dev2)
    assert r.status_code == 403 and "another user" in r.json()["detail"]
    r = api.c.get(f"/api/v1/artifacts/{sha}", headers=api.ev)  # evaluators: only archives of jobs they hold
    assert r.status_code == 403
    lease = api.lease().json()
    assert api.c.get(f"/api/v1/artifacts/{sha}", headers=api.ev).status_code == 200
    # evaluator artifacts: hash checked; hidden ones stay hidden from the developer
    log, secret = b"episode log", b"hidden test trajectory"
    import hashlib

    h_log, h_secret = hashlib.sha256(log).hexdigest(), hashlib.sha256(secret).hexdigest()
    under = {"job_id": lease["job_id"], "lease_id": lease["lease_id"]}  # a result names only its lease's uploads
    assert api.c.put(f"/api/v1/artifacts/{h_log}", headers=api.ev, content=b"other bytes").status_code == 422
    assert api.c.put(f"/api/v1/artifacts/{h_log}", headers=api.ev, content=log, params=under).status_code == 201
    assert api.c.put(f"/api/v1/artifacts/{h_secret}", headers=api.ev, content=secret, params=under).status_code == 201
    assert api.c.put(f"/api/v1/artifacts/{h_log}", headers=api.dev, content=log).status_code == 403
    r = api.finish(lease, artifacts=[{"name": "log.txt", "sha256": h_log},
                                     {"name": "test.parquet", "sha256": h_secret, "hidden": True}])
    assert r.status_code == 201
    assert api.c.get(f"/api/v1/artifacts/{h_log}", headers=api.dev).content == log
    assert api.c.get(f"/api/v1/artifacts/{h_secret}", headers=api.dev).status_code == 403
    assert api.c.get(f"/api/v1/artifacts/{h_log}", headers=api.dev2).status_code == 403
    assert api.c.get(f"/api/v1/artifacts/{h_secret}", headers=api.admin).content == secret


def test_oversized_artifact_refused(tmp_path, database_url):
    api = Api(tmp_path, database_url, artifact_max_bytes=1000)
    import hashlib

    data = b"x" * 2000
    r = api.c.put(f"/api/v1/artifacts/{hashlib.sha256(data).hexdigest()}", headers=api.ev, content=data)
    assert r.status_code == 413 and "1000" in r.json()["detail"]
    assert not any(p.is_file() for p in (tmp_path / "data" / "artifacts").rglob("*"))


def test_benchmark_versions_and_path_progression(api):
    text = Path(__file__).parents[1].joinpath("src/proxybench/benchmarks/aido_lf.yaml").read_text()
    changed = text.replace("count: 5", "count: 3")
    r = api.c.post("/api/v1/benchmarks", headers=api.admin, json={"yaml": changed, "features": ["sim"]})
    assert r.status_code == 201 and r.json()["version"] == 2
    dev_view = api.c.get("/api/v1/benchmarks/aido_lf", headers=api.dev).json()
    assert dev_view["version"] == 2 and "test_seed" not in dev_view
    spec = {"steps": [{"id": "sim", "benchmark": "aido_lf"},
                      {"id": "target", "benchmark": "thesis_loop", "features": ["target"]}],
            "edges": [{"source": "sim", "target": "target",
                       "condition": {"metric": "survival_time_median", "min": 30}}]}
    assert api.c.post("/api/v1/paths", headers=api.admin, json={"name": "lf", "spec": spec}).status_code == 201
    bad = {"steps": spec["steps"], "edges": [{"source": "sim", "target": "sim"}]}
    r = api.c.post("/api/v1/paths", headers=api.admin, json={"name": "cyc", "spec": bad})
    assert r.status_code == 422 and "cycle" in r.json()["detail"]
    # passes the condition: the target step opens, and only target-capable evaluators get it
    api.submit(api.dev, label="good", benchmark=None, path="lf")
    r = api.finish(api.lease().json())
    assert len(r.json()["opened_jobs"]) == 1
    assert api.lease(features=("sim",)).status_code == 204
    assert api.lease("t1", features=("sim", "target")).json()["step"] == "target"
    # fails it: the path stops after the first step
    api.submit(api.dev, label="bad", benchmark=None, path="lf")
    r = api.finish(api.lease().json(), scores={**SCORES, "survival_time_median": 3.0})
    assert r.json()["opened_jobs"] == []


def test_restart_keeps_everything(tmp_path, database_url):
    api = Api(tmp_path, database_url)
    sub = api.submit(api.dev).json()
    api.finish(api.lease().json())
    again = TestClient(create_app(Settings(data_dir=tmp_path / "data", database_url=database_url)))
    view = again.get(f"/api/v1/submissions/{sub['id']}", headers=api.dev).json()
    assert view["results"][0]["public_scores"]["survival_time_median"] == 60.0
    assert again.get("/api/v1/benchmarks", headers=api.dev).status_code == 200


def test_success_without_ranking_scores_refused(api):
    api.submit(api.dev)
    lease = api.lease().json()
    r = api.finish(lease, scores={"survival_time_median": 60.0})
    assert r.status_code == 422 and "driven_lanedir_consec_median" in r.json()["detail"]
    r = api.finish(lease, scores={**SCORES, "deviation_center_line_median": None})  # not computable: ranks last
    assert r.status_code == 201
    row = api.c.get("/api/v1/leaderboards/aido_lf", headers=api.dev).json()["rows"][0]
    assert row["scores"]["deviation_center_line_median"] is None


def test_migrations_match_models(database_url):
    """The Alembic revisions create exactly the schema the ORM models describe."""
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    from proxybench.server.db import make_engine, migrate
    from proxybench.server.models import Base

    engine = make_engine(database_url)
    migrate(engine)
    with engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
    assert diff == []


def test_a_change_that_a_reader_built_is_not_built_again_in_the_background(api, monkeypatch):
    """A result asks for a background rebuild (after the board's interval); a read in between builds the board
    at once (small boards); the background run then finds that build began after the change and skips: one
    build per change. (Before: two, and on a busy machine the second landed among later reads.)"""
    from proxybench.server import leaderboards

    builds = []
    real = leaderboards.build_board
    monkeypatch.setattr(leaderboards, "build_board", lambda *a, **k: builds.append(1) or real(*a, **k))
    monkeypatch.setattr(leaderboards, "interval", lambda board: 0.2)
    boards = api.app.state.boards
    for k in range(3):
        api.submit(api.dev, label=f"s{k}")
        lease = api.lease().json()
        assert api.finish(lease, scores={**SCORES, "driven_lanedir_consec_median": float(k)}).status_code == 201
        board = api.c.get("/api/v1/leaderboards/aido_lf", headers=api.dev).json()
        assert board["total"] == k + 1 and not board["stale"]
        boards._background.submit(lambda: None).result(timeout=120)  # the background runs asked for are done
    assert len(builds) == 3


def test_leaderboards_are_built_once_per_change_incrementally_and_revalidate(api, monkeypatch):
    """Boards are rebuilt when results arrive (incrementally: only new results read), never on a read; the
    incremental board equals a full rebuild, retirements included; ETag / If-None-Match answer 304."""
    from proxybench.server import leaderboards

    builds = []
    real = leaderboards.build_board
    monkeypatch.setattr(leaderboards, "build_board", lambda *a, **k: builds.append(k.get("since")) or real(*a, **k))
    subs = []
    for k in range(6):
        subs.append(api.submit(api.dev, label=f"s{k}").json()["id"])
        lease = api.lease().json()
        assert api.finish(lease, scores={**SCORES, "driven_lanedir_consec_median": float(k)}).status_code == 201
        board = api.c.get("/api/v1/leaderboards/aido_lf", headers=api.dev).json()  # read after write: fresh
        assert board["total"] == k + 1 and board["rows"][0]["label"] == f"s{k}" and not board["stale"]
    n = len(builds)
    for _ in range(5):  # reads without changes build nothing
        r = api.c.get("/api/v1/leaderboards/aido_lf", headers=api.dev)
    assert len(builds) == n and any(since is not None for since in builds)  # incremental after the first
    etag = r.headers["etag"]
    assert r.headers["cache-control"].startswith("private") and r.headers["last-modified"]
    again = api.c.get("/api/v1/leaderboards/aido_lf", headers={**api.dev, "if-none-match": etag})
    assert again.status_code == 304 and again.content == b""
    assert api.c.post(f"/api/v1/submissions/{subs[5]}/retire", headers=api.dev).status_code == 200
    board = api.c.get("/api/v1/leaderboards/aido_lf?limit=2&offset=1", headers=api.dev).json()
    assert board["total"] == 5 and [r["label"] for r in board["rows"]] == ["s3", "s2"]
    whole = api.c.get("/api/v1/leaderboards/aido_lf", headers=api.dev).json()
    bench_id = api.c.get("/api/v1/benchmarks/aido_lf", headers=api.admin).json()
    with api.app.state.sessions() as session:
        from proxybench.server.leaderboards import resolve_version

        full = real(session, resolve_version(session, "aido_lf", bench_id["version"])[0], "public")[1]
    assert whole["rows"] == full["rows"]  # the incremental board is the full one
    assert api.c.get("/api/v1/leaderboards/aido_lf", headers={**api.dev, "if-none-match": etag}).status_code == 200
