"""The Autolab's eyes: tags drawn as tags, watchtower streams, localisation into a target, the DTA's validation.

One short simulated run (straight road, two 320×240 watchtowers, 1.5 s) is recorded once per module and
reused; the bad-input tests edit copies of its log.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")
pytest.importorskip("pupil_apriltags")
pytest.importorskip("gtsam")

from proxybench.agents import make_agent  # noqa: E402
from proxybench.autolab.calibration import draw_calibrations  # noqa: E402
from proxybench.autolab.cli_support import finish_sim_log  # noqa: E402
from proxybench.autolab.detect import Detector, tag_pose  # noqa: E402
from proxybench.autolab.geometry import camera_pose, planar  # noqa: E402
from proxybench.autolab.localize import localize_log  # noqa: E402
from proxybench.autolab.logs import read_log  # noqa: E402
from proxybench.autolab.target import localize_logs  # noqa: E402
from proxybench.autolab.validate import validate_run  # noqa: E402
from proxybench.autolab.watchtowers import (  # noqa: E402
    GroundTag,
    Layout,
    LayoutError,
    Watchtower,
    auto_layout,
    load_layout,
    write_layout,
)
from proxybench.domain import apriltags  # noqa: E402
from proxybench.domain.camera import CameraModel  # noqa: E402
from proxybench.domain.fixed_cameras import FixedCamera, FixedCameraRig  # noqa: E402
from proxybench.domain.map_objects import AprilTag  # noqa: E402
from proxybench.domain.maps import MapObject, load_map  # noqa: E402
from proxybench.domain.params import DomainParams  # noqa: E402
from proxybench.domain.simulator import Simulator  # noqa: E402
from proxybench.runner.jobs import DomainSpec  # noqa: E402
from proxybench.runner.record import record_run  # noqa: E402
from proxybench.targets.recorded import check_recording  # noqa: E402
from proxybench.tasks.trajectory import Trajectory  # noqa: E402

LANE_Y = 0.73
SMALL = DomainParams(image_width=32, image_height=24)


def _layout(**kw) -> Layout:
    towers = [Watchtower(name=n, position=(x, 0.88, 0.5), yaw=90.0, pitch=89.0, resolution=(320, 240), fov_y=60.0,
                         frame_rate=10.0, noise_std=1.0) for n, x in (("wt01", 0.75), ("wt02", 1.05))]
    tags = [GroundTag(id=7, x=0.8, y=1.1), GroundTag(id=8, x=1.0, y=1.08, heading=30.0)]
    return Layout(map="straight_road", watchtowers=towers, ground_tags=tags, **kw)


def _record(out: Path, seconds: float = 1.5, layout: Layout | None = None) -> Path:
    layout = layout or _layout()
    _, streams, _ = layout_streams_for(layout)
    traj = record_run(DomainSpec("simulation", SMALL), make_agent("pid"), "straight_road", 0,
                      seconds, out, video=False, pose=(0.6, LANE_Y, 0.0), meta={"map": "straight_road"},
                      streams=streams).trajectory
    traj.save(out / "trajectory.parquet")
    finish_sim_log(out, layout, "straight_road", "pid", 0, seconds, traj.termination)
    return out


def layout_streams_for(layout: Layout):
    """(layout, streams, the map with the layout's ground tags), as ``--watchtowers`` makes them."""
    from proxybench.autolab.calibration import stream_spec
    from proxybench.runner.streams import with_fixtures

    streams = stream_spec(layout)
    return layout, streams, with_fixtures(load_map("straight_road"), streams.fixtures)


@pytest.fixture(scope="module")
def run_log(tmp_path_factory) -> Path:
    return _record(tmp_path_factory.mktemp("autolab") / "run")


def _copy(log: Path, tmp_path: Path) -> Path:
    dest = tmp_path / "copy"
    shutil.copytree(log, dest)
    return dest


# -- tags -----------------------------------------------------------------------------------------------


def test_the_tag_table_is_opencvs_tag36h11():
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    assert len(apriltags.CODES) == d.bytesList.shape[0] == 587
    for i in (0, 1, 42, 300, 400, 586):
        marker = cv2.aruco.generateImageMarker(d, i, apriltags.GRID - 2, borderBits=1) > 127
        assert np.array_equal(apriltags.cells(i)[1:-1, 1:-1], marker)


_MAKE_AND_DESTROY = """
import gc, sys
import numpy as np
from proxybench.autolab.detect import pupil_detector_class
cls = pupil_detector_class()
img = (np.random.default_rng(0).random((120, 160)) * 255).astype(np.uint8)
for _ in range(8):
    det = cls(families="tag36h11", nthreads=1, quad_decimate=2.0, refine_edges=1)
    det.detect(img)
    del det
    gc.collect()
print("destroyed")
"""


def test_a_detector_is_destroyed_without_touching_freed_memory():
    """pupil-apriltags' own destructor frees the tag families before the detector that still walks them: with
    glibc's freed-memory poisoning (MALLOC_PERTURB_) that use after free crashes at once, as it did now and then
    in evaluator workers; ours destroys the detector first."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "MALLOC_PERTURB_": "165", "MALLOC_CHECK_": "3"}
    done = subprocess.run([sys.executable, "-c", _MAKE_AND_DESTROY], env=env, capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.strip() == "destroyed", done.stderr[-2000:]


def test_floor_tags_are_drawn_as_their_patterns_and_measured_to_a_millimetre():
    rng = np.random.default_rng(3)
    truth = {}
    objs = []
    for k in range(6):
        x, y, th = 0.6 + 0.15 * (k % 3), 0.75 + 0.2 * (k // 3), float(rng.uniform(-3, 3))
        objs.append(MapObject("floor_tag", x, y, th, tag=AprilTag("36h11", 300 + k, 0.065)))
        truth[300 + k] = (x, y, th)
    m = dataclasses.replace(load_map("straight_road"), objects=tuple(objs))
    sim = Simulator(m, SMALL)
    cam = FixedCamera("wt", 0.75, 0.85, 0.5, math.pi / 2, 89.0, 320, 240, fov_y=60.0)
    gray = cv2.cvtColor(FixedCameraRig(sim, [cam]).render(0)[0], cv2.COLOR_RGB2GRAY)
    lay = Layout(watchtowers=[Watchtower(name="wt", position=(0.75, 0.85, 0.5), yaw=90.0, resolution=(320, 240))],
                 calibration_error={"position": 0, "angle": 0, "focal": 0, "principal": 0, "clock": 0})
    cal = draw_calibrations(lay)[0]["wt"]
    T_mc = cal.pose()
    dets = Detector("apriltag").detect(gray)
    assert sorted(d.tag_id for d in dets) == sorted(truth)
    for d in dets:
        x, y, th = planar(T_mc @ tag_pose(d, 0.065, cal, T_mc[:3, :3].T @ [0, 0, 1]).T)
        tx, ty, tth = truth[d.tag_id]
        assert math.hypot(x - tx, y - ty) < 0.003
        assert abs(math.remainder(th - tth, 2 * math.pi)) < math.radians(1.0)


def test_camera_pose_agrees_with_the_renderers_camera():
    for yaw, pitch, roll in ((0.3, 60.0, 0.0), (2.0, 89.0, 5.0), (-1.0, 30.0, -10.0)):
        cam = FixedCamera("c", 1.0, 2.0, 0.7, yaw, pitch, 64, 48, roll=roll)
        model = CameraModel.from_params(cam.params(DomainParams()))
        T = camera_pose(1.0, 2.0, 0.7, yaw, pitch, roll)
        fx, fy, cx, cy = cam.intrinsics()
        for u, v in ((3.5, 7.5), (40.5, 30.5)):
            ray = model.rays(np.array(u), np.array(v))
            c, s = math.cos(yaw), math.sin(yaw)
            ray = np.array([c * ray[0] - s * ray[1], s * ray[0] + c * ray[1], ray[2]])
            mine = T[:3, :3] @ [(u - cx) / fx, (v - cy) / fy, 1.0]
            assert np.allclose(ray / np.linalg.norm(ray), mine / np.linalg.norm(mine), atol=1e-9)


def test_robots_carry_roof_tags_that_watchtowers_read():
    from proxybench.domain.npcs import NpcRobot, Traffic

    sim = Simulator("straight_road", SMALL, npcs=Traffic(robots=(NpcRobot(pose=(1.0, LANE_Y, 0.0)),)))
    sim.reset(0, 0, pose=(0.7, LANE_Y, 0.5))
    img = FixedCameraRig(sim, [FixedCamera("wt", 0.85, 0.85, 0.6, math.pi / 2, 89.0, 320, 240, fov_y=60.0)]).render()[0]
    ids = sorted(d.tag_id for d in Detector("apriltag").detect(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)))
    assert ids == [apriltags.ROOF_TAG_BASE, apriltags.ROOF_TAG_BASE + 1]  # the ego and its NPC robot


# -- layouts --------------------------------------------------------------------------------------------


def test_auto_layout_sees_every_drivable_tile_twice():
    m = load_map("loop_3x3")
    lay = auto_layout(m)
    cams = [w.camera() for w in lay.watchtowers]
    for t in m.drivable_tiles():
        x, y = (t.i + 0.5) * m.tile_size, (t.j + 0.5) * m.tile_size
        seeing = 0
        for c in cams:  # straight down: a footprint of height · tan(half fields of view) around the tower
            half_y = c.z * math.tan(math.radians(c.fov_y) / 2)
            half_x = half_y * c.width / c.height
            seeing += abs(x - c.x) < half_x and abs(y - c.y) < half_y
        assert seeing >= 2, (t.i, t.j)
    assert lay.ground_tags and all(not m.tile_at(g.x, g.y).drivable for g in lay.ground_tags)


def test_layout_errors_name_the_file_and_field(tmp_path):
    bad = tmp_path / "lay.yaml"
    write_layout(bad, _layout())
    bad.write_text(bad.read_text().replace("frame_rate", "framerate", 1))
    with pytest.raises(LayoutError, match=r"lay\.yaml: watchtowers\.0\.framerate: unknown key"):
        load_layout(bad)
    with pytest.raises(ValueError, match="wt01 are used twice"):
        Layout(watchtowers=[_layout().watchtowers[0]] * 2)


# -- streams and localisation ---------------------------------------------------------------------------


def test_a_run_writes_timestamped_streams_that_localise_to_a_checked_target(run_log, tmp_path):
    stamps = list(csv.DictReader((run_log / "watchtowers" / "wt01" / "timestamps.csv").read_text().splitlines()))
    assert 13 <= len(stamps) <= 15 and (run_log / "watchtowers" / "wt01" / "000000.jpg").is_file()
    summary = localize_logs(run_log, load_map("straight_road"), tmp_path / "T", workers=1, decimate=1.0)
    assert summary.runs[0][1].valid, summary.runs[0][1].reasons
    report = check_recording(tmp_path / "T")
    assert report.ok, report.problems
    assert report.manifest.source == "simulation" and report.manifest.agents == ["pid"]
    truth = Trajectory.load(run_log / "trajectory.parquet").columns
    loc = summary.runs[0][2].robots["ego"]
    two = loc.views >= 2
    assert two.sum() >= 10
    err = np.hypot(loc.pose[:, 0] - np.interp(loc.t, truth["t"], truth["x"]),
                   loc.pose[:, 1] - np.interp(loc.t, truth["t"], truth["y"]))
    heading = np.abs(np.remainder(loc.pose[:, 2] - np.interp(loc.t, truth["t"], truth["theta"]) + math.pi,
                                  2 * math.pi) - math.pi)
    assert np.median(err[two]) < 0.02 and np.median(np.degrees(heading[two])) < 2.0
    assert np.all(np.isfinite(loc.sigma)) and np.all(loc.sigma[:, :2] < 0.05)  # per-sample uncertainty, in m
    from proxybench.autolab.effect import localisation_effect

    effect = localisation_effect(tmp_path / "T", ("survival_time", "driven_lanedir_consec"), n_boot=50)
    assert effect is not None and effect.episodes == 1  # the localised run is first seen after its start:
    assert -0.3 < effect.bias["survival_time"].value < 0.0  # it survives a little shorter than the truth
    assert "metric bias (localised − true)" in effect.statement and np.isfinite(effect.prpv.value)


def test_gtsam_and_scipy_solve_the_same_graph(run_log):
    log = read_log(run_log)
    m = load_map("straight_road")
    from proxybench.autolab.localize import detect_log

    frames = detect_log(log, workers=1)
    a = localize_log(log, m, frames=frames, solver="gtsam").robots["ego"]
    b = localize_log(log, m, frames=frames, solver="scipy").robots["ego"]
    assert np.allclose(a.pose[:, :2], b.pose[:, :2], atol=2e-3)


# -- the DTA's validation -------------------------------------------------------------------------------


def _verdict(log_dir: Path):
    log = read_log(log_dir)
    return validate_run(log, localize_log(log, load_map("straight_road"), workers=1))


def test_an_illumination_change_makes_a_run_invalid(run_log, tmp_path):
    log = _copy(run_log, tmp_path)
    for p in sorted((log / "watchtowers" / "wt02").glob("*.jpg"))[8:]:
        img = cv2.imread(str(p))
        cv2.imwrite(str(p), (img * 0.5).astype(np.uint8))  # a lamp went out
    verdict = _verdict(log)
    assert not verdict.valid and "illumination changed by" in verdict.reasons[0] and "wt02" in verdict.reasons[0]


def test_a_lost_robot_and_a_premature_end_make_a_run_invalid(run_log, tmp_path):
    log = _copy(run_log, tmp_path)
    for tower in ("wt01", "wt02"):  # no tag is read after 0.3 s (out of focus), the light stays as it was
        for p in sorted((log / "watchtowers" / tower).glob("*.jpg"))[2:]:
            cv2.imwrite(str(p), cv2.GaussianBlur(cv2.imread(str(p)), (21, 21), 0))
    text = (log / "log.yaml").read_text().replace("seconds: 1.5", "seconds: 10.0")
    (log / "log.yaml").write_text(text)
    verdict = _verdict(log)
    assert not verdict.valid
    assert any("lost for" in r for r in verdict.reasons) and any("ended prematurely" in r for r in verdict.reasons)


def test_invalid_runs_are_listed_in_the_target_never_dropped_silently(run_log, tmp_path):
    root = tmp_path / "logs"
    shutil.copytree(run_log, root / "a")
    shutil.copytree(run_log, root / "b")
    (root / "b" / "log.yaml").write_text((root / "b" / "log.yaml").read_text().replace("seconds: 1.5",
                                                                                       "seconds: 10.0"))
    localize_logs(root, load_map("straight_road"), tmp_path / "T", workers=1)
    report = check_recording(tmp_path / "T")
    assert report.ok and report.manifest.episodes == [0]
    assert [x.run for x in report.manifest.excluded] == [str(root / "b")]
    assert any("excluded" in n and "ended prematurely" in n for n in report.notes)


# -- bad input ------------------------------------------------------------------------------------------


def test_a_watchtower_without_calibration_is_named(run_log, tmp_path):
    log = _copy(run_log, tmp_path)
    (log / "watchtowers" / "wt02" / "calibration.yaml").unlink()
    with pytest.raises(LayoutError, match=r"wt02/calibration\.yaml: missing"):
        read_log(log)


@pytest.mark.parametrize(("edit", "message"), [
    (lambda rows: rows.__setitem__(4, ["4", "0.05"]), r"row 5 \(line 6\): the clock runs backwards"),
    (lambda rows: rows.__setitem__(slice(9, None), [[r[0], str(float(r[1]) + 500)] for r in rows[9:]]),
     r"row 10 \(line 11\): the clock jumps"),
    (lambda rows: rows.clear(), "empty stream"),
])
def test_clock_jumps_and_empty_streams_are_named(run_log, tmp_path, edit, message):
    log = _copy(run_log, tmp_path)
    path = log / "watchtowers" / "wt01" / "timestamps.csv"
    rows = list(csv.reader(path.read_text().splitlines()))[1:]
    edit(rows)
    with open(path, "w", newline="") as fh:
        csv.writer(fh).writerows([["frame", "t"], *rows])
    with pytest.raises(LayoutError, match=rf"wt01/timestamps\.csv: {message}" if rows else message):
        read_log(log)


def test_a_tag_id_seen_twice_in_a_frame_is_named(run_log, tmp_path):
    log = _copy(run_log, tmp_path)
    lay = _layout()
    m = dataclasses.replace(load_map("straight_road"), objects=(  # the lab printed tag 7 twice
        MapObject("floor_tag", 0.8, 1.1, tag=AprilTag("36h11", 7, 0.065)),
        MapObject("floor_tag", 0.9, 0.95, tag=AprilTag("36h11", 7, 0.065))))
    sim = Simulator(m, SMALL)
    img = FixedCameraRig(sim, [lay.watchtowers[0].camera()]).render()[0]
    frame = log / "watchtowers" / "wt01" / "000000.jpg"
    cv2.imwrite(str(frame), img[:, :, ::-1])
    shutil.rmtree(log / "watchtowers" / "wt02")
    (log / "watchtowers" / "wt01" / "timestamps.csv").write_text("frame,t\n0,0.0\n")
    with pytest.raises(LayoutError, match=rf"{frame}: tag id 7 seen twice in one frame"):
        localize_log(read_log(log), load_map("straight_road"), workers=1)


# -- ROS bags -------------------------------------------------------------------------------------------


def test_a_ros_bag_with_camera_and_wheel_topics_becomes_a_target(run_log, tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from proxybench.autolab.logs import WHEELS_CMD_MSG

    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg(WHEELS_CMD_MSG, "duckietown_msgs/msg/WheelsCmdStamped"))
    Image = store.types["sensor_msgs/msg/CompressedImage"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    Wheels = store.types["duckietown_msgs/msg/WheelsCmdStamped"]
    t0 = 1_700_000_000.0

    def stamp(t: float):
        return Header(seq=0, stamp=Time(sec=int(t0 + t), nanosec=int(round((t0 + t) % 1 * 1e9))), frame_id="")

    bag = tmp_path / "run.bag"
    with Writer(bag) as w:
        rows = []
        for tower in ("wt01", "wt02"):
            conn = w.add_connection(f"/{tower}/camera_node/image/compressed", Image.__msgtype__, typestore=store)
            for r in csv.DictReader((run_log / "watchtowers" / tower / "timestamps.csv").read_text().splitlines()):
                data = (run_log / "watchtowers" / tower / f"{int(r['frame']):06d}.jpg").read_bytes()
                msg = Image(header=stamp(float(r["t"])), format="jpeg", data=np.frombuffer(data, np.uint8))
                rows.append((float(r["t"]), conn, msg))
        conn = w.add_connection("/autobot01/wheels_driver_node/wheels_cmd", Wheels.__msgtype__, typestore=store)
        rows += [(k * 0.1, conn, Wheels(header=stamp(k * 0.1), vel_left=0.4, vel_right=0.5)) for k in range(16)]
        for t, c, msg in sorted(rows, key=lambda r: r[0]):
            w.write(c, int((t0 + t) * 1e9), store.serialize_ros1(msg, c.msgtype))
    cals = tmp_path / "calibrations"
    for tower in ("wt01", "wt02"):
        (cals / tower).mkdir(parents=True)
        shutil.copy(run_log / "watchtowers" / tower / "calibration.yaml", cals / tower / "calibration.yaml")
    lay = tmp_path / "lab.yaml"
    write_layout(lay, _layout().model_copy(update={"robots": {400: "autobot01"}}))
    summary = localize_logs(bag, load_map("straight_road"), tmp_path / "T", layout=lay, workers=1,
                            overrides={"agent": "lf", "active": "autobot01", "start": t0, "seconds": 1.5})
    report = check_recording(tmp_path / "T")
    assert report.ok, report.problems
    assert report.manifest.source == "real" and report.manifest.agents == ["lf"]  # a bag is a lab's, unless told
    table = (tmp_path / "T" / "episodes" / "lf" / "0.csv").read_text().splitlines()
    assert table[0].startswith("t,x,y,theta,pwm_left,pwm_right,sigma_x") and ",0.4,0.5," in table[1]
    assert summary.runs[0][2].robots["autobot01"].t.size >= 10


# -- the command line -----------------------------------------------------------------------------------


def test_run_and_localize_commands(run_log, tmp_path):
    from typer.testing import CliRunner

    from proxybench.cli import app

    runner = CliRunner()
    lay = write_layout(tmp_path / "lab.yaml", _layout())
    res = runner.invoke(app, ["run", "--map", "straight_road", "--watchtowers", str(lay), "--seconds", "0.4",
                              "--no-video", "--width", "32", "--height", "24", "--out", str(tmp_path / "D")])
    assert res.exit_code == 0, res.output
    log = read_log(tmp_path / "D")
    assert log.manifest.source == "simulation" and [s.name for s in log.streams] == ["wt01", "wt02"]
    res = runner.invoke(app, ["localize", str(run_log), "--map", "straight_road", "--out", str(tmp_path / "T"),
                              "--workers", "1"])
    assert res.exit_code == 0 and "wrote" in res.output, res.output
    assert runner.invoke(app, ["target", "check", str(tmp_path / "T")]).exit_code == 0
    broken = _copy(run_log, tmp_path)
    (broken / "watchtowers" / "wt01" / "calibration.yaml").unlink()
    res = runner.invoke(app, ["localize", str(broken), "--map", "straight_road", "--out", str(tmp_path / "T2")])
    assert res.exit_code == 1 and "wt01/calibration.yaml: missing" in res.output


def test_a_recorded_target_keeps_each_episodes_watchtower_log(tmp_path):
    from proxybench.autolab.cli_support import result_log
    from proxybench.runner.jobs import AgentSpec
    from proxybench.targets.record import record_target
    from proxybench.targets.spec import RealityTarget

    layout, streams, _ = layout_streams_for(_layout())
    record_target(tmp_path / "R", RealityTarget(), [AgentSpec("pid")], map_name="straight_road", seconds=0.3,
                  episodes=1, image_size=(32, 24), streams=streams,
                  on_streams=lambda res, folder: result_log(res, folder, layout, "straight_road", 0.3,
                                                            "reality-model"))
    log = read_log(tmp_path / "R" / "logs" / "pid" / "0")
    assert log.manifest.source == "reality-model" and log.truth is not None
    assert [s.name for s in log.streams] == ["wt01", "wt02"] and all(s.frames for s in log.streams)
    assert check_recording(tmp_path / "R").ok
