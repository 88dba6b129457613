"""Issue 38, the fuzz of ``localize`` inputs beyond ``log.yaml`` (tests/test_trust_round3.py has 500 mutated logs):
300 mutated watchtower calibrations and 200 mutated ROS bags (bytes flipped, cut or repeated; topic names that
are paths). Each either reads or is refused with a ``LayoutError`` naming the file in each line; nothing else is raised,
nothing hangs, nothing is written outside ``--out``. Seeded, small; a larger run: ``PROXYBENCH_FUZZ_SCALE=20``.
"""

from __future__ import annotations

import os
import random
from pathlib import Path

import numpy as np
import pytest
import yaml

from proxybench.autolab import target as target_mod
from proxybench.autolab.localize import Localization, RobotTrack
from proxybench.autolab.logs import read_log
from proxybench.autolab.validate import Verdict
from proxybench.autolab.watchtowers import LayoutError
from proxybench.domain.maps import load_map
from test_trust_round3 import _NASTY, _tree, make_log

_YAML_NOISE = "{}[]:&*!- \n\t\"'"
_NASTY_NUMBERS = [*_NASTY, [1e308] * 9, [float("inf")] * 9, [0.0] * 9, [1] * 10**4, -5, 0]
SCALE = max(1, int(os.environ.get("PROXYBENCH_FUZZ_SCALE", "1")))


@pytest.fixture
def fake_localisation(monkeypatch):
    """``localize_logs`` without detection (the frames are not images): every robot of the log seen twice."""

    def localize_log(log, m, *, robots=None, **_):
        names = set((robots or log.manifest.robots or {400: "ego"}).values()) | {log.manifest.active}
        tracks = {n: RobotTrack(n, np.array([0.0, 0.1]), np.zeros((2, 3)), np.full((2, 3), 0.01),
                                np.ones(2, dtype=np.int64)) for n in names}
        return Localization(tracks, {}, {}, 2, 2)

    monkeypatch.setattr(target_mod, "localize_log", localize_log)
    monkeypatch.setattr(target_mod, "validate_run", lambda log, loc, limits=None: Verdict(True))


def _names_the_file(exc: BaseException, folder: Path, most: int = 20) -> None:
    """A refusal as the project writes them: one line per problem (``most`` at most), each naming the file at fault
    (a bag's is one line: rosbags' own messages quote the bag's bytes, newlines and all)."""
    lines = str(exc).splitlines()
    assert lines and len(lines) <= most and "Traceback" not in str(exc), str(exc)
    assert all(str(folder) in line for line in lines), str(exc)


def _cut_or_repeat(rng: random.Random, data: bytes | str):
    """A slice of ``data`` deleted, repeated or overwritten with noise (or ``data`` as it is)."""
    if not data:
        return data
    a = rng.randrange(len(data))
    op = rng.randrange(4)
    if op == 0:
        return data[:a] + data[a + rng.randint(1, 64):]
    if op == 1:
        return data[:a] + data[a:a + rng.randint(1, 64)] * rng.randint(2, 6) + data[a:]
    if op == 2:
        n = rng.randint(1, 16)
        noise = rng.randbytes(n) if isinstance(data, bytes) else "".join(rng.choice(_YAML_NOISE) for _ in range(n))
        return data[:a] + noise + data[a + n:]
    return data


def _mutate_calibration(rng: random.Random, seed: dict) -> str:
    """A calibration with fields dropped, swapped for hostile values or nested, then its text cut or repeated."""
    data = yaml.safe_load(yaml.safe_dump(seed))
    for _ in range(rng.randint(0, 3)):
        key = rng.choice(list(seed))
        inner = data.get(key)
        op = rng.randrange(5)
        if op == 0:
            data.pop(key, None)
        elif op == 1:
            data[key] = rng.choice(_NASTY)
        elif op == 2 and isinstance(inner, dict) and inner:
            inner[rng.choice(list(inner))] = rng.choice(_NASTY_NUMBERS)
        elif op == 3:
            data[key] = {"nested": inner}
        else:
            data[key] = [inner] * rng.randint(2, 4)
    try:
        text = yaml.safe_dump(data, allow_unicode=True)
    except yaml.YAMLError:
        text = str(data)
    if rng.random() < 0.1:
        text = "a: " + "[" * rng.randint(10, 3000) + "\n"
    elif rng.random() < 0.1:
        text = "x: &a [1, 2]\n" + "".join(f"y{k}: &a{k} [*a, *a]\n" for k in range(rng.randint(1, 6))) + text
    return _cut_or_repeat(rng, text)


def test_fuzz_calibrations_read_or_are_refused_and_nothing_leaves_out(tmp_path, fake_localisation):
    rng = random.Random(3800)
    m = load_map("straight_road")
    log = make_log(tmp_path / "lab" / "run", {"format": "proxybench-autolab-log/1", "source": "simulation",
                                               "map": "straight_road", "agent": "pid", "episode": 0, "seconds": 0.3,
                                               "start": 0.0, "active": "ego", "robots": {400: "ego"}})
    cal = log / "watchtowers" / "wt01" / "calibration.yaml"
    seed = yaml.safe_load(cal.read_text())
    outcomes = {"read": 0, "refused": 0}
    for k in range(300 * SCALE):
        cal.write_text(_mutate_calibration(rng, seed), encoding="utf-8", errors="surrogatepass")
        try:
            read_log(log)
            target_mod.localize_logs(log, m, tmp_path / "outs" / str(k))
            outcomes["read"] += 1
        except LayoutError as exc:
            _names_the_file(exc, log)
            outcomes["refused"] += 1
    assert outcomes["read"] > 10 and outcomes["refused"] > 100, outcomes
    assert {p for p in _tree(tmp_path) if not p.startswith("outs")} == \
        {"lab", "lab/run", *(f"lab/run/{p}" for p in _tree(log))}


# -- ROS bags ----------------------------------------------------------------------------------------------


def _bag(path: Path, tower: str = "wt01", robot: str = "autobot01") -> Path:
    """A small ROS 1 bag: three camera frames of ``tower`` and four wheel commands of ``robot``."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from proxybench.autolab.logs import WHEELS_CMD_MSG

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg(WHEELS_CMD_MSG, "duckietown_msgs/msg/WheelsCmdStamped"))
    image, header = store.types["sensor_msgs/msg/CompressedImage"], store.types["std_msgs/msg/Header"]
    time_, wheels = store.types["builtin_interfaces/msg/Time"], store.types["duckietown_msgs/msg/WheelsCmdStamped"]

    def stamp(t: float):
        return header(seq=0, stamp=time_(sec=int(1000 + t), nanosec=int(t % 1 * 1e9)), frame_id="")

    with Writer(path) as w:
        cam = w.add_connection(f"/{tower}/camera_node/image/compressed", image.__msgtype__, typestore=store)
        cmd = w.add_connection(f"/{robot}/wheels_driver_node/wheels_cmd", wheels.__msgtype__, typestore=store)
        for k in range(4):
            t = 0.1 * k
            if k < 3:
                msg = image(header=stamp(t), format="jpeg", data=np.frombuffer(b"\xff\xd8 frame %d" % k, np.uint8))
                w.write(cam, int((1000 + t) * 1e9), store.serialize_ros1(msg, cam.msgtype))
            msg = wheels(header=stamp(t), vel_left=0.3, vel_right=0.4)
            w.write(cmd, int((1000 + t) * 1e9) + 1, store.serialize_ros1(msg, cmd.msgtype))
    return path


@pytest.mark.parametrize("tower", ["..", "a\\..", "~root", "x" * 200])
def test_a_bag_whose_topic_is_a_path_is_refused(tmp_path, tower):
    bag = _bag(tmp_path / "run.bag", tower=tower)
    with pytest.raises(LayoutError) as exc:
        read_log(bag, tmp_path / "calibrations")
    _names_the_file(exc.value, tmp_path, most=1)


def test_fuzz_bags_read_or_are_refused(tmp_path):
    rng = random.Random(3801)
    seed = _bag(tmp_path / "seed.bag").read_bytes()
    cals = tmp_path / "calibrations"
    cals.mkdir()
    (cals / "wt01.yaml").write_text((make_log(tmp_path / "cal-src") / "watchtowers" / "wt01" /
                                     "calibration.yaml").read_text())
    before = _tree(tmp_path)
    outcomes = {"read": 0, "refused": 0}
    for _ in range(200 * SCALE):
        data = seed
        for _ in range(rng.randint(1, 3)):
            data = _cut_or_repeat(rng, data)
        (tmp_path / "fuzz.bag").write_bytes(data)
        try:
            log = read_log(tmp_path / "fuzz.bag", cals, overrides={"agent": "lf", "active": "autobot01",
                                                                      "start": 1000.0, "seconds": 0.3})
            assert all(len(s.frames) <= 3 for s in log.streams)
            outcomes["read"] += 1
        except LayoutError as exc:
            _names_the_file(exc, tmp_path, most=1)
            outcomes["refused"] += 1
    assert outcomes["read"] > 10 and outcomes["refused"] > 50, outcomes
    assert _tree(tmp_path) == before | {"fuzz.bag"}  # nothing written beside the bag
