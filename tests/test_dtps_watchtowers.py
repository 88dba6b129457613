"""Watchtowers as a lab has them (issue 36 item 4): simulated watchtowers served as DTPS camera topics with
duckietown-messages, a reader of any lab's camera topics writing the folders localisation reads, and the Autolab
evaluator's episodes recorded through it.

The reader's checks run on events made by hand (no SDK needed); the rest needs the SDK environment (``sdk``).
"""

from __future__ import annotations

import csv
import json
import logging
import subprocess
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from proxybench.dtps.cameras import CameraSource, EpisodeWriter, camera_source, image_size
from support.dtps import sdk


def _jpeg(w: int = 64, h: int = 48) -> bytes:
    img = np.zeros((h, w, 3), np.uint8)
    img[::4] = 200
    return cv2.imencode(".jpg", img)[1].tobytes()


def _png(w: int = 64, h: int = 48) -> bytes:
    return cv2.imencode(".png", np.zeros((h, w, 3), np.uint8))[1].tobytes()


SOURCES = [CameraSource(name="wt01", url="http://x:1/", path="wt01/sensor/camera/front_center/jpeg", width=64,
                        height=48),
           CameraSource(name="wt02", url="http://x:1/", path="wt02/sensor/camera/front_center/jpeg")]


def test_image_size_reads_jpeg_and_png_headers_and_refuses_what_is_not_one() -> None:
    assert image_size(_jpeg(64, 48), "jpeg") == (64, 48)
    assert image_size(_png(30, 20), "png") == (30, 20)
    for data, words in [(b"", "not a JPEG"), (b"GIF89a" + bytes(40), "not a JPEG"),
                        (_jpeg()[:-40], "cut short"), (b"\xff\xd8\xff\xd9", "without a frame header"),
                        (b"\xff\xd8\x00\x00\xff\xd9", "broken JPEG")]:
        with pytest.raises(ValueError, match=words):
            image_size(data, "jpeg")
    with pytest.raises(ValueError, match="not a PNG"):
        image_size(_jpeg(), "png")


def test_a_watchtower_address_names_its_camera_topic() -> None:
    s = camera_source("wt01", "wt01.local/wt01", 640, 480)
    assert (s.url, s.path) == ("http://wt01.local:11911/", "wt01/sensor/camera/front_center/jpeg")
    assert camera_source("a", "127.0.0.1:7510/a").url == "http://127.0.0.1:7510/"
    with pytest.raises(ValueError, match="not a DTPS robot address"):
        camera_source("a", "no-path-here")


def test_the_writer_records_good_frames_and_names_each_streams_first_bad_one(tmp_path: Path, caplog) -> None:
    w = EpisodeWriter(SOURCES, tmp_path / "ep", origin=100.0, max_frame_bytes=50_000, max_frames=3)
    good = _jpeg()
    with caplog.at_level(logging.WARNING, "proxybench.dtps.cameras"):
        w.frame({"ev": "frame", "name": "wt01", "data": good, "format": "jpeg", "stamp": 100.0, "wall": 5.0})
        w.frame({"ev": "frame", "name": "wt01", "data": _jpeg(32, 24), "format": "jpeg", "stamp": 100.1})  # size
        w.frame({"ev": "frame", "name": "wt01", "data": good, "format": "jpeg", "stamp": 99.9})  # backwards
        w.frame({"ev": "frame", "name": "wt01", "data": good[:-10], "format": "jpeg", "stamp": 100.2})  # cut
        w.frame({"ev": "frame", "name": "wt01", "data": "text", "format": "jpeg", "stamp": 100.3})  # not bytes
        w.frame({"ev": "frame", "name": "wt01", "data": good, "format": "jpeg", "stamp": None})  # stamp missing
        w.frame({"ev": "frame", "name": "wt01", "data": bytes(60_000), "format": "jpeg", "stamp": 100.4})  # large
        w.frame({"ev": "frame", "name": "wt01", "data": good, "format": "jpeg", "stamp": 100.5, "wall": 6.0})
        w.bad({"ev": "bad", "name": "wt02", "detail": "TypeError: data is str, not image bytes"})
        for k in range(5):  # wt02 stamps nothing: its frames are stamped on arrival; only 3 are kept
            w.frame({"ev": "frame", "name": "wt02", "data": _png(), "format": "png", "stamp": None,
                     "wall": 101.0 + k})
        w.frame({"ev": "frame", "name": "wt09", "data": good, "format": "jpeg", "stamp": 100.0})  # not ours
    out = w.finish({"wt01": 9, "wt02": 6})
    assert out.frames == {"wt01": 2, "wt02": 3}
    assert out.bad == {"wt01": 6, "wt02": 1} and out.dropped == {"wt02": 2} and out.missing == {"wt01": 1}
    assert out.problems["wt01"] == "a 32×24 frame; the calibration is for 64×48"
    assert out.problems["wt02"] == "TypeError: data is str, not image bytes"
    logged = [r.getMessage() for r in caplog.records]
    assert sum("wt01: a bad message" in m for m in logged) == 1  # one line per stream, not per message
    assert all("\n" not in m for m in logged)
    with open(tmp_path / "ep" / "wt01" / "timestamps.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["frame"], r["t"], r["received"]) for r in rows] == [("0", "0.000000", "5.000000"),
                                                                   ("1", "0.500000", "6.000000")]
    assert (tmp_path / "ep" / "wt01" / "000001.jpg").read_bytes() == good
    assert sorted(p.name for p in (tmp_path / "ep" / "wt02").iterdir()) == [
        "000000.png", "000001.png", "000002.png", "timestamps.csv"]
    with open(tmp_path / "ep" / "wt02" / "timestamps.csv") as fh:
        assert [r["t"] for r in csv.DictReader(fh)] == ["1.000000", "2.000000", "3.000000"]


def test_a_watchtower_that_sent_nothing_gets_no_folder(tmp_path: Path) -> None:
    w = EpisodeWriter(SOURCES, tmp_path / "ep", origin=0.0)
    w.frame({"ev": "frame", "name": "wt01", "data": _jpeg(), "format": "jpeg", "stamp": 1.0})
    assert w.finish().frames == {"wt01": 1, "wt02": 0}
    assert sorted(p.name for p in (tmp_path / "ep").iterdir()) == ["wt01"]



def test_a_stream_spec_with_a_sink_needs_no_camera_and_keys_its_jobs_apart(tmp_path: Path) -> None:
    """The runner's side: a recorder whose spec has a sink opens and closes the sink's episode, writes nothing."""
    from proxybench.domain.fixed_cameras import FixedCamera
    from proxybench.runner.streams import StreamRecorder, StreamSpec

    calls: list[tuple] = []

    class Sink:
        kind = "dtps"

        def begin(self, out: Path) -> None:
            calls.append(("begin", out))

        def frame(self, *args) -> None:
            calls.append(("frame", *args))

        def end(self) -> None:
            calls.append(("end",))

    with pytest.raises(ValueError, match="and a camera"):
        StreamSpec((), (), ())
    cam = FixedCamera("wt01", 0.5, 0.5, 0.8, 0.0, 89.0, 64, 48)
    assert "sink" not in StreamSpec((cam,), (5.0,), (0.0,)).key_data()
    assert StreamSpec((cam,), (5.0,), (0.0,), sink=Sink()).key_data()["sink"] == "dtps"
    rec = StreamRecorder(None, StreamSpec((), (), (), sink=Sink()), tmp_path / "ep")
    assert rec.frame(0.2) == 0
    rec.close()
    assert calls == [("begin", tmp_path / "ep"), ("end",)] and not (tmp_path / "ep").exists()

LAB = """\
format: proxybench-lab/1
name: dtps-lab
map: loop_3x3
robots:
  - {name: db1, virtual: true}
watchtowers: {layout: auto, serve: dtps}
reset: {mode: teleport}
"""


def test_lab_yaml_serves_only_simulated_watchtowers_and_checks_stream_addresses(tmp_path: Path) -> None:
    from proxybench.autolab.lab import LabError, load_lab

    (tmp_path / "lab.yaml").write_text(LAB)
    assert load_lab(tmp_path / "lab.yaml").watchtowers.serve == "dtps"
    for text, words in [
        (LAB.replace("{layout: auto, serve: dtps}", "{serve: dtps, streams: [{name: a, dtps: h/a, calibration: "
                                                    "c.yaml}]}"), "only simulated watchtowers"),
        (LAB.replace("{layout: auto, serve: dtps}", "{streams: [{name: a, dtps: 'h:99999/a', calibration: c.yaml}]}"),
         "port 99999"),
        (LAB.replace("serve: dtps", "serve: http"), "serve")]:
        (tmp_path / "lab.yaml").write_text(text)
        with pytest.raises(LabError, match=words):
            load_lab(tmp_path / "lab.yaml")


@sdk
def test_served_watchtowers_publish_the_sdks_camera_messages_and_refuse_writes(tmp_path: Path) -> None:
    """What a DTPS client sees of a simulated watchtower: CompressedImage on jpeg, CameraIntrinsicCalibration on
    parameters and Camera on info, decoded with duckietown-messages' own classes; every write refused."""
    from proxybench.dtps.cameras import WatchtowerServer
    from proxybench.dtps.env import sdk_python

    server = WatchtowerServer(["wt01"])
    try:
        server.info("wt01", width=64, height=48, fov=1.2, frequency=5.0, K=[50, 0, 31.5, 0, 50, 23.5, 0, 0, 1],
                    D=[0.0] * 5, distortion_model="plumb_bob")
        server.publish("wt01", _jpeg(), 1234.5, 0.5)
        probe = f"""
import asyncio, json
from dtps import context
from dtps_http import RawData
from duckietown_messages.sensors.compressed_image import CompressedImage
from duckietown_messages.calibrations.camera_intrinsic import CameraIntrinsicCalibration
from duckietown_messages.sensors.camera import Camera
async def main():
    ctx = await context("probe", urls=["{server.url}"])
    base = ctx.navigate("wt01", "sensor", "camera", "front_center")
    img = CompressedImage.from_rawdata(await base.navigate("jpeg").data_get())
    par = CameraIntrinsicCalibration.from_rawdata(await base.navigate("parameters").data_get())
    info = Camera.from_rawdata(await base.navigate("info").data_get())
    refused = None
    try:
        await base.navigate("jpeg").publish(RawData.cbor_from_native_object({{"format": "jpeg", "data": b"x"}}))
    except Exception as exc:
        refused = type(exc).__name__
    print(json.dumps({{"shape": list(img.as_array().shape), "stamp": img.header.timestamp, "K": par.K,
                      "P": par.P, "w": info.width, "sim": info.simulated, "refused": refused}}))
    await ctx.aclose()
asyncio.run(main())
"""
        run = subprocess.run([str(sdk_python()), "-I", "-c", probe], capture_output=True, text=True, timeout=120)
        assert run.returncode == 0, run.stderr[-2000:]
        seen = json.loads(run.stdout.strip().splitlines()[-1])
        assert seen["shape"] == [48, 64, 3] and seen["stamp"] == 1234.5
        assert seen["K"][0] == 50 and len(seen["P"]) == 12 and seen["w"] == 64 and seen["sim"] is True
        assert seen["refused"] is not None  # a camera takes no writes
    finally:
        server.close()


@sdk
def test_the_reader_records_served_frames_and_names_a_watchtower_it_cannot_reach(tmp_path: Path) -> None:
    from proxybench.dtps.cameras import ReaderError, WatchtowerReader, WatchtowerServer, free_port

    server = WatchtowerServer(["wt01", "wt02"])
    try:
        reader = WatchtowerReader([camera_source(n, server.address(n), 64, 48) for n in ("wt01", "wt02")])
        try:
            server.publish("wt01", _jpeg(), 10.0, 0.0)  # between episodes: not recorded
            time.sleep(0.3)
            reader.begin(tmp_path / "ep", origin=1000.0)
            for k in range(20):
                server.publish("wt01", _jpeg(), 1000.0 + 0.2 * k, 0.2 * k)
                server.publish("wt02", _jpeg(32, 24) if k == 5 else _jpeg(), 1000.1 + 0.2 * k, 0.2 * k)
            got = reader.end({"wt01": 20, "wt02": 20}, timeout=20.0)
            server.take_counts()
        finally:
            reader.close()
    finally:
        server.close()
    assert got.frames == {"wt01": 20, "wt02": 19} and got.missing == {}
    assert got.problems == {"wt02": "a 32×24 frame; the calibration is for 64×48"}
    with open(tmp_path / "ep" / "wt02" / "timestamps.csv") as fh:
        assert float(next(csv.DictReader(fh))["t"]) == pytest.approx(0.1, abs=1e-5)
    with pytest.raises(ReaderError, match=r"watchtower wt09: cannot subscribe to http://127\.0\.0\.1:"):
        WatchtowerReader([camera_source("wt09", f"127.0.0.1:{free_port()}/wt09")], timeout=3.0)


BENCH = """\
name: dtps_towers
description: one short episode in a lab whose watchtowers are served over DTPS
map: loop_3x3
episodes: {count: 1, seed: 3}
duration: 3.0
physics_rate: 30.0
frame_rate: 5.0
metrics: [survival_time, driven_lanedir_consec]
scoring:
  - {metric: survival_time_median}
"""


@sdk
def test_a_virtual_lab_served_over_dtps_is_read_back_and_localised_within_two_centimetres(tmp_path: Path) -> None:
    """Item 4's test: the lab's simulated watchtowers served as DTPS camera topics, every frame read back by the
    reader into the episode's streams, localised by the evaluator's own per-episode path against the truth."""
    from proxybench.autolab.lab import load_lab
    from proxybench.autolab.live import live_streams
    from proxybench.domain.maps import load_map
    from proxybench.evaluator.autolab import localize_episode
    from proxybench.runner.backends import InlineBackend
    from proxybench.runner.evaluate import evaluate_benchmark
    from proxybench.runner.jobs import AgentSpec
    from proxybench.tasks.benchmark import Benchmark
    from proxybench.tasks.metrics import METRICS

    (tmp_path / "lab.yaml").write_text(LAB)
    lab = load_lab(tmp_path / "lab.yaml")
    bench = Benchmark.from_dict(yaml.safe_load(BENCH), origin="dtps_towers")
    m = load_map(bench.map)
    layout = lab.layout(m)
    with live_streams(lab, layout) as live:
        ev = evaluate_benchmark(bench, [AgentSpec("pid")], tmp_path / "runs", InlineBackend(), streams=live.spec)
        read = live.sink.episodes
    (res,) = ev.sweep.results
    assert len(read) == 1 and read[0].missing == {} and read[0].bad == {}
    assert sum(read[0].frames.values()) >= 12 * 3 * 5 * 0.9  # 12 watchtowers at 5 Hz for 3 s
    stamps = Path(res.streams) / "wt01" / "timestamps.csv"
    with open(stamps) as fh:
        assert {"frame", "t", "stamp", "received"} <= set(next(csv.DictReader(fh)))
    episode = localize_episode(res, bench, lab, layout, m, tmp_path / "autolab", METRICS)
    assert episode.valid, episode.reasons
    assert episode.error_median_m is not None and episode.error_median_m <= 0.02

    # the same frames as a lab's own streams: its calibration files and ground tags in lab.yaml, no layout
    from proxybench.autolab.calibration import draw_calibrations, write_calibration

    cals, _ = draw_calibrations(layout)
    (tmp_path / "cal").mkdir()
    streams = [{"name": n, "dtps": f"wt.local/{n}", "calibration": str(write_calibration(tmp_path / "cal" / n, c))}
               for n, c in cals.items()]
    own = {**yaml.safe_load(LAB), "watchtowers": {"streams": streams, "ground_tags": [
        g.model_dump() for g in layout.ground_tags]}}
    (tmp_path / "own.yaml").write_text(yaml.safe_dump(own))
    mine = localize_episode(res, bench, load_lab(tmp_path / "own.yaml"), None, m, tmp_path / "own", METRICS)
    assert mine.valid and mine.error_median_m <= 0.02
    assert (tmp_path / "own" / "watchtowers" / "wt01" / "calibration.yaml").read_text() == (
        tmp_path / "cal" / "wt01").read_text()


@sdk
def test_a_labs_own_dtps_streams_are_recorded_per_episode_on_the_wall_clock(tmp_path: Path) -> None:
    """A lab's own watchtowers (here served by the test, stamping with the wall clock as a camera does): the sink
    opens an episode at its recorder's start, times are seconds since then, frames outside it are not kept."""
    from proxybench.autolab.calibration import Calibration, write_calibration
    from proxybench.autolab.lab import load_lab
    from proxybench.autolab.live import live_streams
    from proxybench.dtps.cameras import WatchtowerServer

    server = WatchtowerServer(["cam1"])
    try:
        cal = Calibration(name="cam1", image_width=64, image_height=48,
                          camera_matrix={"rows": 3, "cols": 3, "data": [50, 0, 31.5, 0, 50, 23.5, 0, 0, 1]},
                          extrinsics={"position": [0.5, 0.5, 0.8], "yaw": 90, "pitch": 89})
        write_calibration(tmp_path / "cam1.yaml", cal)
        (tmp_path / "lab.yaml").write_text(LAB.replace(
            "{layout: auto, serve: dtps}", f"{{streams: [{{name: cam1, dtps: '{server.address('cam1')}', "
                                           "calibration: cam1.yaml}], ground_tags: [{id: 1, x: 0.3, y: 0.3}]}"))
        with live_streams(load_lab(tmp_path / "lab.yaml"), None) as live:
            assert live.spec.cameras == () and len(live.spec.fixtures) == 1  # nothing simulated; the floor tag
            server.publish("cam1", _jpeg(), time.time(), 0.0)  # before the episode
            time.sleep(0.3)
            live.sink.begin(tmp_path / "ep")
            for _ in range(5):
                server.publish("cam1", _jpeg(), time.time(), 0.0)
                time.sleep(0.1)
            live.sink.end()
            (read,) = live.sink.episodes
    finally:
        server.close()
    assert read.frames == {"cam1": 5}
    with open(tmp_path / "ep" / "cam1" / "timestamps.csv") as fh:
        times = [float(r["t"]) for r in csv.DictReader(fh)]
    assert 0.0 <= times[0] < 0.3 and times == sorted(times)
    assert json.loads((tmp_path / "ep" / "reader.json").read_text())["frames"] == {"cam1": 5}


@sdk
def test_hostile_camera_messages_over_dtps_are_counted_with_one_line_and_never_written(tmp_path: Path) -> None:
    """A watchtower whose messages are a stranger's worst: text for bytes, a NaN clock, a message over the bound,
    bytes that are no image; each is refused by the reader with one line, the good frames around them kept."""
    from proxybench.dtps.cameras import WatchtowerReader, WatchtowerServer

    server = WatchtowerServer(["wt01"])
    try:
        reader = WatchtowerReader([camera_source("wt01", server.address("wt01"), 64, 48)], max_frame_bytes=100_000)
        try:
            reader.begin(tmp_path / "ep", origin=0.0)
            server.publish("wt01", _jpeg(), 1.0, 1.0)
            for jpeg, stamp in [("text", 2.0), (_jpeg(), float("nan")), (bytes(200_000), 3.0),
                                (b"\x00" * 100, 4.0)]:
                server.link.send(op="frame", name="wt01", jpeg=jpeg, stamp=stamp, t=0.0, seq=0)
            server.publish("wt01", _jpeg(), 5.0, 5.0)
            got = reader.end({"wt01": 6}, timeout=20.0)
            server.take_counts()
        finally:
            reader.close()
        assert server.alive
    finally:
        server.close()
    assert got.frames == {"wt01": 2} and got.bad == {"wt01": 4} and got.missing == {}
    assert got.problems["wt01"] == "TypeError: data is str, not image bytes"
    with open(tmp_path / "ep" / "wt01" / "timestamps.csv") as fh:
        assert [r["t"] for r in csv.DictReader(fh)] == ["1.000000", "5.000000"]
