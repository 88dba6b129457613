"""Timestamped image streams of fixed cameras (a lab's watchtowers), recorded while an episode runs.

A ``StreamSpec`` rides along with an episode (``Job.streams``, ``record_run(streams=...)``): the cameras
(``domain.fixed_cameras.FixedCamera``, where they truly are), each one's frame rate and clock offset, and the
objects the lab adds to the map (its calibration tags, ``fixtures``: they are part of the simulated world,
so the robots' cameras see them too). ``StreamRecorder`` is called from the episode's frame hook: at every
camera frame of the episode it renders the fixed cameras that are due and writes, per camera::

    <out>/<camera>/000000.jpg ...         the frames (JPEG by default, as a lab's compressed image topics)
    <out>/<camera>/timestamps.csv         frame,t: the file's index and the camera's clock [s] at exposure

A camera is due when its own schedule (one frame every 1/rate s from a phase drawn from its name) has come
since its last frame; its frame shows the world at the episode frame at or after that time (the simulator
steps at ``frame_rate``), stamped with that time on the camera's clock (episode time + ``clock_offset``).
Nothing here chooses where episodes run: the runner's frame hook calls it.

A spec with a ``sink`` (a :class:`StreamSink`) sends the frames there instead of writing them: the sink is told
where the episode's streams belong when its recorder starts (``begin``), gets each frame as JPEG bytes stamped on
the camera's clock (``frame``), and writes the folder itself when the episode ends (``end``). The Autolab's
simulated watchtowers served over DTPS are such a sink (``autolab.live``): their frames reach the folder through
a DTPS server and the lab's reader, as a lab's own watchtowers' do. A spec with a sink may have no cameras at all
(a lab's own cameras, recorded by the sink while the episode runs).

A spec without a sink may have an ``observer`` (a :class:`FrameObserver`), told of each frame as its file is
written, so that it can work on the frames while the episode runs (the Autolab's online localisation,
``autolab.online``); it never changes what is written.
"""

from __future__ import annotations

import csv
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from proxybench.domain.fixed_cameras import FixedCamera, FixedCameraRig
from proxybench.domain.maps import Map, MapObject

__all__ = ["EpisodeObserver", "FrameObserver", "StreamRecorder", "StreamSink", "StreamSpec", "with_fixtures"]


class StreamSink(Protocol):
    """Where an episode's watchtower frames go instead of files (see the module); ``kind`` enters the job's key."""

    kind: str

    def begin(self, out: Path) -> None: ...

    def frame(self, camera: str, jpeg: bytes, stamp: float, t: float) -> None: ...

    def end(self) -> None: ...


class EpisodeObserver(Protocol):
    """One episode's frames as they are written: ``frame`` must return at once (it runs in the frame hook)."""

    def frame(self, camera: str, index: int, ref: str, t: float) -> None: ...

    def end(self) -> None: ...


class FrameObserver(Protocol):
    """Told of each episode whose streams are written to files (see the module): ``begin`` gives its handle."""

    def begin(self, out: Path) -> EpisodeObserver: ...


@dataclass(frozen=True)
class StreamSpec:
    """Fixed cameras to record during an episode: ``rates`` [Hz] and ``clock_offsets`` [s] per camera."""

    cameras: tuple[FixedCamera, ...]
    rates: tuple[float, ...]
    clock_offsets: tuple[float, ...]
    fixtures: tuple[MapObject, ...] = ()
    image_format: str = "jpg"
    quality: int = 95
    sink: StreamSink | None = field(default=None, compare=False)
    observer: FrameObserver | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if not (len(self.cameras) == len(self.rates) == len(self.clock_offsets)) or not (self.cameras or self.sink):
            raise ValueError("a stream spec needs one rate and one clock offset per camera, and a camera (or a sink)")
        if self.sink is not None and self.image_format != "jpg":
            raise ValueError("a stream sink takes JPEG frames (image_format jpg)")
        if self.image_format not in ("jpg", "png"):
            raise ValueError(f"image_format must be jpg or png, got {self.image_format!r}")
        if any(r <= 0 for r in self.rates):
            raise ValueError("frame rates must be positive")

    def key_data(self) -> dict[str, Any]:
        """What identifies the streams in a job's hash."""
        from dataclasses import asdict

        doc = {"cameras": [asdict(c) for c in self.cameras], "rates": list(self.rates),
               "clock": list(self.clock_offsets), "fixtures": [asdict(o) for o in self.fixtures],
               "format": [self.image_format, self.quality]}
        if self.sink is not None:  # absent otherwise, so jobs recording files keep their keys
            doc["sink"] = self.sink.kind
        return doc


def with_fixtures(m: Map, fixtures: tuple[MapObject, ...]) -> Map:
    """``m`` with a lab's fixtures added to its objects."""
    import dataclasses

    return dataclasses.replace(m, objects=(*m.objects, *fixtures)) if fixtures else m


class StreamRecorder:
    """Writes the streams of ``spec`` for world ``world`` of ``sim`` into ``out`` (see the module docstring)."""

    def __init__(self, sim, spec: StreamSpec, out: str | Path, world: int = 0, rig: FixedCameraRig | None = None):
        self.sim, self.spec, self.world = sim, spec, world
        self.out = Path(out)
        if rig is None and spec.cameras:  # a sink alone: nothing rendered; ``rig``: shared by a lab world's episodes
            rig = FixedCameraRig(sim, spec.cameras)
        self.rig = rig
        self.phase = [(zlib.crc32(c.name.encode()) % 1000) / 1000.0 / r for c, r in zip(spec.cameras, spec.rates,
                                                                                          strict=True)]
        self.count = [0] * len(spec.cameras)
        self.stamps: list[list[tuple[int, float]]] = [[] for _ in spec.cameras]
        self.watch = spec.observer.begin(self.out) if spec.observer is not None and spec.sink is None else None
        if spec.sink is not None:
            spec.sink.begin(self.out)
            return
        for c in spec.cameras:
            (self.out / c.name).mkdir(parents=True, exist_ok=True)

    def frame(self, t: float) -> int:
        """Render and write the cameras due at episode time ``t`` [s]; how many frames were written."""
        import cv2

        due = [i for i, r in enumerate(self.spec.rates) if t + 1e-9 >= self.phase[i] + self.count[i] / r]
        if not due:
            return 0
        images = self.rig.render(self.world, frame=int(round(t * 1000)), only=due)
        ext = self.spec.image_format
        flags = [cv2.IMWRITE_JPEG_QUALITY, self.spec.quality] if ext == "jpg" else []
        for i in due:
            cam = self.spec.cameras[i]
            r = self.spec.rates[i]
            k = len(self.stamps[i])
            bgr = np.ascontiguousarray(images[i][:, :, ::-1])
            if self.spec.sink is not None:
                ok, jpeg = cv2.imencode(".jpg", bgr, flags)
                if not ok:
                    raise OSError(f"watchtower {cam.name}: cannot encode its frame")
                self.spec.sink.frame(cam.name, jpeg.tobytes(), t + self.spec.clock_offsets[i], t)
            else:
                path = self.out / cam.name / f"{k:06d}.{ext}"
                if not cv2.imwrite(str(path), bgr, flags):
                    raise OSError(f"{path}: cannot write the frame")
                if self.watch is not None:
                    self.watch.frame(cam.name, k, str(path), t)
            self.stamps[i].append((k, t + self.spec.clock_offsets[i]))
            while t + 1e-9 >= self.phase[i] + self.count[i] / r:  # skip slots the episode's frames stepped over
                self.count[i] += 1
        return len(due)

    def close(self) -> None:
        """Write every camera's ``timestamps.csv`` (with a sink: the sink writes the folder)."""
        if self.spec.sink is not None:
            self.spec.sink.end()
            return
        for cam, rows in zip(self.spec.cameras, self.stamps, strict=True):
            with open(self.out / cam.name / "timestamps.csv", "w", newline="") as fh:
                w = csv.writer(fh)
                w.writerow(["frame", "t"])
                w.writerows([(k, f"{t:.6f}") for k, t in rows])
        if self.watch is not None:
            self.watch.end()
