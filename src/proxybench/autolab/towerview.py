"""A watchtower's view of an episode with the localised pose drawn on it (issue 36: the Autolab's video artifact).

The top-down video is redrawn from the localised trajectory: it shows what was scored, not what the lab saw. This
one shows the lab's own frames: the watchtower that saw the robot best (the most localised samples inside its
image), each of its frames with the robot's localised pose at that frame's time drawn where the tower's
*calibration* projects it, with its 2σ ellipse and heading. A pose drawn off the robot therefore shows a
localisation (or calibration) error at a glance; a frame in which the robot was not localised says so.

Bounded so that it never dominates a job: at most ``max_frames`` frames (evenly thinned beyond), at most
``max_width`` pixels wide (shrunk beyond), only frames of the span in which the robot is in that tower's view;
each frame is decoded once, drawn with OpenCV and encoded (H.264, by an ffmpeg process). Its CPU time (the
encoder's included) is measured and reported.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from proxybench.autolab.calibration import Calibration
from proxybench.autolab.logs import Log, Stream

__all__ = ["TowerVideo", "project", "watchtower_video"]

#: how far outside its view [px] a pose still counts as seen by a tower (the roof tag's half width, about)
_MARGIN_PX = 20
#: a frame more than this [s] from the nearest localised sample shows "not localised" instead of a pose
_MAX_GAP_S = 0.5
_POSE = (255, 64, 0)  # RGB: the localised pose (orange on grey floors and white tags)
_SIGMA = (0, 200, 255)  # its 2σ ellipse


@dataclass
class TowerVideo:
    """The video written, the tower it shows, its frames and size, the pose drawn in each frame (episode time [s],
    pixel u, v in the tower's original image; None where the robot was not localised near that time) and the CPU
    time it took."""

    path: Path
    watchtower: str
    frames: int
    width: int
    height: int
    cpu_s: float
    drawn: list[tuple[float, float, float] | None] = field(default_factory=list)
    frame_times: list[float] = field(default_factory=list)  # the clock time of each frame shown (the log's own)

    def report(self) -> dict[str, object]:
        """What the job's report says of it."""
        return {"name": self.path.name, "watchtower": self.watchtower, "frames": self.frames,
                "width": self.width, "height": self.height, "cpu_s": round(self.cpu_s, 3)}


def project(cal: Calibration, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) pixels of the map points ``points`` (N, 3) in the calibrated camera, and whether each lies in front
    of it (a point behind the camera has no pixel: its row is NaN)."""
    import cv2

    T_cam_map = np.linalg.inv(cal.pose())
    cam = points @ T_cam_map[:3, :3].T + T_cam_map[:3, 3]
    front = cam[:, 2] > 1e-6
    out = np.full((len(points), 2), np.nan)
    if not front.any():
        return out, front
    pts = cam[front].reshape(-1, 1, 3)
    zero = np.zeros(3)
    if cal.distortion_model == "equidistant":
        img, _ = cv2.fisheye.projectPoints(pts, zero, zero, cal.K, cal.D[:4])
    else:
        img, _ = cv2.projectPoints(pts, zero, zero, cal.K, np.zeros(5) if cal.distortion_model == "none" else cal.D)
    out[front] = img.reshape(-1, 2)
    return out, front


def _inside(cal: Calibration, uv: np.ndarray, margin: float = _MARGIN_PX) -> np.ndarray:
    """Which pixels lie in the image (with ``margin``)."""
    with np.errstate(invalid="ignore"):
        return ((uv[:, 0] >= -margin) & (uv[:, 0] < cal.image_width + margin)
                & (uv[:, 1] >= -margin) & (uv[:, 1] < cal.image_height + margin))


def _roof(track: Mapping[str, np.ndarray], roof_z: float) -> np.ndarray:
    """(N, 3) the roof tag's centre of each localised sample."""
    return np.column_stack([track["x"], track["y"], np.full(len(track["x"]), roof_z)])


def best_tower(log: Log, track: Mapping[str, np.ndarray], roof_z: float) -> Stream | None:
    """The stream whose calibrated view holds the most localised samples (ties: the nearer the image's centre on
    average, then the name); None when no tower's view holds one."""
    best, key = None, None
    for s in log.streams:
        uv, _ = project(s.calibration, _roof(track, roof_z))
        seen = _inside(s.calibration, uv, 0.0)
        if not seen.any():
            continue
        centre = np.array([s.calibration.image_width, s.calibration.image_height]) / 2.0
        spread = float(np.mean(np.hypot(*(uv[seen] - centre).T)))
        k = (-int(seen.sum()), spread, s.name)
        if key is None or k < key:
            best, key = s, k
    return best


def _pose_at(track: Mapping[str, np.ndarray], t: float) -> dict[str, float] | None:
    """The localised pose (interpolated, heading unwrapped) and σ at episode time ``t``; None beyond the track or
    more than :data:`_MAX_GAP_S` from its nearest sample."""
    ts = track["t"]
    if t < ts[0] - _MAX_GAP_S or t > ts[-1] + _MAX_GAP_S or np.min(np.abs(ts - t)) > _MAX_GAP_S:
        return None
    out = {k: float(np.interp(t, ts, track[k])) for k in ("x", "y", "sigma_x", "sigma_y", "sigma_theta")}
    out["theta"] = float(np.interp(t, ts, np.unwrap(track["theta"])))
    return out


def _read(ref: str | bytes) -> np.ndarray | None:
    """An RGB frame from its file or bytes; None when it cannot be decoded."""
    import cv2

    data = np.frombuffer(ref, np.uint8) if isinstance(ref, bytes) else np.fromfile(ref, np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_COLOR)
    return None if img is None else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _draw(img: np.ndarray, cal: Calibration, pose: dict[str, float] | None, roof_z: float,
          label: str) -> tuple[float, float] | None:
    """Draw ``pose`` (its roof point, heading and 2σ ellipse, projected) and ``label`` into ``img``; the pose's
    pixel, or None when it is not drawn."""
    import cv2

    scale = img.shape[1] / cal.image_width
    drawn = None
    if pose is None:
        label += "  robot not localised"
    else:
        x, y, th = pose["x"], pose["y"], pose["theta"]
        phi = np.linspace(0.0, 2 * math.pi, 32)
        pts = np.array([[x, y, roof_z], [x + 0.08 * math.cos(th), y + 0.08 * math.sin(th), roof_z],
                        *np.column_stack([x + 2 * pose["sigma_x"] * np.cos(phi), y + 2 * pose["sigma_y"] * np.sin(phi),
                                          np.full(phi.size, roof_z)])])
        uv, front = project(cal, pts)
        if front.all():
            px = np.round(uv * scale).astype(np.int32)
            cv2.polylines(img, [px[2:]], True, _SIGMA, 1, cv2.LINE_AA)
            cv2.arrowedLine(img, tuple(px[0]), tuple(px[1]), _POSE, 2, cv2.LINE_AA, tipLength=0.3)
            cv2.circle(img, tuple(px[0]), 6, _POSE, 2, cv2.LINE_AA)
            drawn = (float(uv[0, 0]), float(uv[0, 1]))
        label += (f"  sigma {1000 * math.hypot(pose['sigma_x'], pose['sigma_y']):.1f} mm, "
                  f"{math.degrees(pose['sigma_theta']):.1f} deg")
    cv2.putText(img, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return drawn


def _span(stream: Stream, track: Mapping[str, np.ndarray], start: float, roof_z: float) -> list[int]:
    """Indices of the stream's frames from the first to the last in which the localised robot is in its view."""
    times = np.array([f.t - start for f in stream.frames])
    poses = [_pose_at(track, t) for t in times]
    seen = []
    for k, p in enumerate(poses):
        if p is not None:
            uv, _ = project(stream.calibration, np.array([[p["x"], p["y"], roof_z]]))
            if _inside(stream.calibration, uv)[0]:
                seen.append(k)
    return list(range(seen[0], seen[-1] + 1)) if seen else []


def watchtower_video(log: Log, track: Mapping[str, np.ndarray], out: Path, *, roof_z: float | None = None,
                     max_frames: int = 150, max_width: int = 640) -> TowerVideo | None:
    """The best-placed watchtower's frames of ``log`` with the localised ``track`` drawn (see the module) as an MP4
    at ``out``; None when no tower's view holds a localised sample. ``track``: episode time ``t`` [s from the
    log's start], ``x``, ``y``, ``theta``, ``sigma_x``, ``sigma_y``, ``sigma_theta`` (localisation's track table)."""
    from proxybench.domain.objects import ROOF_TAG_Z
    from proxybench.media import VideoWriter

    cpu = _cpu()
    z = ROOF_TAG_Z if roof_z is None else roof_z
    track = {k: np.asarray(v, dtype=float) for k, v in track.items()}
    if len(track.get("t", ())) == 0:
        return None
    stream = best_tower(log, track, z)
    if stream is None:
        return None
    start = log.manifest.start or 0.0
    span = _span(stream, track, start, z)
    if not span:
        return None
    if len(span) > max_frames:  # evenly thinned: the whole span, shown faster
        span = [span[int(k)] for k in np.linspace(0, len(span) - 1, max_frames)]
    cal = stream.calibration
    scale = min(1.0, max_width / cal.image_width)
    width, height = int(round(cal.image_width * scale)), int(round(cal.image_height * scale))
    dts = np.diff([f.t for f in stream.frames])
    fps = float(min(30.0, max(1.0, 1.0 / np.median(dts)))) if dts.size else 5.0
    video = TowerVideo(out, stream.name, 0, width, height, 0.0)
    with VideoWriter(out, fps) as writer:
        for k in span:
            frame = stream.frames[k]
            img = _read(frame.ref)
            if img is None:
                continue
            if img.shape[:2] != (height, width):
                import cv2

                img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
            t = frame.t - start
            video.drawn.append(_draw(img, cal, _pose_at(track, t), z, f"{stream.name}  t {t:5.2f} s"))
            video.frame_times.append(frame.t)
            writer.append(img)
            video.frames += 1
    video.cpu_s = _cpu() - cpu
    return video


def _cpu() -> float:
    """CPU time [s] of this process and of its children that ended (the encoder, ffmpeg, is one)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system
