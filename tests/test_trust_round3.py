"""Issue 38 (trust, round 3): a lab's logs are strangers' input (``localize``), the DTPS server is a robot (its
tests need the SDK environment: mark ``sdk``), and protocol numbers of any size.
"""

from __future__ import annotations

import os
import random
import sys
import time
from pathlib import Path

import cbor2
import numpy as np
import pytest
import yaml

from proxybench.autolab import target as target_mod
from proxybench.autolab.calibration import Calibration, Extrinsics, _Matrix, write_calibration
from proxybench.autolab.localize import Localization, RobotTrack
from proxybench.autolab.logs import read_log
from proxybench.autolab.validate import Verdict
from proxybench.autolab.watchtowers import LayoutError, UnsafeLogError
from proxybench.domain.maps import load_map
from support.dtps import sdk

# -- a small folder log ------------------------------------------------------------------------------------


def _calibration(name: str = "wt01") -> Calibration:
    return Calibration(name=name, image_width=32, image_height=24,
                       camera_matrix=_Matrix(rows=3, cols=3, data=[30.0, 0, 16, 0, 30.0, 12, 0, 0, 1]),
                       extrinsics=Extrinsics(position=(0.5, 0.5, 0.8), yaw=90.0, pitch=89.0))


def make_log(root: Path, manifest: dict | str | None = None, frames: int = 3) -> Path:
    """A log folder: ``log.yaml`` (a mapping, or text as it is), one watchtower with ``frames`` tiny frames."""
    tower = root / "watchtowers" / "wt01"
    tower.mkdir(parents=True)
    write_calibration(tower / "calibration.yaml", _calibration())
    (tower / "timestamps.csv").write_text("frame,t\n" + "".join(f"{k},{0.1 * k:.3f}\n" for k in range(frames)))
    for k in range(frames):
        (tower / f"{k:06d}.jpg").write_bytes(b"\xff\xd8 not really a jpeg")
    if manifest is not None:
        text = manifest if isinstance(manifest, str) else yaml.safe_dump(manifest)
        (root / "log.yaml").write_text(text)
    return root


def _tree(root: Path) -> set[str]:
    """Every path under ``root`` (links not followed), relative."""
    out = set()
    for dirpath, dirnames, filenames in os.walk(root):
        for n in dirnames + filenames:
            out.add(os.path.relpath(os.path.join(dirpath, n), root))
    return out


@pytest.fixture
def fake_localisation(monkeypatch):
    """``localize_logs`` without detection: every run valid, each robot of the log seen twice."""

    def localize_log(log, m, *, robots=None, **_):
        names = set((robots or log.manifest.robots or {400: "ego"}).values()) | {log.manifest.active}
        tracks = {n: RobotTrack(n, np.array([0.0, 0.1]), np.zeros((2, 3)), np.full((2, 3), 0.01),
                                np.ones(2, dtype=np.int64)) for n in names}
        return Localization(tracks, {}, {}, 2, 2)

    monkeypatch.setattr(target_mod, "localize_log", localize_log)
    monkeypatch.setattr(target_mod, "validate_run", lambda log, loc, limits=None: Verdict(True))


HOSTILE = ["../x", "../../results", "/tmp/results", "a/b", "a\x00b", ".", "..", "x\\..\\y", "~root", "\n"]


# -- 1. names from log.yaml --------------------------------------------------------------------------------


@pytest.mark.parametrize("field", ["agent", "active", "robots"])
@pytest.mark.parametrize("value", HOSTILE, ids=repr)
def test_a_name_that_is_a_path_is_refused_naming_the_field_and_value(tmp_path, field, value, fake_localisation):
    manifest = {"agent": "pid", "robots": {400: "ego"}}
    manifest[field] = {400: value} if field == "robots" else value
    log = make_log(tmp_path / "logs" / "run", manifest)
    before = _tree(tmp_path)
    with pytest.raises(UnsafeLogError) as err:
        target_mod.localize_logs(log, load_map("straight_road"), tmp_path / "out" / "T")
    msg = str(err.value)
    assert len(msg.splitlines()) == 1, msg
    assert ("robots.400" if field == "robots" else field) in msg and repr(value)[:20] in msg, msg
    assert _tree(tmp_path) == before  # nothing written, anywhere


def test_localize_exits_2_with_one_line_and_writes_nothing_for_a_relative_robot_name(tmp_path):
    from typer.testing import CliRunner

    from proxybench.cli import app

    log = make_log(tmp_path / "lab" / "run", {"agent": "pid", "robots": {400: "../../escaped"}})
    results = tmp_path / "results.csv"
    results.write_text("keep me\n")
    before = _tree(tmp_path)
    res = CliRunner().invoke(app, ["localize", str(log), "--map", "straight_road", "--out", str(tmp_path / "a" / "T"),
                                   "--workers", "1"])
    assert res.exit_code == 2, res.output
    assert "robots.400: '../../escaped' is not a single file name" in res.output
    assert "Traceback" not in res.output and (res.exception is None or isinstance(res.exception, SystemExit))
    assert _tree(tmp_path) == before and results.read_text() == "keep me\n"


def test_an_agent_name_from_the_command_line_is_checked_too(tmp_path):
    log = make_log(tmp_path / "run", {"agent": "pid"})
    with pytest.raises(UnsafeLogError, match=r"agent: '/etc/x'"):
        read_log(log, overrides={"agent": "/etc/x"})


def test_a_deeply_nested_log_yaml_is_one_line_error(tmp_path):
    log = make_log(tmp_path / "run", "agent: pid\nx: " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(UnsafeLogError) as err:
        read_log(log)
    assert "nested deeper than" in str(err.value) and len(str(err.value).splitlines()) == 1


def test_log_yaml_and_calibration_may_not_be_links(tmp_path):
    outside = tmp_path / "outside.yaml"
    outside.write_text("agent: pid\n")
    log = make_log(tmp_path / "run", None)
    (log / "log.yaml").symlink_to(outside)
    with pytest.raises(UnsafeLogError, match="link"):
        read_log(log)
    (log / "log.yaml").unlink()
    cal = log / "watchtowers" / "wt01" / "calibration.yaml"
    cal.rename(tmp_path / "cal.yaml")
    cal.symlink_to(tmp_path / "cal.yaml")
    with pytest.raises(UnsafeLogError, match="link"):
        read_log(log)


# -- 1. frames ------------------------------------------------------------------------------------------------


def test_a_fifo_frame_is_refused_without_being_opened(tmp_path):
    log = make_log(tmp_path / "run", {"agent": "pid"})
    frame = log / "watchtowers" / "wt01" / "000001.jpg"
    frame.unlink()
    os.mkfifo(frame)  # opening it for reading would block until a writer came: never
    with pytest.raises(UnsafeLogError, match=r"000001\.jpg: not a regular file"):
        read_log(log)


def test_the_detector_reads_no_fifo_either(tmp_path):
    pytest.importorskip("cv2")
    from proxybench.autolab.localize import _decode
    from proxybench.autolab.logs import Frame

    fifo = tmp_path / "000000.jpg"
    os.mkfifo(fifo)
    with pytest.raises(UnsafeLogError, match="not a regular file"):
        _decode(Frame(0.0, str(fifo), str(fifo)))


def test_a_frame_that_is_a_link_is_refused(tmp_path):
    log = make_log(tmp_path / "run", {"agent": "pid"})
    secret = tmp_path / "secret.jpg"
    secret.write_bytes(b"secret")
    frame = log / "watchtowers" / "wt01" / "000002.jpg"
    frame.unlink()
    frame.symlink_to(secret)
    with pytest.raises(UnsafeLogError, match=r"000002\.jpg: a link"):
        read_log(log)


def test_a_watchtower_folder_that_is_a_link_is_refused(tmp_path):
    log = make_log(tmp_path / "run", {"agent": "pid"})
    (log / "watchtowers" / "wt02").symlink_to(log / "watchtowers" / "wt01")
    with pytest.raises(UnsafeLogError, match=r"wt02: a link"):
        read_log(log)


def test_repeated_and_too_many_frames_are_refused(tmp_path, monkeypatch):
    from proxybench.autolab import logs

    log = make_log(tmp_path / "run", {"agent": "pid"}, frames=3)
    stamps = log / "watchtowers" / "wt01" / "timestamps.csv"
    stamps.write_text("frame,t\n0,0.0\n1,0.1\n1,0.2\n2,0.3\n")
    with pytest.raises(UnsafeLogError, match=r"row 3 \(line 4\): frame 1 is listed twice"):
        read_log(log)
    stamps.write_text("frame,t\n0,0.0\n1,0.1\n2,0.2\n")
    monkeypatch.setattr(logs, "MAX_STREAM_FRAMES", 2)
    with pytest.raises(UnsafeLogError, match="more than 2 frames"):
        read_log(log)
    monkeypatch.setattr(logs, "MAX_STREAM_FRAMES", 10)
    monkeypatch.setattr(logs, "MAX_FRAME_BYTES", 4)
    with pytest.raises(UnsafeLogError, match=r"000000\.jpg: \d+ bytes; a frame is at most 4"):
        read_log(log)


# -- 1. writes stay under --out --------------------------------------------------------------------------------


def test_a_link_planted_in_out_is_not_followed(tmp_path, fake_localisation):
    log = make_log(tmp_path / "run", {"agent": "pid"})
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = tmp_path / "T"
    out.mkdir()
    (out / "episodes").symlink_to(elsewhere)
    with pytest.raises(UnsafeLogError, match="episodes"):
        target_mod.localize_logs(log, load_map("straight_road"), out)
    assert not any(elsewhere.iterdir())
    (out / "episodes").unlink()
    (out / "target.yaml").symlink_to(elsewhere / "target.yaml")
    target_mod.localize_logs(log, load_map("straight_road"), out)  # the link is replaced, never written through
    assert not (elsewhere / "target.yaml").exists() and not (out / "target.yaml").is_symlink()
    assert (out / "episodes" / "pid" / "0.csv").is_file() and (out / "localization" / "pid" / "0" / "ego.csv").is_file()


def test_write_file_under_refuses_names_that_leave_the_folder(tmp_path):
    from proxybench.untrusted import UntrustedInputError, write_file_under

    for rel in ("../x", "/abs", "a/../../x", "a/..", "a\x00/b", ""):
        with pytest.raises(UntrustedInputError):
            write_file_under(tmp_path / "out", rel, "no")
    assert write_file_under(tmp_path / "out", "a/b.csv", "yes").read_text() == "yes"
    assert _tree(tmp_path) == {"out", "out/a", "out/a/b.csv"}


# -- 1. a bounded fuzz of log.yaml ------------------------------------------------------------------------------

_SEED_MANIFEST = {"format": "proxybench-autolab-log/1", "source": "simulation", "map": "straight_road",
                  "agent": "pid", "episode": 0, "seconds": 0.3, "start": 0.0, "active": "ego",
                  "robots": {400: "ego", 401: "npc0"}, "ground_tags": [{"id": 7, "x": 0.8, "y": 1.1}]}
_NASTY = ["../up", "/abs/results.csv", "a/b", "a\x00b", "..", ".", "", "~", "-rf", " x", "x" * 300, "\u202e",
          "con", "a\\b", 1, -1, 1.5, True, None, [], {}, 10 ** 40, float("nan"), "*a", "&a", "[[[[", "{"]


def _mutate(rng: random.Random) -> str:
    """A mutated ``log.yaml``: values swapped for hostile ones, keys dropped or duplicated, text cut or repeated."""
    data = {k: (dict(v) if isinstance(v, dict) else list(v) if isinstance(v, list) else v)
            for k, v in _SEED_MANIFEST.items()}
    for _ in range(rng.randint(0, 3)):
        op = rng.randrange(6)
        key = rng.choice(list(_SEED_MANIFEST))
        if op == 0:
            data.pop(key, None)
        elif op == 1:
            data[key] = rng.choice(_NASTY)
        elif op == 2 and isinstance(data.get("robots"), dict):
            data["robots"][rng.choice([400, 401, 402, -1])] = rng.choice(_NASTY)
        elif op == 3:
            data[rng.choice(["extra", key + "x"])] = rng.choice(_NASTY)
        elif op == 4:
            data[key] = [data.get(key)] * rng.randint(1, 3)
        else:
            data[key] = {"nested": data.get(key)}
    try:
        text = yaml.safe_dump(data, allow_unicode=True)
    except yaml.YAMLError:
        text = str(data)
    op = rng.randrange(8)  # 5..7: the text as dumped
    if op == 0 and text:  # delete a slice
        a = rng.randrange(len(text))
        text = text[:a] + text[a + rng.randint(1, 20):]
    elif op == 1 and text:  # duplicate a slice
        a = rng.randrange(len(text))
        text = text[:a] + text[a:a + rng.randint(1, 40)] * rng.randint(2, 5) + text[a:]
    elif op == 2:
        text = "a: " + "[" * rng.randint(10, 3000) + "\n"
    elif op == 3:
        text = "x: &a [1, 2]\n" + "".join(f"y{k}: &a{k} [*a, *a]\n" for k in range(rng.randint(0, 4))) + text
    return text


def test_fuzz_log_yaml_loads_or_is_refused_and_nothing_leaves_out(tmp_path, fake_localisation):
    rng = random.Random(38)
    m = load_map("straight_road")
    log = make_log(tmp_path / "lab" / "run", None)
    outcomes = {"loaded": 0, "refused": 0}
    for k in range(500):
        (log / "log.yaml").write_text(_mutate(rng), encoding="utf-8", errors="surrogatepass")
        out = tmp_path / "outs" / str(k)
        try:
            read_log(log)
            target_mod.localize_logs(log, m, out)
            outcomes["loaded"] += 1
        except LayoutError as exc:
            assert str(exc) and "Traceback" not in str(exc)
            outcomes["refused"] += 1
    assert outcomes["loaded"] > 20 and outcomes["refused"] > 100, outcomes
    # every file written lies under its own --out: outside outs/ the tree is the log alone
    assert {p for p in _tree(tmp_path) if not p.startswith("outs")} == \
        {"lab", "lab/run", "lab/run/log.yaml", *(f"lab/run/{p}" for p in _tree(log) if p != "log.yaml")}
    for k in range(500):
        for p in _tree(tmp_path / "outs" / str(k)) if (tmp_path / "outs" / str(k)).exists() else ():
            assert not os.path.islink(tmp_path / "outs" / str(k) / p)


# -- 4. protocol numbers ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("value", [10 ** 20000, -(10 ** 20000), float("nan"), float("inf"), "fast", 2 ** 64],
                         ids=["20000-digits", "minus-20000-digits", "nan", "inf", "string", "2**64"])
def test_a_command_value_of_any_size_is_a_message_type_error_with_a_short_message(value):
    from proxybench.protocol.wire import MessageTypeError, parse_commands

    with pytest.raises(MessageTypeError) as err:
        parse_commands({"wheels": {"motor_left": value, "motor_right": 0.0}})
    msg = str(err.value)
    assert len(msg) < 160 and "\n" not in msg and "motor_left" in msg, msg


def test_a_20000_digit_command_in_a_cbor_message_is_a_recorded_agent_failure(tmp_path):
    """An agent node answering get_commands with a 20,000-digit integer: the caller records ``bad-commands``."""
    from proxybench.agents.base import Observation
    from proxybench.protocol import AgentFailure, AgentProcess

    agents = Path(__file__).resolve().parent / "protocol_agents"
    script = tmp_path / "bigint_agent.py"
    script.write_text(
        "import sys\n"
        f"sys.path.insert(0, {str(agents)!r})\n"
        "import misbehave as m\n"
        "def bigint(mode):\n"
        "    m.send(m.ctrl('understood'), m.commands(10 ** 20000, 0.0), m.ctrl('over'))\n"
        "    m.hang()\n"
        "m.misbehave = bigint\n"
        "m.main()\n")
    assert len(cbor2.dumps(10 ** 20000)) > 8000  # a CBOR bignum of ~8 kB
    proc = AgentProcess([sys.executable, str(script), "bigint", "get_commands"], init_timeout=5.0,
                        step_timeout=5.0)
    try:
        proc.seed(1)
        proc.episode_start("e")
        proc.observe(Observation(np.zeros((12, 16, 3), np.uint8), 0.0, (0.0, 0.0), 0.01))
        with pytest.raises(AgentFailure) as err:
            proc.get_commands(0.0)
    finally:
        proc.close()
    failure = err.value
    assert failure.reason == "bad-commands", failure
    assert "integer of about 20001 digits" in str(failure) and len(failure.detail) < 200, failure.detail


# -- 2. the DTPS server is a robot, not a shared folder ---------------------------------------------------------

CAMERA = "robot/map_0/vehicle_0/sensor/camera/front_center/jpeg/"
PWM = "robot/map_0/vehicle_0/actuator/wheels/base/pwm/"


def _request(port: int, method: str, path: str, body: bytes | None = None, headers: dict | None = None,
             timeout: float = 3.0) -> int:
    """The HTTP status of one request (0: no answer within ``timeout`` s or the connection closed; -1: not
    sent)."""
    import http.client

    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    try:
        conn.request(method, "/" + path, body=body, headers=headers or {})
        return conn.getresponse().status
    except (OSError, http.client.HTTPException):
        return 0
    except ValueError:  # a method or header http.client will not send
        return -1
    finally:
        conn.close()


class _Serve:
    """``dtps serve`` on a free port in a thread, a stand-in agent posting (0, 0) to the PWM topic over HTTP,
    the robot at hand (``robot``: its bridge), every wait bounded."""

    def __init__(self, tmp_path: Path, monkeypatch) -> None:
        import threading

        from proxybench.domain.params import DomainParams
        from proxybench.runner import dtps_serve
        from support.dtps import free_port

        self.port, self.out, self.robots = free_port(), tmp_path / "served", []
        real = dtps_serve.VirtualDB21J

        def robot(**kw):
            self.robots.append(real(**kw, lock=False))
            return self.robots[-1]

        monkeypatch.setattr(dtps_serve, "VirtualDB21J", robot)
        self.stop, self.ready = threading.Event(), threading.Event()
        self.error: BaseException | None = None
        self.files: list[Path] | None = None

        def run() -> None:
            try:
                self.files = dtps_serve.serve("loop_3x3", self.out, port=self.port, seconds=300.0, episode_seconds=2.0,
                                              params=DomainParams(image_width=32, image_height=24),
                                              on_ready=lambda url: self.ready.set(), stop=self.stop)
            except BaseException as exc:  # the test reads it
                self.error = exc
            finally:
                self.ready.set()

        def agent() -> None:
            body = cbor2.dumps({"header": {}, "left": 0.0, "right": 0.0})
            while not self.stop.is_set() and self.thread.is_alive():
                if self.ready.is_set():
                    _request(self.port, "POST", PWM, body, {"Content-Type": "application/cbor"})
                time.sleep(0.05)

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        assert self.ready.wait(120), "the serve did not start in 120 s"
        assert self.error is None, self.error
        threading.Thread(target=agent, daemon=True).start()
        deadline = time.monotonic() + 60
        while _request(self.port, "GET", CAMERA) != 200:  # 204 until the first frame is published
            assert time.monotonic() < deadline, "no camera frame in 60 s"
            time.sleep(0.1)

    @property
    def robot(self):
        return self.robots[0]

    def finish(self, timeout: float = 60.0) -> None:
        self.stop.set()
        self.thread.join(timeout)
        assert not self.thread.is_alive(), "the serve did not stop"


def _episodes(folder: Path) -> list[Path]:
    return sorted(folder.glob("episode-*.parquet"))


def _assert_no_empty_episodes(folder: Path) -> None:
    from proxybench.tasks.trajectory import Trajectory

    for f in _episodes(folder):
        assert len(Trajectory.load(f)) > 0, f


@sdk
def test_a_delete_on_the_camera_is_refused_and_the_serve_keeps_serving(tmp_path, monkeypatch):
    serve = _Serve(tmp_path, monkeypatch)
    try:
        assert _request(serve.port, "GET", CAMERA) == 200
        assert _request(serve.port, "DELETE", CAMERA) == 405
        assert _request(serve.port, "PATCH", "", b"[]", {"Content-Type": "application/json-patch+json"}) == 405
        assert _request(serve.port, "POST", CAMERA, b"fake frame", {"Content-Type": "application/cbor"}) == 403
        assert _request(serve.port, "GET", CAMERA) == 200 and serve.robot.alive
    finally:
        serve.finish()
    assert serve.error is None, serve.error
    _assert_no_empty_episodes(serve.out)


@sdk
def test_a_bridge_that_dies_ends_the_serve_with_one_line_and_no_empty_episodes(tmp_path, monkeypatch):
    import signal

    from proxybench.dtps.link import BridgeError

    serve = _Serve(tmp_path, monkeypatch)
    try:
        os.kill(serve.robot.link.pid, signal.SIGKILL)
        serve.thread.join(60)
        assert not serve.thread.is_alive(), "the serve went on without its bridge"
    finally:
        serve.finish()
    assert isinstance(serve.error, BridgeError), serve.error
    assert "bridge ended" in str(serve.error) and len(str(serve.error).splitlines()) == 1, serve.error
    assert len(_episodes(serve.out)) <= 1 and not (serve.out / "served.json").exists()
    _assert_no_empty_episodes(serve.out)


_METHODS = ["GET", "HEAD", "OPTIONS", "POST", "PUT", "PATCH", "DELETE", "TRACE", "CONNECT", "PROPFIND", "FOO",
            "get", "G\tET"]
_PATHS = ["", CAMERA, PWM, CAMERA + ":push/", PWM + ":push/", CAMERA + ":meta/", CAMERA + ":history/",
          CAMERA + ":events/", "robot/", "robot/map_0/vehicle_0/", "map/tiles/", "static/../../etc/passwd",
          "robot/map_0/vehicle_0/state/reset/", "x/:blobs/abc/" + "A" * 300, "%00", "a" * 5000, "robot/%2e%2e/",
          "robot/map_0/vehicle_0/new/queue/", "?x=" + "y" * 100]
_TYPES = ["application/cbor", "application/json", "application/json-patch+json", "application/yaml",
          "text/plain", "multipart/form-data; boundary=x", "\u00ff", ""]


def _hostile(rng: random.Random) -> tuple[str, str, bytes | None, dict]:
    method = rng.choice(_METHODS)
    path = rng.choice(_PATHS)
    if rng.random() < 0.3:
        path = path + "".join(rng.choice("abc/%:.-_~") for _ in range(rng.randint(1, 30)))
    body = None
    kind = rng.randrange(5)
    if kind == 1:
        body = rng.randbytes(rng.randint(0, 2000))
    elif kind == 2:
        body = cbor2.dumps(rng.choice([{"left": 10 ** 40, "right": "x"}, {"left": float("nan"), "right": 0.0}, [1] * 50,
                                       {"op": "remove", "path": "/robot"}, {"data": None}, 10 ** 30]))
    elif kind == 3:
        body = b'[{"op": "remove", "path": "/robot/map_0/vehicle_0/sensor"}]'
    elif kind == 4:
        body = b"{" * rng.randint(1, 3000)
    headers = {"Content-Type": rng.choice(_TYPES)}
    if rng.random() < 0.2:
        headers["X-" + "h" * rng.randint(1, 50)] = "v" * rng.randint(0, 500)
    if rng.random() < 0.1:
        headers["Upgrade"], headers["Connection"] = "websocket", "Upgrade"
    return method, path, body, headers


@sdk
def test_fuzz_hostile_requests_never_break_the_serve(tmp_path, monkeypatch):
    rng = random.Random(38)
    serve = _Serve(tmp_path, monkeypatch)
    try:
        statuses: dict[int, int] = {}
        for _ in range(500):
            method, path, body, headers = _hostile(rng)
            # the bridge never answers a CONNECT (the client gives up and closes it, which is what the serve must
            # survive); waiting 3 s for each of them was most of this test's time
            status = _request(serve.port, method, path, body, headers,
                              timeout=0.5 if method.upper() == "CONNECT" else 3.0)
            statuses[status] = statuses.get(status, 0) + 1
            if method.upper() in ("DELETE", "PATCH", "PUT"):
                assert status in (-1, 0, 400, 403, 405), (method, path, status)
        assert serve.robot.alive, serve.robot.link.stderr_tail()
        assert _request(serve.port, "GET", CAMERA) == 200  # still serving the camera
        tail = "\n".join(serve.robot.link.stderr_tail())
        assert "Traceback" not in tail, tail
    finally:
        serve.finish()
    assert serve.error is None, serve.error
    assert statuses.get(405, 0) > 50 and statuses.get(200, 0) > 20, statuses
    _assert_no_empty_episodes(serve.out)


def test_a_bare_huge_integer_instead_of_a_map_is_a_one_line_protocol_error() -> None:
    """An agent that sends a 20,000-digit integer where a map belongs gets NotAMapError naming its size, not the
    ValueError Python raises when asked to print it."""
    import cbor2

    from proxybench.protocol.cbor_stream import CborStream, NotAMapError

    stream = CborStream()
    stream.feed(cbor2.dumps(10**20000))
    with pytest.raises(NotAMapError, match="where a map was expected"):
        stream.next()
