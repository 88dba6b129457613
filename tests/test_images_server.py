"""Container images submitted to the challenges server (issue 37's end-to-end test): an image built here from
Debian's packages (its own Python) is uploaded as an OCI archive or a `docker save` tarball, checked by the server
as the evaluator checks it, stored, leased, unpacked into the evaluator's image cache, run in the sandbox and ranked
on the leaderboard. A hostile image is refused at upload with a one-line reason naming the layer and member (and
nothing is stored), or, when its bytes are clean but its agent attacks, ends ``failed`` with its reason and leaves
nothing behind."""

from __future__ import annotations

import json
import os
import subprocess
import tarfile
from pathlib import Path

import pytest

from proxybench.client import ServerError
from support.images import agent_image, member, oci_layout, tar_layer
from support.sandbox import AGENT_USER_GROUP, processes_left, require_safe_sandbox
from test_evaluator import Served, evaluator, the_job
from test_evaluator import served as served_fixture  # noqa: F401 - the fixture, under this name

pytestmark = AGENT_USER_GROUP  # its agents run as the agent user: one test at a time
AGENT = Path(__file__).with_name("image_agents") / "z2_agent.py"
HOSTILE = Path(__file__).with_name("hostile_agents") / "hostile.py"


@pytest.fixture(scope="module")
def archives(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The z2 agent's image as an OCI archive and as `docker save` writes it, built once."""
    require_safe_sandbox()
    root = tmp_path_factory.mktemp("image-archives")
    layout = agent_image(root / "layout", AGENT)
    out = {"oci-archive": root / "agent.oci.tar", "docker-archive": root / "agent.docker.tar"}
    for form, path in out.items():
        ref = f"{path}:agent:latest" if form == "docker-archive" else f"{path}:latest"
        subprocess.run(["skopeo", "--insecure-policy", "copy", "-q", f"oci:{layout}:latest", f"{form}:{ref}"],
                       check=True)
    return out


@pytest.fixture(autouse=True)
def _cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The evaluator's image cache, one per test (its worker inherits the variable)."""
    cache = tmp_path / "image-cache"
    monkeypatch.setenv("PROXYBENCH_IMAGE_CACHE", str(cache))
    return cache


def oci_archive(layout: Path, dest: Path) -> Path:
    """An OCI archive: the layout folder's files in a tar, as `skopeo copy … oci-archive:` writes it."""
    with tarfile.open(dest, "w") as tf:
        for path in sorted(layout.rglob("*")):
            tf.add(path, arcname=str(path.relative_to(layout)), recursive=False)
    return dest


def _stored(srv: Served) -> list[str]:
    return sorted(p.name for p in (srv.data_dir / "artifacts").rglob("*") if p.is_file())


@pytest.mark.parametrize("form", ["oci-archive", "docker-archive"])
def test_a_submitted_image_is_evaluated_and_ranked(served_fixture: Served, tmp_path: Path,  # noqa: F811
                                                   archives: dict[str, Path], _cache: Path, form: str) -> None:
    served = served_fixture
    sub = served.developer.submit_archive(archives[form], "z2-image", benchmark="tiny_open")
    assert sub["status"] == "active"
    ev = evaluator(served, tmp_path, video=False)
    assert ev.take_one() == "success"
    job, (result,) = the_job(served, sub["id"])
    assert job["status"] == "success", job["message"]
    # the agent exits 5 unless it runs on the image's /usr/bin/python3 with no proxybench importable
    assert result["public_scores"]["survival_time_median"] == pytest.approx(2.0)
    assert [e["termination"] for e in result["public_report"]["episodes"]] == ["timeout"] * 2
    assert [r["label"] for r in served.developer.leaderboard("tiny_open")["rows"]] == ["z2-image"]
    assert len(list((_cache / "rootfs").glob("*.json"))) == 1  # unpacked into the evaluator's cache, once
    assert processes_left(require_safe_sandbox().uid) == []


def _refused(srv: Served, archive: Path, label: str) -> str:
    before = _stored(srv)
    with pytest.raises(ServerError) as err:
        srv.developer.submit_archive(archive, label, benchmark="tiny_open")
    assert err.value.status == 422
    assert _stored(srv) == before and srv.developer.get("/submissions") == []  # nothing stored
    message = str(err.value)
    assert "\n" not in message and str(archive.parent) not in message
    return message


def test_a_hostile_image_is_refused_at_upload(served_fixture: Served, tmp_path: Path) -> None:  # noqa: F811
    served = served_fixture
    require_safe_sandbox()
    escape = tar_layer([member("escape", tarfile.SYMTYPE, linkname="/tmp"), member("escape/pwned", data=b"x")])
    archive = oci_archive(oci_layout(tmp_path / "escape", [escape], {"Cmd": ["/bin/true"]}), tmp_path / "escape.tar")
    message = _refused(served, archive, "escape")
    assert "archive 'escape.tar': layer 0 (sha256:" in message
    assert "member 'escape/pwned' is written through the symbolic link 'escape'" in message
    assert not Path("/tmp/pwned").exists()

    plain = tar_layer([member("a.txt", data=b"a")])
    lying = oci_layout(tmp_path / "lying", [plain], {"Cmd": ["/bin/true"]}, diff_ids=["sha256:" + "0" * 64])
    assert "diff_id" in _refused(served, oci_archive(lying, tmp_path / "lying.tar"), "lying")

    labelled = oci_layout(tmp_path / "labelled", [plain], {"Cmd": ["/bin/true"],
                                                           "Labels": {"org.proxybench.agent.step_timeout": "999"}})
    message = _refused(served, oci_archive(labelled, tmp_path / "labelled.tar"), "labelled")
    assert "label org.proxybench.agent.step_timeout:" in message and "30" in message


def test_an_image_whose_agent_attacks_ends_failed_with_its_reason(served_fixture: Served,  # noqa: F811
                                                                  tmp_path: Path) -> None:
    """Clean bytes, hostile agent: the server stores it, the evaluator runs it, it ends `failed` naming the node's
    end, its attack shows it ran and was stopped, and no process of it is left."""
    served = served_fixture
    isolation = require_safe_sandbox()
    work = tmp_path / "work-e1"
    targets = {"secrets": ["/etc/shadow"], "work_dir": str(work), "evaluator_pid": os.getpid(),
               "db": str(served.data_dir / "proxybench.sqlite3"), "data_dir": str(served.data_dir),
               "listener_port": 9, "server_port": int(served.url.rsplit(":", 1)[1])}
    layout = agent_image(tmp_path / "hostile", HOSTILE, args=("kill_parent",), user="4242:4242", workdir="/agent",
                         at="agent", files={"targets.json": json.dumps(targets).encode()})
    archive = tmp_path / "hostile.tar"
    subprocess.run(["skopeo", "--insecure-policy", "copy", "-q", f"oci:{layout}:latest", f"oci-archive:{archive}"],
                   check=True)
    sub = served.developer.submit_archive(archive, "hostile-image", benchmark="tiny_open")
    ev = evaluator(served, tmp_path, video=False)
    assert ev.take_one() == "failed"
    job, (result,) = the_job(served, sub["id"])
    assert job["status"] == "failed"
    assert "the agent failed the agent contract before its episodes" in result["message"]
    (failure,) = result["public_report"]["agent_failures"]
    stderr = "\n".join(failure["stderr_tail"])
    assert "ATTEMPTED kill_parent" in stderr and "now kill(-1)" in stderr and "ESCAPED" not in stderr
    assert served.developer.leaderboard("tiny_open")["rows"] == []
    assert processes_left(isolation.uid) == []


def test_an_image_has_its_own_size_limit_and_each_refusal_names_its_setting(tmp_path: Path,
                                                                          archives: dict[str, Path]) -> None:
    """AIDO images are hundreds of MB, packages a few: an upload told to be an image is held to image_max_bytes,
    a package to archive_max_bytes, and the 413 names the setting to raise; nothing is stored by a refusal."""
    import io
    import zipfile

    from fastapi.testclient import TestClient

    from proxybench.server.app import create_app
    from proxybench.server.config import Settings

    image = archives["oci-archive"]
    size = image.stat().st_size
    package = io.BytesIO()
    with zipfile.ZipFile(package, "w", zipfile.ZIP_STORED) as zf:
        zf.writestr("proxybench-agent.yaml", "name: big\ncommand: python3 agent.py\n")
        zf.writestr("weights.bin", os.urandom(2 << 20))

    def upload(client: TestClient, who: dict, name: str, data: bytes) -> tuple[int, str]:
        r = client.post("/api/v1/submissions/upload", headers=who, data={"label": name, "benchmark": "aido_lf"},
                        files={"archive": (name, data, "application/octet-stream")})
        return r.status_code, r.text

    for image_max, image_ok in ((size + 10, True), (size - 1, False)):
        data_dir = tmp_path / f"server-{image_max}"
        app = create_app(Settings(data_dir=data_dir, archive_max_bytes=1 << 20, image_max_bytes=image_max))
        with TestClient(app) as client:
            admin = {"Authorization": f"Bearer {app.state.admin_token}"}
            token = client.post("/api/v1/users", headers=admin, json={"name": "dev", "role": "developer"}).json()
            dev = {"Authorization": f"Bearer {token['token']}"}
            status, text = upload(client, dev, "image.tar", image.read_bytes())
            if image_ok:  # 50 MB over the package limit, under the image limit
                assert status == 201, text
            else:
                assert status == 413 and "image_max_bytes" in text and "image.tar" in text, text
            status, text = upload(client, dev, "big.zip", package.getvalue())
            assert status == 413 and "archive_max_bytes" in text and "big.zip" in text, text
            stored = [p for p in (data_dir / "artifacts").rglob("*") if p.is_file()]
            assert len(stored) == (1 if image_ok else 0)


def test_a_download_is_streamed_and_a_corrupt_or_broken_one_is_a_host_side_error(tmp_path: Path) -> None:
    """The evaluator writes a submission's archive as it arrives (an image is not held in memory); bytes that do
    not hash to the submitted digest, or a transfer that breaks off, are the transfer's fault (status 0)."""
    import hashlib

    import httpx

    from proxybench.client import ServerClient

    body = os.urandom(3 << 20)
    good = hashlib.sha256(body).hexdigest()

    def handler(request: httpx.Request) -> httpx.Response:
        if request.url.path.endswith(good):
            return httpx.Response(200, content=body)
        if request.url.path.endswith("0" * 64):
            raise httpx.ReadError("connection reset", request=request)
        return httpx.Response(200, content=body[:-1] + b"x")

    client = ServerClient("http://server.invalid", "pbt_x")
    client.http = httpx.Client(base_url="http://server.invalid/api/v1", transport=httpx.MockTransport(handler))
    chunks = list(client.stream_artifact(good, chunk=1 << 20))
    assert len(chunks) == 3 and b"".join(chunks) == body
    for sha, says in (("f" * 64, "do not match their hash"), ("0" * 64, "broke off")):
        with pytest.raises(ServerError, match=says) as err:
            list(client.stream_artifact(sha))
        assert err.value.status == 0
