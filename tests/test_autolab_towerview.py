"""The watchtower-view video (issue 36): a tower's own frames with the localised pose drawn where its calibration
projects it. A simulated run of test_autolab's (two 320 × 240 towers over a straight road, 1.5 s) is localised,
the video made from it, decoded and compared with the robot's roof tag as the tower's frames show it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cv2")
pytest.importorskip("pupil_apriltags")
pytest.importorskip("gtsam")
pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

from support.dtps import sdk
from support.sandbox import AGENT_USER_GROUP, require_safe_sandbox
from test_autolab import _record
from test_autolab_evaluator import BENCH, LAB, sdk_package
from test_evaluator import evaluator, served, the_job  # noqa: F401 - served: test_evaluator's fixture


@pytest.fixture(scope="module")
def localised(tmp_path_factory):
    """(the log, the ego's track table) of a short simulated run."""
    from proxybench.autolab.localize import localize_log
    from proxybench.autolab.logs import read_log
    from proxybench.autolab.target import track_table
    from proxybench.domain.maps import load_map

    log = read_log(_record(tmp_path_factory.mktemp("towerview") / "run"))
    track = localize_log(log, load_map("straight_road"), workers=1).robots["ego"]
    return log, track_table(track, log.manifest.start)


def _decode(path: Path) -> list[np.ndarray]:
    import imageio.v2 as imageio

    with imageio.get_reader(path) as reader:
        return [np.asarray(f) for f in reader]


def test_the_video_shows_a_towers_frames_with_the_pose_drawn_on_the_robot(localised, tmp_path: Path) -> None:
    from proxybench.autolab.detect import Detector
    from proxybench.autolab.towerview import _read, watchtower_video
    from proxybench.domain.apriltags import ROOF_TAG_BASE

    log, track = localised
    video = watchtower_video(log, track, tmp_path / "tower.mp4")
    assert video is not None and video.path.is_file()
    assert video.watchtower in {"wt01", "wt02"} and (video.width, video.height) == (320, 240)
    frames = _decode(video.path)
    assert len(frames) == video.frames >= 10  # the frames of the span the robot is in that tower's view
    assert frames[0].shape == (240, 320, 3)
    stream = next(s for s in log.streams if s.name == video.watchtower)
    by_time = {f.t: f for f in stream.frames}
    detector, checked = Detector("apriltag", decimate=1.0), 0
    for k, (t, drawn) in enumerate(zip(video.frame_times, video.drawn, strict=True)):
        if drawn is None:
            continue
        raw = _read(by_time[t].ref)
        tag = next((d for d in detector.detect(raw.mean(axis=2).astype(np.uint8)) if d.tag_id == ROOF_TAG_BASE), None)
        if tag is None:  # the roof tag cut by the image's edge
            continue
        centre = tag.corners.mean(axis=0)
        assert np.hypot(*(np.array(drawn) - centre)) < 8.0, (t, drawn, centre)  # a quarter of the tag's width
        u, v = int(round(drawn[0])), int(round(drawn[1]))
        ring = frames[k][max(0, v - 3):v + 4, u + 3:u + 10].astype(int)  # the drawn circle's right edge
        assert (ring[..., 0] - ring[..., 2]).max() > 80  # orange on the grey frame: the drawing is there
        checked += 1
    assert checked >= 5, "the roof tag was detected in too few of the video's frames to check the drawing"


def test_a_track_no_tower_sees_makes_no_video_and_the_video_is_bounded(localised, tmp_path: Path) -> None:
    from proxybench.autolab.towerview import watchtower_video

    log, track = localised
    away = {**track, "x": np.asarray(track["x"]) + 50.0}  # 50 m off: in no tower's view
    assert watchtower_video(log, away, tmp_path / "none.mp4") is None
    small = watchtower_video(log, track, tmp_path / "small.mp4", max_frames=4, max_width=160)
    assert small is not None and (small.frames, small.width, small.height) == (4, 160, 120)
    frames = _decode(small.path)
    assert len(frames) == 4 and frames[0].shape == (120, 160, 3)


@sdk
@AGENT_USER_GROUP
def test_an_autolab_job_uploads_the_watchtower_video_beside_the_top_down_one(served, tmp_path: Path) -> None:  # noqa: F811
    """End to end (the demo's SDK agent, one 3-s episode, 12 towers at 5 Hz): both videos are artifacts, and the
    watchtower one decodes to the frames and size the report says."""
    from proxybench.autolab.lab import load_lab

    require_safe_sandbox()
    served.admin.post("/benchmarks", {"yaml": BENCH, "features": ["autolab"], "hidden_split": False})
    (tmp_path / "lab.yaml").write_text(LAB)
    archive = tmp_path / "agent.zip"
    archive.write_bytes(sdk_package())
    sub = served.developer.submit_archive(archive, "sdk-lane", benchmark="autolab_tiny")
    ev = evaluator(served, tmp_path, name="lab", video=True, features=("sim", "autolab"),
                   autolab=load_lab(tmp_path / "lab.yaml"))
    status = ev.take_one()
    _, (result,) = the_job(served, sub["id"])
    assert status == "success", result["message"]
    names = {a["name"]: a for a in result["artifacts"]}
    assert {"validation-episode-0.mp4", "validation-episode-0-watchtower.mp4"} <= set(names)
    info = result["public_report"]["watchtower_video"]
    assert info["name"] == "validation-episode-0-watchtower.mp4" and info["watchtower"].startswith("wt")
    video = tmp_path / "tower.mp4"
    video.write_bytes(served.admin.http.get(f"/artifacts/{names[info['name']]['sha256']}").content)
    frames = _decode(video)
    assert len(frames) == info["frames"] >= 5 and frames[0].shape == (info["height"], info["width"], 3)
    assert (info["width"], info["height"]) == (640, 480)
