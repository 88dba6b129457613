"""Hostile and malformed input: each is refused quickly with a 4xx that names the problem, never a 500
(SQLite and PostgreSQL). Archive bombs go through the upload endpoint (the server's own limits); the times
are printed (not asserted: the machine may be busy).
"""

from __future__ import annotations

import gzip
import io
import json
import struct
import tarfile
import time
import zipfile
import zlib

import numpy as np
import pytest

from test_server_api import SCORES, Api

MANIFEST = b"name: mine\nprotocol: aido-z2\ncommand: [python3, agent.py]\n"


@pytest.fixture
def api(tmp_path, database_url):
    return Api(tmp_path, database_url)


# -- archive bombs and broken archives ---------------------------------------------------------------------


def empty_headers_targz(n: int) -> bytes:
    """A tar.gz of ``n`` empty files (distinct names): a few hundred KB that stdlib tarfile lists for minutes."""
    info = tarfile.TarInfo("f0000000")
    info.mtime = 0
    header = np.frombuffer(info.tobuf(tarfile.USTAR_FORMAT), dtype=np.uint8)
    rows = np.tile(header, (n, 1))
    idx = np.arange(n)
    for k in range(7):
        rows[:, 1 + k] = ord("0") + (idx // 10 ** (6 - k)) % 10
    rows[:, 148:156] = ord(" ")
    checksum = rows.astype(np.int64).sum(axis=1)
    for k in range(6):
        rows[:, 148 + k] = ord("0") + ((checksum >> (3 * (5 - k))) & 7)
    rows[:, 154] = 0
    return gzip.compress(rows.tobytes() + b"\0" * 1024, 1)


def zip_of(files: dict[str, bytes], method: int = zipfile.ZIP_DEFLATED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=method) as zf:
        for name, data in files.items():
            zf.writestr(name, data)
    return buf.getvalue()


def big_manifest_zip() -> bytes:
    """25 KB on the wire, a 24 MiB manifest once inflated."""
    return zip_of({"proxybench-agent.yaml": MANIFEST + b"#" * (24 << 20), "agent.py": b""})


def declared_bomb_zip() -> bytes:
    """A member whose header declares 4 GiB (zip64): refused from the directory, nothing inflated."""
    data = bytearray(zip_of({"proxybench-agent.yaml": MANIFEST, "blob": b"x" * 1000}))
    # patch the central directory's uncompressed size of "blob" to 0xFFFFFFFE bytes
    cd = data.rfind(b"PK\x01\x02")
    struct.pack_into("<L", data, cd + 24, 0xFFFFFFFE)
    return bytes(data)


def many_entries_zip(n: int) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_STORED) as zf:
        for i in range(n):
            zf.writestr(f"d/{i}", b"")
        zf.writestr("proxybench-agent.yaml", MANIFEST)
    return buf.getvalue()


def bad_crc_zip() -> bytes:
    data = bytearray(zip_of({"proxybench-agent.yaml": MANIFEST, "agent.py": b"print('hello world')\n" * 50},
                            zipfile.ZIP_STORED))
    at = data.find(b"print('hello")
    data[at] ^= 0xFF  # one flipped byte in a stored member
    return bytes(data)


def encrypted_zip() -> bytes:
    data = bytearray(zip_of({"proxybench-agent.yaml": MANIFEST, "agent.py": b"x"}))
    for sig, flags_at in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):  # set the "encrypted" bit everywhere
        at = data.find(sig)
        while at >= 0:
            struct.pack_into("<H", data, at + flags_at, struct.unpack_from("<H", data, at + flags_at)[0] | 1)
            at = data.find(sig, at + 4)
    return bytes(data)


def huge_pax_targz() -> bytes:
    """A pax extended header claiming 200 MiB (tarfile would read it all into memory first)."""
    info = tarfile.TarInfo("././@PaxHeader")
    info.type = tarfile.XHDTYPE
    info.size = 200 << 20
    header = info.tobuf(tarfile.USTAR_FORMAT)
    comp = zlib.compressobj(1, zlib.DEFLATED, 31)
    out = [comp.compress(header)]
    zeros = b"\0" * (1 << 20)
    for _ in range(200):
        out.append(comp.compress(zeros))
    out.append(comp.flush())
    return b"".join(out)


def manifest_zip(text: bytes) -> bytes:
    return zip_of({"proxybench-agent.yaml": text, "agent.py": b""})


CASES = {
    "tar.gz of 200,000 empty headers": (lambda: empty_headers_targz(200_000), "more than 10000 members"),
    "zip with a 24 MiB manifest": (big_manifest_zip, "proxybench-agent.yaml"),
    "zip declaring a 4 GiB member": (declared_bomb_zip, "bytes"),
    "zip with 20,000 entries": (lambda: many_entries_zip(20_000), "members"),
    "zip with a bad CRC": (bad_crc_zip, "agent.py"),
    "zip with an encrypted member": (encrypted_zip, "encrypted"),
    "manifest nested 30,000 deep": (lambda: manifest_zip(b"name: " + b"[" * 30_000), "nested deeper"),
    "manifest with an alias bomb": (lambda: manifest_zip(
        b"a: &a [x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
        b"c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]\nname: [*c, *c, *c, *c, *c, *c, *c, *c, *c]\n"), "aliases"),
    "manifest with a NUL in the command": (lambda: manifest_zip(
        b'name: x\nprotocol: aido-z2\ncommand: ["py\\0thon"]\n'), "NUL"),
    "manifest not UTF-8": (lambda: manifest_zip(b"name: \xff\xfe\n"), "UTF-8"),
    "tar.gz with a 200 MiB pax header": (huge_pax_targz, "extension header"),
    "truncated tar.gz": (lambda: gzip.compress(b"\0" * 5000)[:-30] + b"", "archive"),
    "random bytes": (lambda: np.random.default_rng(0).bytes(10_000), "archive"),
    "empty file": (lambda: b"", "empty"),
}


def test_archive_bombs_and_broken_archives_are_refused_quickly(api):
    timings = []
    for name, (make, expect) in CASES.items():
        data = make()
        t0 = time.perf_counter()
        r = api.c.post("/api/v1/submissions/upload", headers=api.dev, data={"label": "bomb", "benchmark": "aido_lf"},
                       files={"archive": ("agent.tar.gz", data, "application/octet-stream")})
        seconds = time.perf_counter() - t0
        timings.append((name, len(data), r.status_code, seconds))
        assert r.status_code in (413, 422), (name, r.status_code, r.text[:300])
        assert expect in r.json()["detail"], (name, r.json()["detail"])
    width = max(len(n) for n, *_ in timings)
    print("\n" + "\n".join(f"  {n:<{width}}  {size:>10,} B  {status}  {s * 1000:7.0f} ms"
                            for n, size, status, s in timings))
    assert api.c.get("/api/v1/submissions", headers=api.dev).json() == []  # nothing was stored


# -- malformed requests -----------------------------------------------------------------------------------


def test_malformed_requests_get_4xx_naming_the_problem(api):
    r = api.c.post("/api/v1/submissions", headers={**api.dev, "content-type": "application/json"},
                   content=b"[" * 100_000 + b"]" * 100_000)
    assert r.status_code == 400 and "nested too deeply" in r.json()["detail"]
    r = api.c.post("/api/v1/submissions", headers={**api.dev, "content-type": "application/json"},
                   content=b'{"label": "\xff\xfe", "agent": "vision", "benchmark": "aido_lf"}')
    assert 400 <= r.status_code < 500
    r = api.c.post("/api/v1/benchmarks", headers=api.admin, json={"yaml": "name: " + "[" * 50_000})
    assert r.status_code == 422 and "nested deeper" in r.json()["detail"]
    r = api.c.post("/api/v1/users", headers=api.admin, json={"name": "x", "role": "developer", "daily_limit": 2**40})
    assert r.status_code == 422 and "daily_limit" in r.json()["detail"]
    r = api.c.post("/api/v1/jobs/lease", headers=api.ev, json={"evaluator": "e\x00vil"})
    assert r.status_code == 422 and "evaluator" in r.json()["detail"]
    for url in ("/api/v1/jobs/99999999999", f"/api/v1/submissions/{2**31}", f"/api/v1/jobs/{2**70}",
                f"/api/v1/benchmarks/aido_lf?version={2**40}", f"/api/v1/leaderboards/aido_lf?version={2**40}",
                "/api/v1/jobs/0", "/api/v1/jobs/-1"):
        r = api.c.get(url, headers=api.admin)
        assert r.status_code == 422 and r.json()["detail"], (url, r.status_code, r.text[:200])
    r = api.c.post(f"/api/v1/tokens/{2**33}/revoke", headers=api.admin)
    assert r.status_code == 422
    r = api.c.post(f"/api/v1/jobs/{2**40}/heartbeat", headers=api.ev, json={"evaluator": "e", "lease_id": "ab"})
    assert r.status_code == 422


def _finish_raw(api, lease, body: bytes):
    return api.c.post(f"/api/v1/jobs/{lease['job_id']}/result", headers={**api.ev, "content-type": "application/json"},
                      content=body)


def test_non_finite_scores_are_refused_and_agent_text_is_cleaned(api):
    api.submit(api.dev)
    lease = api.lease().json()
    cases = ((b"Infinity", b"public_scores"), (b"NaN", b"hidden_scores"), (b"-Infinity", b"public_report"))
    for literal, field in cases:
        scores = b"{" + b", ".join(b'"%s": %s' % (k.encode(), literal if i == 0 else b"1.0")
                                  for i, k in enumerate(SCORES)) + b"}"
        ok = b'{"driven_lanedir_consec_median": 1, "survival_time_median": 1, "deviation_center_line_median": 1, ' \
             b'"in_drivable_lane_median": 1}'
        parts = {b"public_scores": ok, b"hidden_scores": ok, b"public_report": b"{}"}
        parts[field] = scores
        body = (b'{"evaluator": "e1", "lease_id": "%s", "status": "success", "public_scores": %s, '
                b'"hidden_scores": %s, "public_report": %s}' % (lease["lease_id"].encode(), parts[b"public_scores"],
                                                               parts[b"hidden_scores"], parts[b"public_report"]))
        r = _finish_raw(api, lease, body)
        assert r.status_code == 422 and field.decode() in r.json()["detail"] and "finite" in r.json()["detail"], r.text
    # a NUL byte in the agent's stderr (was: PostgreSQL refused the result with a 500, the evaluator retried)
    stderr = "Traceback ...\x00\x00 garbage \ud800 end"  # NULs and a lone surrogate (\\ud800 in JSON)
    body = {"evaluator": "e1", "lease_id": lease["lease_id"], "status": "failed", "message": f"agent crashed: {stderr}",
            "public_report": {"agent_failures": [{"stderr_tail": [stderr], "n\x00": 1}]}}
    r = _finish_raw(api, lease, json.dumps(body).encode())  # ASCII JSON: escapes carry what UTF-8 cannot
    assert r.status_code == 201, r.text
    got = api.c.get(f"/api/v1/submissions/{api.c.get('/api/v1/submissions', headers=api.dev).json()[0]['id']}",
                    headers=api.dev).json()["results"][0]
    assert "\x00" not in got["message"] and "\ufffd garbage" in got["message"]
    failure = got["public_report"]["agent_failures"][0]
    assert failure["stderr_tail"] == ["Traceback ...\ufffd\ufffd garbage \ufffd end"] and "n\ufffd" in failure


def test_leases_follow_the_monotonic_server_clock(api, monkeypatch):
    """A wall-clock step of a day (NTP, a manual date -s) neither lapses a lease nor keeps a dead one alive."""
    api.submit(api.dev)
    lease = api.lease("e1").json()
    real = time.time
    monkeypatch.setattr(time, "time", lambda: real() + 86_400)
    assert api.lease("e2").status_code == 204  # e1's lease still holds
    hb = api.c.post(f"/api/v1/jobs/{lease['job_id']}/heartbeat", headers=api.ev,
                    json={"evaluator": "e1", "lease_id": lease["lease_id"]})
    assert hb.status_code == 200
    assert api.finish(lease, name="e1").status_code == 201


def test_large_uploads_without_a_valid_token_are_refused_before_their_body(api):
    """An artifact or archive upload is read (and spooled to disk) only for a caller with a live token."""
    import hashlib

    data = b"x" * 200_000
    sha = hashlib.sha256(data).hexdigest()
    spool = api.app.state.settings.data_dir / "spool"
    for headers in ({}, {"Authorization": "Bearer pbt_not-a-real-token-at-all"}):
        r = api.c.put(f"/api/v1/artifacts/{sha}", headers=headers, content=data)
        assert r.status_code == 401 and "before their body is read" in r.json()["detail"]
        r = api.c.post("/api/v1/submissions/upload", headers=headers, data={"label": "x", "benchmark": "aido_lf"},
                       files={"archive": ("a.zip", data, "application/zip")})
        assert r.status_code == 401
    assert not list(spool.glob(".body-*"))
    assert api.c.put(f"/api/v1/artifacts/{sha}", headers=api.ev, content=data).status_code == 201
