"""What an evaluator may claim in a result (issue 23 §5): only artifacts its own lease uploaded (any evaluator
could hand a developer another job's hidden files, or another developer's archive, by naming their hash), and
reports of bounded depth and size (one nested 300 deep was stored, then every read of its submission failed).
SQLite and PostgreSQL.
"""

from __future__ import annotations

import hashlib

import pytest

from test_server_api import Api


@pytest.fixture
def api(tmp_path, database_url):
    return Api(tmp_path, database_url)


def _put(api: Api, data: bytes, lease: dict | None = None) -> str:
    sha = hashlib.sha256(data).hexdigest()
    params = {"job_id": lease["job_id"], "lease_id": lease["lease_id"]} if lease else None
    r = api.c.put(f"/api/v1/artifacts/{sha}", headers=api.ev, content=data, params=params)
    assert r.status_code == 201, r.text
    return sha


def test_a_result_names_only_artifacts_its_own_lease_uploaded(api: Api) -> None:
    api.submit(api.dev, label="mine")
    api.submit(api.dev2, label="theirs")
    mine, theirs = api.lease("e1").json(), api.lease("e2").json()
    secret = _put(api, b"the other job's hidden test trajectories", theirs)
    unbound = _put(api, b"uploaded without a lease")
    own = _put(api, b"my own log", mine)
    for sha in (secret, unbound):
        r = api.finish(mine, artifacts=[{"name": "x", "sha256": sha}])
        assert r.status_code == 422 and "was not uploaded under this lease" in r.json()["detail"], r.text
    assert api.finish(mine, artifacts=[{"name": "log", "sha256": own}]).status_code == 201
    sub = api.c.get("/api/v1/submissions", headers=api.dev).json()[0]
    links = api.c.get(f"/api/v1/submissions/{sub['id']}", headers=api.dev).json()["results"][0]["artifacts"]
    assert [a["sha256"] for a in links] == [own]
    assert api.c.get(f"/api/v1/artifacts/{secret}", headers=api.dev).status_code == 403
    r = api.c.put(f"/api/v1/artifacts/{own}", headers=api.ev, content=b"my own log", params={
        "job_id": theirs["job_id"], "lease_id": "ab" * 16})
    assert r.status_code == 409  # a lease this evaluator does not hold


def test_reports_are_bounded_in_depth_and_size(api: Api) -> None:
    api.submit(api.dev)
    lease = api.lease().json()
    deep: dict = {}
    node = deep
    for _ in range(300):
        node["x"] = {}
        node = node["x"]
    r = api.finish(lease, public_report=deep)
    assert r.status_code == 422 and "public_report is nested" in r.json()["detail"], r.text
    r = api.finish(lease, hidden_report={"stderr": "x" * (5 << 20)})
    assert r.status_code in (413, 422), r.text
    assert api.finish(lease, public_report={"episodes": [{"events": [{"kind": "ok"}]}]}).status_code == 201
    sub = api.c.get("/api/v1/submissions", headers=api.dev).json()[0]
    assert api.c.get(f"/api/v1/submissions/{sub['id']}", headers=api.dev).status_code == 200
