"""A run's log → every robot's trajectory in the map frame, with per-sample uncertainty.

1. **Detect** (``detect``) the tags in every frame of every watchtower (in ``workers`` processes), and measure
   each frame's brightness (for the DTA's illumination check, ``validate``).
2. **Measure** each tag's pose relative to its watchtower from the watchtower's calibration.
3. **Build the pose graph** (``posegraph``): watchtowers at their calibrated poses, floor tags (the map's and the
   lab's ground tags) at their known poses, and every robot's roof tag at every time a watchtower saw it.
4. **Solve** it (GTSAM, or SciPy) and read each robot's samples: (t, x, y, θ) of the robot (its roof tag lowered
   to the ground), σ of each, and how many watchtowers saw it within one frame of that time (``views``).

A tag id seen twice in one frame (two tags printed with one id, or a robot tag that is also a floor tag) is an
error naming the frame.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from proxybench.autolab.detect import Detection, Detector, TagPose, tag_pose
from proxybench.autolab.geometry import planar, pose_from_planar
from proxybench.autolab.logs import MAX_FRAME_BYTES, Frame, Log
from proxybench.autolab.posegraph import Observation, PoseGraph, solve_gtsam, solve_scipy
from proxybench.autolab.watchtowers import LayoutError, UnsafeLogError
from proxybench.domain.apriltags import ROOF_TAG_BASE, ROOF_TAG_SIZE
from proxybench.domain.maps import Map
from proxybench.untrusted import UntrustedInputError, read_bytes_file

__all__ = ["FrameResult", "Localization", "RobotTrack", "StreamView", "detect_frame", "detect_log",
           "localize_log"]


@dataclass
class RobotTrack:
    """One robot's localised samples: times [s], poses (K, 3) [m, m, rad], their 1σ (K, 3), views (K,)."""

    name: str
    t: np.ndarray
    pose: np.ndarray
    sigma: np.ndarray
    views: np.ndarray


@dataclass
class FrameResult:
    """What one frame gave: its stream, time, detections and mean brightness [0..255]."""

    stream: int
    t: float
    detections: list[Detection]
    brightness: float
    detected: bool = True  # the detector ran on this frame (False: its watchtower's view had not changed)


@dataclass
class Localization:
    """The result of :func:`localize_log`: tracks by robot, watchtowers as solved, per-frame brightness, counts."""

    robots: dict[str, RobotTrack]
    towers: dict[str, np.ndarray]
    brightness: dict[str, np.ndarray]  # stream -> (F, 2) time, brightness
    frames: int
    detections: int
    notes: list[str] = field(default_factory=list)
    timing: dict[str, float] = field(default_factory=dict)
    detected: int = 0  # frames the detector ran on (the others re-used their watchtower's unchanged view)


#: a watchtower is fixed: a frame whose 8 × 8-pixel block means all lie within this many grey levels of the frame
#: its tags were last detected in shows the same tags, which are re-used (sensor noise and JPEG move a block's
#: mean by ≤ 2 levels; a robot moving half a pixel moves the blocks on its tag's edges by more than 6)
SAME_VIEW_LEVELS = 6
#: the side of those blocks [px]
BLOCK = 8
#: an unchanged view is detected again every this many frames all the same: independent detections of the
#: floor tags keep coming (each frame's noise is its own), which the pose graph averages
REFRESH_FRAMES = 10

_WORKER: dict = {}


def _init(kind: str, decimate: float) -> None:
    _WORKER["det"] = Detector(kind, decimate)


def _decode(frame: Frame) -> np.ndarray:
    """The frame as a (H, W) grey image; its file read as strangers' input (regular, bounded, not a link)."""
    import cv2

    data = frame.ref
    if not isinstance(data, bytes):  # a file of the log: regular, bounded, not a link (a FIFO is never read)
        try:
            data = read_bytes_file(data, max_bytes=MAX_FRAME_BYTES, follow_links=False)
        except UntrustedInputError as exc:
            raise UnsafeLogError(str(exc)) from None
    gray = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE) if data else None
    if gray is None:
        raise LayoutError(f"{frame.label}: not a readable image")
    return gray


def _thumbnail(gray: np.ndarray) -> np.ndarray:
    """Each BLOCK × BLOCK block's mean (int16, so that differences do not wrap)."""
    import cv2

    h, w = gray.shape
    size = (max(1, w // BLOCK), max(1, h // BLOCK))
    return cv2.resize(gray, size, interpolation=cv2.INTER_AREA).astype(np.int16)


def _checked(frame: Frame, dets: list[Detection]) -> list[Detection]:
    seen: set[int] = set()
    for d in dets:
        if d.tag_id in seen:
            raise LayoutError(f"{frame.label}: tag id {d.tag_id} seen twice in one frame: two tags carry that id")
        seen.add(d.tag_id)
    return dets


@dataclass
class StreamView:
    """One watchtower's last detected view, carried from frame to frame of its stream in order: its block means
    (None before the first frame), its detections, and the frames since it was detected. Offline
    (:func:`detect_log`) and online (:mod:`.online`) detection step the same state, so both give the same frames."""

    ref: np.ndarray | None = None
    dets: list[Detection] = field(default_factory=list)
    age: int = 0


def detect_frame(view: StreamView, detector: Detector, frame: Frame, stream: int, reuse: bool = True) -> FrameResult:
    """The next frame of the stream whose view is ``view``. With ``reuse``, a frame whose view has not changed since
    the frame its tags were last detected in (every block within SAME_VIEW_LEVELS) gets those detections again
    without running the detector: a fixed camera mostly sees a still floor, so only frames where something moved
    cost a detection. Brightness is each frame's own (the mean of its blocks)."""
    gray = _decode(frame)
    thumb = _thumbnail(gray)
    view.age += 1
    ref = view.ref
    same = (reuse and ref is not None and view.age < REFRESH_FRAMES and ref.shape == thumb.shape
            and int(np.abs(thumb - ref).max(initial=0)) <= SAME_VIEW_LEVELS)
    if not same:
        view.dets, view.ref, view.age = _checked(frame, detector.detect(gray)), thumb, 0
    return FrameResult(stream, frame.t, view.dets, float(thumb.mean()), detected=not same)


def _detect_stream(args: tuple[int, list[Frame], bool]) -> list[FrameResult]:
    """One watchtower's frames in order (:func:`detect_frame`)."""
    k, frames, reuse = args
    view = StreamView()
    return [detect_frame(view, _WORKER["det"], frame, k, reuse) for frame in frames]


def detect_log(log: Log, detector: str = "apriltag", workers: int | None = None, decimate: float = 1.0,
               progress: Callable[[int, int], None] | None = None, reuse: bool = True) -> list[FrameResult]:
    """Tags and brightness of every frame of every stream, one stream at a time in order (its frames re-use the
    last detection while the view is unchanged, unless ``reuse`` is False), in ``workers`` processes (default:
    the cores)."""
    jobs = [(k, s.frames, reuse) for k, s in enumerate(log.streams)]
    total = sum(len(s.frames) for s in log.streams)
    workers = workers or len(os.sched_getaffinity(0))
    out: list[FrameResult] = []
    if workers <= 1:
        _init(detector, decimate)
        results = map(_detect_stream, jobs)
    else:
        import multiprocessing as mp

        pool = ProcessPoolExecutor(min(workers, max(1, len(jobs))), mp_context=mp.get_context("spawn"),
                                   initializer=_init, initargs=(detector, decimate))
        results = pool.map(_detect_stream, jobs)
    try:
        for res in results:
            out.extend(res)
            if progress:
                progress(len(out), total)
    finally:
        if workers > 1:
            pool.shutdown(cancel_futures=True)
    return out


def _tag_tables(log: Log, m: Map, robots: dict[int, str]) -> tuple[dict[int, np.ndarray], dict[int, float]]:
    """Known floor tags (id -> T_map_tag) and every tag's size [m]: the map's floor tags and the log's ground tags."""
    fixed: dict[int, np.ndarray] = {}
    sizes: dict[int, float] = dict.fromkeys(robots, ROOF_TAG_SIZE)
    where: dict[int, str] = {}
    tags = [(o.tag.tag_id, o.tag.size, o.x, o.y, o.heading, f"map {m.name!r}") for o in m.objects
            if o.kind == "floor_tag" and o.tag is not None]
    tags += [(g.id, g.size, g.x, g.y, math.radians(g.heading), f"{log.root}: ground_tags") for g in
             log.manifest.ground_tags]
    for tag_id, size, x, y, th, origin in tags:
        if tag_id in robots:
            raise LayoutError(f"{origin}: tag id {tag_id} is a floor tag and robot {robots[tag_id]!r}'s roof tag")
        if tag_id in fixed:
            raise LayoutError(f"{origin}: floor tag id {tag_id} is placed twice (also in {where[tag_id]})")
        fixed[tag_id] = pose_from_planar(x, y, th, 0.001)
        sizes[tag_id] = size
        where[tag_id] = origin
    return fixed, sizes


def localize_log(log: Log, m: Map, *, robots: dict[int, str] | None = None, detector: str = "apriltag",
                 solver: str = "gtsam", workers: int | None = None, decimate: float = 1.0,
                 frames: list[FrameResult] | None = None,
                 progress: Callable[[int, int], None] | None = None, reuse: bool = True) -> Localization:
    """Every robot's trajectory in the map frame from one run's log (see the module docstring)."""
    import time

    t0, c0 = time.perf_counter(), time.process_time()
    robots = dict(robots or log.manifest.robots or {ROOF_TAG_BASE: "ego"})
    if frames is None:
        frames = detect_log(log, detector, workers, decimate, progress, reuse)
    t1, c1 = time.perf_counter(), time.process_time()
    fixed, sizes = _tag_tables(log, m, robots)
    graph = PoseGraph(fixed=fixed)
    cals = {s.name: s.calibration for s in log.streams}
    ups = {}
    for s in log.streams:
        c = s.calibration
        graph.towers[s.name] = (c.pose(), c.uncertainty.position, math.radians(c.uncertainty.angle))
        ups[s.name] = c.pose()[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    seen: dict[str, list[tuple[float, str, np.ndarray, np.ndarray]]] = {}
    unknown: set[int] = set()
    n_det = 0
    poses: dict[int, TagPose | None] = {}  # a detection re-used by unchanged frames is measured once (by its identity)
    for fr in frames:
        name = log.streams[fr.stream].name
        for d in fr.detections:
            n_det += 1
            if d.tag_id not in sizes:
                unknown.add(d.tag_id)
                continue
            if id(d) not in poses:
                poses[id(d)] = tag_pose(d, sizes[d.tag_id], cals[name], ups[name])
            tp = poses[id(d)]
            if tp is None:
                continue
            if d.tag_id in fixed:
                graph.observations.append(Observation(name, ("tag", d.tag_id), tp.T, tp.cov))
            else:
                seen.setdefault(robots[d.tag_id], []).append((fr.t, name, tp.T, tp.cov))
    notes = [f"tag id(s) {', '.join(map(str, sorted(unknown)))} seen but neither a floor tag nor a known robot: "
             "ignored"] if unknown else []
    rates = {s.name: (len(s.frames) - 1) / max(s.frames[-1].t - s.frames[0].t, 1e-9) if len(s.frames) > 1 else 10.0
             for s in log.streams}
    for robot, obs in seen.items():
        obs.sort(key=lambda o: o[0])
        times: list[float] = []
        for t, name, T, cov in obs:
            if not times or t - times[-1] > 5e-4:  # one vertex per time (within half a millisecond)
                times.append(t)
            graph.observations.append(Observation(name, ("robot", robot, len(times) - 1), T, cov))
        graph.robots[robot] = np.array(times)
    solution = (solve_gtsam if solver == "gtsam" else solve_scipy)(graph)
    t2, c2 = time.perf_counter(), time.process_time()
    tracks = {r: _track(r, graph, solution, seen[r], rates) for r in graph.robots}
    bright: dict[str, list[tuple[float, float]]] = {}
    for fr in frames:
        bright.setdefault(log.streams[fr.stream].name, []).append((fr.t, fr.brightness))
    towers = {n: solution.poses[("tower", n)] for n in graph.towers}
    return Localization(tracks, towers, {k: np.array(v) for k, v in bright.items()}, len(frames), n_det, notes,
                        {"detect_s": t1 - t0, "solve_s": t2 - t1,  # wall; CPU of this process (not its workers)
                         "detect_cpu_s": c1 - c0, "solve_cpu_s": c2 - c1}, sum(f.detected for f in frames))


def _track(robot: str, graph: PoseGraph, solution, obs: list, rates: dict[str, float]) -> RobotTrack:
    times = graph.robots[robot]
    # the roof tag's pose raised above the robot's: its planar part is the robot's pose
    pose = np.array([planar(solution.poses[("robot", robot, k)]) for k in range(len(times))])
    sigma = np.full((len(times), 3), np.nan)
    for k in range(len(times)):
        c = solution.cov.get(("robot", robot, k))
        if c is not None:
            sigma[k] = np.sqrt(np.maximum(np.diag(c), 0.0))
    # views: watchtowers that saw the robot within one of their frame periods of the sample
    obs_t = np.array([o[0] for o in obs])
    obs_w = np.array([o[1] for o in obs])
    views = np.zeros(len(times), dtype=np.int64)
    for k, t in enumerate(times):
        near = np.abs(obs_t - t) <= np.array([1.0 / rates[w] for w in obs_w]) + 1e-6
        views[k] = len(set(obs_w[near].tolist()))
    return RobotTrack(robot, times, pose, sigma, views)
