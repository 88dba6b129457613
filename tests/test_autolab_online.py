"""Localisation online (issue 36 item 4): frames detected as they arrive, while the episode runs.

A simulated run whose watchtower frames are detected as they are written localises the robot as offline detection of
the same recording does (and of the recording cut short, as a stopped stream's drill leaves it); a lab whose
detection falls behind drops frames, counted and reported, and never makes the episode wait; the DTPS reader tells
each frame it writes, and only those.
"""

from __future__ import annotations

import csv
import dataclasses
import threading
from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")
pytest.importorskip("pupil_apriltags")
pytest.importorskip("gtsam")

from proxybench.autolab.localize import localize_log  # noqa: E402
from proxybench.autolab.logs import Frame, Log, LogManifest, Stream, read_log  # noqa: E402
from proxybench.autolab.online import Lag, OnlineDetector  # noqa: E402
from proxybench.autolab.watchtowers import LayoutError  # noqa: E402
from proxybench.domain.maps import load_map  # noqa: E402
from test_autolab import LANE_Y, SMALL, _layout  # noqa: E402
from test_localize_reuse import _image  # noqa: E402

#: guards against a hang only (a blocked worker would otherwise stall the suite); never a speed threshold
HANG = 120.0


def _record_observed(out: Path, online: OnlineDetector, seconds: float = 1.5) -> Path:
    """test_autolab's short PID run on straight_road, its watchtower frames told to ``online`` as written."""
    from proxybench.agents import make_agent
    from proxybench.autolab.calibration import stream_spec
    from proxybench.autolab.cli_support import finish_sim_log
    from proxybench.runner.jobs import DomainSpec
    from proxybench.runner.record import record_run

    layout = _layout()
    streams = dataclasses.replace(stream_spec(layout), observer=online)
    traj = record_run(DomainSpec("simulation", SMALL), make_agent("pid"), "straight_road", 0, seconds, out,
                      video=False, pose=(0.6, LANE_Y, 0.0), meta={"map": "straight_road"}, streams=streams).trajectory
    traj.save(out / "trajectory.parquet")
    finish_sim_log(out, layout, "straight_road", "pid", 0, seconds, traj.termination)
    return out


def _cut(stream: Path, keep: int) -> None:
    """A watchtower's recording ending after ``keep`` frames (what the streams_stop drill leaves)."""
    with open(stream / "timestamps.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    for r in rows[keep:]:
        (stream / f"{int(r['frame']):06d}.jpg").unlink()
    with open(stream / "timestamps.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "t"])
        w.writerows([(r["frame"], r["t"]) for r in rows[:keep]])


def test_online_detection_localises_the_robot_as_offline_detection_does(tmp_path: Path) -> None:
    online = OnlineDetector(decimate=2.0)
    run = _record_observed(tmp_path / "run", online)
    online.close()
    log, m = read_log(run), load_map("straight_road")
    ep = online.episode(run / "watchtowers")
    assert ep is not None
    frames = ep.frames_for(log)
    report = ep.report()
    total = sum(len(s.frames) for s in log.streams)
    assert report["frames"] == report["localised"] == len(frames) == total and report["dropped"] == {}
    live = localize_log(log, m, frames=frames)
    offline = localize_log(log, m, workers=1, decimate=2.0)
    a, b = live.robots["ego"], offline.robots["ego"]
    assert a.t.size >= 5 and np.array_equal(a.t, b.t) and np.array_equal(a.views, b.views)
    assert np.abs(a.pose - b.pose).max() < 1e-6  # the same detections, the same graph: the same trajectory
    assert (live.detections, live.detected) == (offline.detections, offline.detected) == (
        offline.detections, report["detected"])

    # a stream that stopped mid-episode: the frames after its end are not localised, as offline
    stream = run / "watchtowers" / log.streams[0].name
    _cut(stream, keep=3)
    cut = read_log(run)
    live, offline = localize_log(cut, m, frames=ep.frames_for(cut)), localize_log(cut, m, workers=1, decimate=2.0)
    assert live.frames == offline.frames == total - len(log.streams[0].frames) + 3
    assert np.abs(live.robots["ego"].pose - offline.robots["ego"].pose).max() < 1e-6


class _Gate:
    """A detector that holds its first frame until the test opens the gate (a lab whose CPU is taken)."""

    def __init__(self) -> None:
        self.entered, self.opened = threading.Event(), threading.Event()

    def detect(self, gray: np.ndarray) -> list:
        self.entered.set()
        assert self.opened.wait(HANG)
        return []


def _frames(folder: Path, n: int) -> list[Frame]:
    (folder / "wt01").mkdir(parents=True)
    out = []
    for k in range(n):
        path = folder / "wt01" / f"{k:06d}.jpg"
        path.write_bytes(_image([(3, 30, 30)], seed=k, light=40.0 * k))  # each a changed view: each detected
        out.append(Frame(0.2 * k, str(path), str(path)))
    return out


def _log(frames: list[Frame]) -> Log:
    return Log(Path("."), LogManifest(source="simulation", map="straight_road", seconds=2.0),
               [Stream("wt01", None, frames, "synthetic")])  # type: ignore[arg-type]


def test_a_lab_that_falls_behind_drops_frames_counted_and_never_waits(tmp_path: Path) -> None:
    gate, told = _Gate(), []
    online = OnlineDetector(gate, max_queue=2, report=told.append, every=0.0)
    ep = online.begin(tmp_path / "ep")
    frames = _frames(tmp_path / "ep", 6)
    ep.frame("wt01", 0, frames[0].ref, frames[0].t)
    assert gate.entered.wait(HANG)  # the worker holds frame 0
    for k in range(1, 6):  # returns at once though nothing is detected: 1 and 2 queue, 3, 4, 5 are dropped
        ep.frame("wt01", k, frames[k].ref, frames[k].t)
    assert online.lag() == Lag(queued=2, behind_s=1.0, detected=0, dropped=3)
    assert ep.report()["dropped"] == {"wt01": 3} and ep.report()["max_queued"] == 2
    gate.opened.set()
    ep.end()
    online.close()
    kept = ep.frames_for(_log(frames))  # waits for the queue: frames 0, 1, 2
    assert [f.t for f in kept] == [frames[0].t, frames[1].t, frames[2].t]
    report = ep.report()
    assert (report["frames"], report["localised"], report["detected"]) == (6, 3, 3)
    assert told and all(isinstance(lag, Lag) for lag in told)  # the evaluator's live view of the lag


def test_a_frame_that_fails_online_raises_its_error_as_offline_detection_would(tmp_path: Path) -> None:
    (tmp_path / "wt01").mkdir()
    path = tmp_path / "wt01" / "000000.jpg"
    path.write_bytes(_image([(3, 30, 30), (3, 200, 120)], seed=0))  # one tag id printed twice
    online = OnlineDetector(decimate=2.0)
    ep = online.begin(tmp_path)
    ep.frame("wt01", 0, str(path), 0.0)
    online.close()
    with pytest.raises(LayoutError, match="tag id 3 seen twice in one frame"):
        ep.frames_for(_log([Frame(0.0, str(path), str(path))]))


def test_the_dtps_reader_tells_each_frame_it_writes_and_only_those(tmp_path: Path) -> None:
    from proxybench.dtps.cameras import CameraSource, EpisodeWriter

    told: list[tuple[str, int, bytes, float]] = []
    src = CameraSource(name="wt01", url="http://x:1/", path="wt01/sensor/camera/front_center/jpeg")
    w = EpisodeWriter([src], tmp_path / "ep", origin=100.0, on_frame=lambda *a: told.append(a))
    good = _image([(3, 30, 30)], seed=0)
    w.frame({"ev": "frame", "name": "wt01", "data": good, "format": "jpeg", "stamp": 100.0})
    w.frame({"ev": "frame", "name": "wt01", "data": good[:-10], "format": "jpeg", "stamp": 100.2})  # cut short
    w.frame({"ev": "frame", "name": "wt01", "data": good, "format": "jpeg", "stamp": 100.4})
    assert [(n, k, t) for n, k, _, t in told] == [("wt01", 0, pytest.approx(0.0)), ("wt01", 1, pytest.approx(0.4))]
    assert told[1][2] == (tmp_path / "ep" / "wt01" / "000001.jpg").read_bytes()
