"""A lab's logs in: image folders with timestamps and calibration files (the Autolab's), or ROS 1/2 bags.

**Image folders** (``proxybench run --watchtowers`` writes them; a lab can too)::

    LOG/log.yaml                          what the run was (``LogManifest``: source, map, agent, episode, seconds,
                                          the active robot, roof tag ids, the lab's ground tags)
    LOG/watchtowers/<name>/calibration.yaml   the watchtower's calibration (``autolab.calibration``)
    LOG/watchtowers/<name>/timestamps.csv     frame,t: the frame's file index and the clock time [s]
    LOG/watchtowers/<name>/000000.jpg ...     the frames (JPEG or PNG)
    LOG/trajectory.parquet                (simulation only) the true trajectory, for measuring the localisation

**ROS bags** (read with ``rosbags``: no ROS install), ROS 1 ``.bag`` or ROS 2 folders, with Duckietown's topics:
``/<name>/camera_node/image/compressed`` (sensor_msgs/CompressedImage: one stream per ``<name>``, stamped by
the message header) and ``/<robot>/wheels_driver_node/wheels_cmd`` (duckietown_msgs/WheelsCmdStamped:
``vel_left``, ``vel_right``, kept as the trajectory's ``pwm_left``/``pwm_right``). A bag holds no extrinsics:
each watchtower's calibration is ``<calibrations>/<name>/calibration.yaml`` or ``<calibrations>/<name>.yaml``.

Every problem names the file at fault: a watchtower without calibration, an empty stream, time that runs
backwards or jumps (a gap of more than ``MAX_GAP`` frame periods), a frame file that is missing.

A log comes from another person's machine, so it is read as a stranger's input (:class:`UnsafeLogError`
otherwise, naming the file or field and the value): ``log.yaml`` and calibrations through the bounded YAML
loader (no links); every name that becomes a file or folder name (the agent, the active robot, the robots'
names, a bag's watchtower names) is one path component (:func:`proxybench.untrusted.path_component`);
watchtower folders and frames are never links, frames are regular files (a FIFO is refused, never opened) of
at most ``MAX_FRAME_BYTES``, a stream holds at most ``MAX_STREAM_FRAMES`` frames, each listed once, a log at
most ``MAX_LOG_FRAMES``; a bag at most ``MAX_BAG_MESSAGES`` messages and ``MAX_BAG_BYTES`` of images.
"""

from __future__ import annotations

import csv
import io
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field

from proxybench.autolab.calibration import Calibration, draw_calibrations, load_calibration, write_calibration
from proxybench.autolab.watchtowers import GroundTag, Layout, LayoutError, UnsafeLogError, read_model, robot_names
from proxybench.untrusted import UntrustedInputError, path_component, read_text_file

__all__ = ["LOG_FORMAT", "MAX_BAG_BYTES", "MAX_BAG_MESSAGES", "MAX_FRAME_BYTES", "MAX_GAP", "MAX_LOG_FRAMES",
           "MAX_STREAM_FRAMES", "Frame", "Log", "LogManifest", "Stream", "find_logs", "read_log",
           "write_log_manifest", "write_sim_log"]

LOG_FORMAT = "proxybench-autolab-log/1"
LOG_NAME = "log.yaml"
#: a stream whose clock jumps ahead by more than this many frame periods (or runs backwards) is refused
MAX_GAP = 20.0
#: the largest frame file read [bytes] (a 4K PNG is ~25 MB)
MAX_FRAME_BYTES = 32 << 20
#: frames of one watchtower's stream (an hour at 30 Hz is 108,000), and of one log
MAX_STREAM_FRAMES = 200_000
MAX_LOG_FRAMES = 1_000_000
#: the largest timestamps.csv read [bytes] (~20 bytes a row)
MAX_TIMESTAMPS_BYTES = 16 << 20
#: watchtower folders of one log
MAX_TOWERS = 512
#: a ROS bag's messages read, and its image bytes held [bytes]
MAX_BAG_MESSAGES = 2_000_000
MAX_BAG_BYTES = 4 << 30
_IMAGE_TOPIC = "/camera_node/image/compressed"
_WHEELS_TOPIC = "/wheels_driver_node/wheels_cmd"
WHEELS_CMD_MSG = """std_msgs/Header header
float32 vel_left
float32 vel_right
"""


class LogManifest(BaseModel):
    """What one run's log is: ``log.yaml`` (strict)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: Literal["proxybench-autolab-log/1"] = LOG_FORMAT
    source: Literal["real", "reality-model", "robot-node", "simulation"] = "real"
    map: str | None = None
    agent: str = Field("agent", min_length=1, description="the agent the active robot ran")
    episode: int = Field(0, ge=0)
    seconds: float | None = Field(None, gt=0.0, le=3600.0, description="the episode's length as planned [s] "
                                  "(a target's episodes are at most an hour)")
    start: float = Field(0.0, description="clock time of the episode's start [s]")
    termination: str | None = Field(None, description="why the run ended, if it ended early for a reason")
    active: str = Field("ego", description="the robot the agent drove")
    robots: dict[int, str] = Field(default_factory=dict, description="roof tag id -> robot name")
    ground_tags: list[GroundTag] = Field(default_factory=list)


@dataclass(frozen=True)
class Frame:
    """One frame of a stream: clock time [s], and a file path or encoded bytes (``label`` names it in errors)."""

    t: float
    ref: str | bytes
    label: str


@dataclass
class Stream:
    """One watchtower's frames and calibration."""

    name: str
    calibration: Calibration
    frames: list[Frame]
    origin: str  # the folder or bag topic, for messages


@dataclass
class Log:
    """One run: its manifest, its watchtower streams, its robots' wheel commands (t, left, right)."""

    root: Path
    manifest: LogManifest
    streams: list[Stream]
    commands: dict[str, np.ndarray] = field(default_factory=dict)
    truth: Path | None = None


def _manifest(path: Path, overrides: dict | None = None) -> LogManifest:
    """``log.yaml`` (bounded, no link), every name in it that becomes a file or folder name checked as one."""
    manifest = read_model(path, LogManifest, LOG_FORMAT, overrides, missing_ok=True, follow_links=False)
    check_names(manifest, str(path))
    return manifest


def check_names(manifest: LogManifest, origin: str) -> None:
    """:class:`UnsafeLogError` unless the agent, the active robot and every robot's name can each be one file
    name (``localize`` writes ``episodes/<agent>/…`` and ``localization/<agent>/<episode>/<robot>.csv``)."""
    names = [("agent", manifest.agent), ("active", manifest.active),
             *((f"robots.{tag}", name) for tag, name in manifest.robots.items())]
    for field_name, value in names:
        try:
            path_component(value, field=field_name)
        except UntrustedInputError as exc:
            raise UnsafeLogError(f"{origin}: {exc}") from None


def write_log_manifest(root: str | Path, manifest: LogManifest) -> Path:
    path = Path(root) / LOG_NAME
    path.write_text(yaml.safe_dump(manifest.model_dump(mode="json", exclude_none=True), sort_keys=False))
    return path


def write_sim_log(root: str | Path, layout: Layout, streams: str | Path, manifest: LogManifest) -> Path:
    """Make ``root`` a log of a simulated run whose streams were recorded into ``streams``: move them to
    ``root/watchtowers``, add each watchtower's calibration (the layout's truth plus its drawn error) and the
    manifest (with the layout's ground tags and the simulator's robots)."""
    import shutil

    root, streams = Path(root), Path(streams)
    towers = root / "watchtowers"
    if streams.resolve() != towers.resolve():
        if towers.exists():
            shutil.rmtree(towers)
        towers.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(str(streams), str(towers))
    cals, _ = draw_calibrations(layout)
    for name, cal in cals.items():
        write_calibration(towers / name / "calibration.yaml", cal)
    update = {"source": manifest.source if manifest.source != "real" else "simulation",
              "ground_tags": list(layout.ground_tags), "robots": manifest.robots or robot_names(layout)}
    return write_log_manifest(root, manifest.model_copy(update=update))


def _check_times(times: np.ndarray, origin: str, row_label) -> None:
    """Time must run forwards without jumps: an error naming ``origin`` and the row otherwise."""
    if times.size == 0:
        raise LayoutError(f"{origin}: empty stream (no frames)")
    if not np.all(np.isfinite(times)):
        k = int(np.argmax(~np.isfinite(times)))
        raise LayoutError(f"{origin}: {row_label(k)}: time is not a finite number")
    d = np.diff(times)
    if d.size and np.any(d <= 0):
        k = int(np.argmax(d <= 0)) + 1
        raise LayoutError(f"{origin}: {row_label(k)}: the clock runs backwards or stands still "
                          f"({times[k - 1]:.6f} → {times[k]:.6f} s)")
    if d.size >= 2:
        period = float(np.median(d))
        if np.any(d > MAX_GAP * period):
            k = int(np.argmax(d > MAX_GAP * period)) + 1
            raise LayoutError(f"{origin}: {row_label(k)}: the clock jumps {d[k - 1]:.3f} s ahead (frames come every "
                              f"{period:.3f} s): a clock reset, or frames lost")


def _folder_stream(folder: Path) -> Stream:
    cal = load_calibration(folder / "calibration.yaml")
    stamps = folder / "timestamps.csv"
    if not os.path.lexists(stamps):
        raise LayoutError(f"{stamps}: missing (frame,t: each frame's index and clock time [s])")
    try:
        text = read_text_file(stamps, max_bytes=MAX_TIMESTAMPS_BYTES, follow_links=False)
    except UntrustedInputError as exc:
        raise UnsafeLogError(str(exc)) from None
    try:
        rows = []
        for row in csv.DictReader(io.StringIO(text, newline="")):
            rows.append(row)
            if len(rows) > MAX_STREAM_FRAMES:
                raise UnsafeLogError(f"{stamps}: more than {MAX_STREAM_FRAMES} frames")
    except csv.Error as exc:
        raise LayoutError(f"{stamps}: cannot read ({exc})") from None
    if rows and not {"frame", "t"} <= set(rows[0]):
        raise LayoutError(f"{stamps}: columns must be frame,t; got {', '.join(rows[0])}")
    try:
        idx = [int(r["frame"]) for r in rows]
        times = np.array([float(r["t"]) for r in rows], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise LayoutError(f"{stamps}: not a number ({exc})") from None
    _check_times(times, str(stamps), lambda k: f"row {k + 1} (line {k + 2})")
    if len(set(idx)) != len(idx):
        seen: set[int] = set()
        k = next(i for i, v in enumerate(idx) if v in seen or seen.add(v))
        raise UnsafeLogError(f"{stamps}: row {k + 1} (line {k + 2}): frame {idx[k]} is listed twice (each frame "
                             "once)")
    files = {}
    with os.scandir(folder) as entries:
        for entry in entries:
            p = Path(entry.path)
            if p.suffix.lower() in (".jpg", ".jpeg", ".png"):
                files[p.stem] = entry
    frames = []
    for k, t in zip(idx, times, strict=True):
        entry = files.get(f"{k:06d}")
        if entry is None:
            raise LayoutError(f"{stamps}: frame {k}: no image {folder / f'{k:06d}.jpg'}")
        _check_frame(Path(entry.path), entry.stat(follow_symlinks=False))
        frames.append(Frame(float(t), entry.path, entry.path))
    return Stream(folder.name, cal, frames, str(folder))


def _check_frame(path: Path, st: os.stat_result) -> None:
    """A frame is a regular file (never a link, a FIFO or a device: a FIFO would hang its reader) of at most
    ``MAX_FRAME_BYTES``."""
    if stat.S_ISLNK(st.st_mode):
        raise UnsafeLogError(f"{path}: a link (frames are files of the log, links are not followed)")
    if not stat.S_ISREG(st.st_mode):
        raise UnsafeLogError(f"{path}: not a regular file (a FIFO, a device or a folder where a frame belongs)")
    if st.st_size > MAX_FRAME_BYTES:
        raise UnsafeLogError(f"{path}: {st.st_size} bytes; a frame is at most {MAX_FRAME_BYTES}")


def _read_folder(root: Path, overrides: dict | None) -> Log:
    manifest = _manifest(root / LOG_NAME, overrides)
    towers = root / "watchtowers"
    if not towers.is_dir():
        raise LayoutError(f"{root}: no watchtowers/ folder (one folder per watchtower: calibration.yaml, "
                          "timestamps.csv, frames)")
    if towers.is_symlink():
        raise UnsafeLogError(f"{towers}: a link (the log's folders are not followed out of it)")
    folders = []
    for d in sorted(towers.iterdir()):
        if d.is_symlink():
            raise UnsafeLogError(f"{d}: a link (the log's folders are not followed out of it)")
        if d.is_dir():
            folders.append(d)
        if len(folders) > MAX_TOWERS:
            raise UnsafeLogError(f"{towers}: more than {MAX_TOWERS} watchtower folders")
    streams = [_folder_stream(d) for d in folders]
    if not streams:
        raise LayoutError(f"{towers}: no watchtower folders")
    total = sum(len(s.frames) for s in streams)
    if total > MAX_LOG_FRAMES:
        raise UnsafeLogError(f"{towers}: {total} frames; a log holds at most {MAX_LOG_FRAMES}")
    truth = root / "trajectory.parquet"
    return Log(root, manifest, streams, {}, truth if truth.is_file() else None)


def _calibration_for(name: str, where: Path) -> Calibration:
    for p in (where / name / "calibration.yaml", where / f"{name}.yaml"):
        if p.is_file():
            return load_calibration(p)
    raise LayoutError(f"{where / name / 'calibration.yaml'}: missing: watchtower {name!r} of the bag has no "
                      f"calibration (give --calibrations DIR with {name}/calibration.yaml or {name}.yaml)")


def _read_bag(path: Path, calibrations: Path | None, overrides: dict | None) -> Log:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(WHEELS_CMD_MSG, "duckietown_msgs/msg/WheelsCmdStamped"))
    where = calibrations or path.parent / "calibrations"
    images: dict[str, list[tuple[float, bytes]]] = {}
    wheels: dict[str, list[tuple[float, float, float]]] = {}
    count = held = 0
    try:
        with AnyReader([path], default_typestore=store) as reader:
            conns = [c for c in reader.connections if c.topic.endswith((_IMAGE_TOPIC, _WHEELS_TOPIC))]
            for conn in conns:  # the name becomes a file name (its calibration's): one path component
                path_component(conn.topic.strip("/").split("/")[0], field=f"{path}: topic {conn.topic[:80]!r}")
            for conn, _, raw in reader.messages(connections=conns):
                count += 1
                if count > MAX_BAG_MESSAGES:
                    raise UnsafeLogError(f"{path}: more than {MAX_BAG_MESSAGES} camera and wheel messages")
                msg = reader.deserialize(raw, conn.msgtype)
                stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                name = conn.topic.strip("/").split("/")[0]
                if conn.topic.endswith(_IMAGE_TOPIC):
                    data = bytes(msg.data)
                    held += len(data)
                    if len(data) > MAX_FRAME_BYTES or held > MAX_BAG_BYTES:
                        raise UnsafeLogError(f"{path}: {conn.topic[:80]} message {count}: images beyond "
                                             f"{MAX_FRAME_BYTES} bytes each or {MAX_BAG_BYTES} in all")
                    images.setdefault(name, []).append((stamp, data))
                else:
                    wheels.setdefault(name, []).append((stamp, float(msg.vel_left), float(msg.vel_right)))
    except UnsafeLogError:
        raise
    except UntrustedInputError as exc:
        raise UnsafeLogError(str(exc)) from None
    except Exception as exc:  # rosbags raises its own errors for unreadable or foreign files
        raise LayoutError(f"{path}: cannot read as a ROS bag ({type(exc).__name__}: {_one_line(exc)})") from None
    robots = set(wheels)
    streams = []
    for name, msgs in sorted(images.items()):
        if name in robots:
            continue  # a robot's own camera: not a watchtower
        topic = f"{path}:/{name}{_IMAGE_TOPIC}"
        times = np.array([m[0] for m in msgs])
        _check_times(times, topic, lambda k: f"message {k + 1}")
        streams.append(Stream(name, _calibration_for(name, where),
                              [Frame(t, data, f"{topic} message {k + 1}") for k, (t, data) in enumerate(msgs)], topic))
    if not streams:
        raise LayoutError(f"{path}: no watchtower image topics (/<name>{_IMAGE_TOPIC}) in the bag")
    commands = {r: np.array(sorted(v)) for r, v in wheels.items()}
    return Log(path, _manifest(path.with_suffix(".log.yaml"), overrides), streams, commands)


def _one_line(exc: BaseException, limit: int = 200) -> str:
    """An exception's text as one short printable line: rosbags quotes the bag's own bytes, newlines and all."""
    text = "".join(c if c.isprintable() else " " for c in " ".join(str(exc).split()))
    return text if len(text) <= limit else text[:limit] + "…"


def _is_bag(p: Path) -> bool:
    return (p.is_file() and p.suffix in (".bag", ".mcap", ".db3")) or (p.is_dir() and (p / "metadata.yaml").is_file())


def read_log(path: str | Path, calibrations: str | Path | None = None, overrides: dict | None = None) -> Log:
    """One run's log: an image folder or a bag (see the module). ``overrides``: manifest fields given on the
    command line (they win over ``log.yaml``)."""
    path = Path(path)
    if not path.exists():
        raise LayoutError(f"{path}: no such file or folder")
    if _is_bag(path):
        return _read_bag(path, Path(calibrations) if calibrations else None, overrides)
    return _read_folder(path, overrides)


def find_logs(root: str | Path) -> list[Path]:
    """The runs under ``root``: itself if it is a log (a folder with ``log.yaml`` or ``watchtowers/``, or a bag),
    else every such folder or bag below it, sorted."""
    root = Path(root)
    if _is_bag(root) or (root / LOG_NAME).is_file() or (root / "watchtowers").is_dir():
        return [root]
    if not root.is_dir():
        raise LayoutError(f"{root}: no such folder or bag")
    found = [p for p in sorted(root.rglob("*")) if _is_bag(p) or (p.is_dir() and (p / LOG_NAME).is_file())]
    return [p for p in found if not any(q != p and q in p.parents for q in found)]
