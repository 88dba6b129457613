"""Localisation that keeps up: a fixed watchtower's unchanged view re-uses its last detection (issue 36 item 4).

Synthetic streams (tags drawn from their patterns on a noisy grey floor, JPEG-encoded) pin down when the detector
runs and what a re-used frame reports; one short simulated run checks that the localised track is the one that
detecting every frame gives.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")
pytest.importorskip("pupil_apriltags")
pytest.importorskip("gtsam")

from proxybench.autolab import localize as loc_mod  # noqa: E402
from proxybench.autolab.localize import detect_log, localize_log  # noqa: E402
from proxybench.autolab.logs import Frame, Log, LogManifest, Stream, read_log  # noqa: E402
from proxybench.domain import apriltags  # noqa: E402
from proxybench.domain.maps import load_map  # noqa: E402

CELL = 4  # pixels per tag cell: a 40-px tag


def _image(tags: list[tuple[int, int, int]], seed: int, light: float = 0.0) -> bytes:
    """A 320 × 240 grey floor with sensor noise (1σ 2 levels) and tags (id, left, top), as a quality-95 JPEG."""
    rng = np.random.default_rng(seed)
    img = 128.0 + light + rng.normal(0.0, 2.0, (240, 320))
    for tag_id, x, y in tags:
        patch = np.kron(apriltags.cells(tag_id), np.ones((CELL, CELL))) * 230.0 + 15.0
        img[y:y + patch.shape[0], x:x + patch.shape[1]] = patch
    ok, buf = cv2.imencode(".jpg", np.clip(img, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return buf.tobytes()


def _log(images: list[bytes]) -> Log:
    frames = [Frame(0.2 * k, img, f"frame {k}") for k, img in enumerate(images)]
    # detection reads only the frames; the calibration is the pose graph's business
    return Log(Path("."), LogManifest(source="simulation", map="straight_road", agent="a", episode=0, seconds=2.0),
               [Stream("wt01", None, frames, "synthetic")])  # type: ignore[arg-type]


def _moving_robot() -> list[bytes]:
    """A floor tag that stays and a roof tag (400) that stands for three frames, moves 24 px, then stands."""
    return [_image([(3, 30, 30), (400, 150 if k < 3 else 174, 100)], seed=k) for k in range(8)]


def test_an_unchanged_view_reuses_its_detection_and_a_moved_tag_is_detected_again():
    frames = detect_log(_log(_moving_robot()), workers=1, decimate=2.0)
    assert [f.detected for f in frames] == [True, False, False, True, False, False, False, False]
    ids = [sorted(d.tag_id for d in f.detections) for f in frames]
    assert ids == [[3, 400]] * 8
    robot = [next(d for d in f.detections if d.tag_id == 400).corners for f in frames]
    assert robot[1] is robot[0] and robot[4] is robot[3]  # the very detection, not a new one
    assert np.allclose(robot[3] - robot[2], [24.0, 0.0], atol=0.3)  # the moved tag where it now is


def test_reused_detections_agree_with_detecting_every_frame():
    log = _log(_moving_robot())
    fast = detect_log(log, workers=1, decimate=2.0)
    every = detect_log(log, workers=1, decimate=2.0, reuse=False)
    assert all(f.detected for f in every)
    for a, b in zip(fast, every, strict=True):
        ca = {d.tag_id: d.corners for d in a.detections}
        cb = {d.tag_id: d.corners for d in b.detections}
        assert ca.keys() == cb.keys()
        for k in ca:  # the same tags within the noise of a detection
            assert np.abs(ca[k] - cb[k]).max() < 0.3


def test_a_still_view_is_detected_again_every_refresh_and_on_a_change_of_light():
    n = loc_mod.REFRESH_FRAMES + 3
    images = [_image([(3, 30, 30)], seed=k, light=25.0 if k == n - 1 else 0.0) for k in range(n)]
    frames = detect_log(_log(images), workers=1, decimate=2.0)
    detected = [k for k, f in enumerate(frames) if f.detected]
    assert detected == [0, loc_mod.REFRESH_FRAMES, n - 1]  # independent detections keep coming; light counts
    assert frames[-1].brightness > frames[-2].brightness + 20  # each frame's own brightness, reused or not


def test_a_tag_printed_twice_is_named_in_a_reusing_stream():
    from proxybench.autolab.watchtowers import LayoutError

    images = [_image([(3, 30, 30)], seed=0), _image([(3, 30, 30), (3, 200, 120)], seed=1)]
    with pytest.raises(LayoutError, match="frame 1: tag id 3 seen twice in one frame"):
        detect_log(_log(images), workers=1, decimate=2.0)


def test_the_localised_track_is_the_one_that_detecting_every_frame_gives(tmp_path):
    from test_autolab import _record

    log = read_log(_record(tmp_path / "run", seconds=1.5))
    m = load_map("straight_road")
    fast = localize_log(log, m, workers=1, decimate=2.0)
    every = localize_log(log, m, workers=1, decimate=2.0, reuse=False)
    a, b = fast.robots["ego"], every.robots["ego"]
    assert np.array_equal(a.t, b.t) and np.array_equal(a.views, b.views)
    assert np.abs(a.pose[:, :2] - b.pose[:, :2]).max() < 2e-3  # within 2 mm
    assert fast.detections == every.detections
