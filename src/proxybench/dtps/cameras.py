"""Watchtowers over DTPS: simulated ones served as a lab's are, and a reader of any lab's (docs/dtps.md §9).

A Duckietown watchtower serves its camera as a Duckiebot does: ``<name>/sensor/camera/front_center/jpeg``
(duckietown-messages ``CompressedImage``, stamped with the camera's clock in ``header.timestamp``), ``…/parameters``
(``CameraIntrinsicCalibration``: ROS ``camera_info``'s K, D, P, R) and ``…/info`` (``Camera``). Both ends run
in the SDK environment through ``camera_bridge.py``:

- :class:`WatchtowerServer` serves simulated watchtowers on one DTPS server (role ``towers``): proxybench
  publishes each rendered frame; SDK programs, the reader below and anyone's DTPS tools read them.
- :class:`WatchtowerReader` subscribes to a lab's camera topics (ours or a real lab's, role ``watch``) and, between
  :meth:`~WatchtowerReader.begin` and :meth:`~WatchtowerReader.end`, writes each stream in the folder form
  localisation reads (``<out>/<name>/000000.jpg``…, ``timestamps.csv``: ``frame,t,stamp,received``; ``t`` is the
  stamp less the episode's clock origin). What arrives is a stranger's input: a frame that is not a JPEG or PNG of
  the calibrated size, larger than ``max_frame_bytes``, stamped with a clock that does not run forwards, or beyond
  ``max_frames`` of its stream, is not written; one line per stream says why (:class:`EpisodeStreams`).
"""

from __future__ import annotations

import csv
import logging
import math
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from proxybench.dtps.link import BridgeError, BridgeLink, PortLock, PortLockError

__all__ = ["CAMERA_BRIDGE", "CAMERA_TOPIC", "MAX_FRAMES", "MAX_FRAME_BYTES", "CameraSource", "EpisodeStreams",
           "EpisodeWriter", "ReaderError", "WatchtowerReader", "WatchtowerServer", "camera_source", "free_port",
           "image_size"]

log = logging.getLogger("proxybench.dtps.cameras")

CAMERA_BRIDGE = Path(__file__).with_name("camera_bridge.py")
#: a device's camera topic under its name (what duckiebot-interface serves)
CAMERA_TOPIC = "sensor/camera/front_center/jpeg"
#: the largest frame message read [bytes] (a 1296×972 JPEG of a busy scene is ~1 MB)
MAX_FRAME_BYTES = 8 << 20
#: frames of one stream in one episode (an hour at 30 Hz is 108,000; the localiser's own bound is 200,000)
MAX_FRAMES = 200_000
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


class ReaderError(RuntimeError):
    """The watchtower reader cannot go on (its bridge failed, a source is unreachable); one line naming it."""


class CameraSource(BaseModel):
    """One watchtower's camera topic: ``url`` of its DTPS server, ``path`` of the ``jpeg`` topic on it, and the
    image size its calibration expects (None: not checked)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    url: str
    path: str
    width: int | None = Field(None, ge=1, le=8192)
    height: int | None = Field(None, ge=1, le=8192)


def camera_source(name: str, address: str, width: int | None = None, height: int | None = None) -> CameraSource:
    """A watchtower at ``HOST[:PORT]/PATH`` (as a lab.yaml names it): its camera topic is ``PATH/`` + CAMERA_TOPIC."""
    from proxybench.dtps.robot_options import parse_address

    addr = parse_address(address)
    return CameraSource(name=name, url=addr.url, path=f"{addr.path}/{CAMERA_TOPIC}", width=width, height=height)


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` now (the simulated watchtowers of a split take one)."""
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def image_size(data: bytes, fmt: str) -> tuple[int, int]:
    """(width, height) from a JPEG's or PNG's own header, without decoding it; a ValueError saying what is wrong.
    A JPEG must also end with its end-of-image marker (a frame cut short in transit does not)."""
    if fmt == "png":
        if data[:8] != b"\x89PNG\r\n\x1a\n" or data[12:16] != b"IHDR" or len(data) < 24:
            raise ValueError("not a PNG (no signature and IHDR header)")
        w, h = struct.unpack(">II", data[16:24])
        return int(w), int(h)
    if data[:2] != b"\xff\xd8":
        raise ValueError("not a JPEG (no start-of-image marker)")
    if data[-2:] != b"\xff\xd9":
        raise ValueError("a JPEG cut short (no end-of-image marker)")
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            raise ValueError(f"a broken JPEG (no marker at byte {i})")
        marker = data[i + 1]
        if marker == 0xFF:
            i += 1
            continue
        if marker in _JPEG_SOF:
            if i + 9 > len(data):
                break
            h, w = struct.unpack(">HH", data[i + 5:i + 9])
            return int(w), int(h)
        if marker == 0x01 or 0xD0 <= marker <= 0xD9:
            i += 2
            continue
        (n,) = struct.unpack(">H", data[i + 2:i + 4])
        if n < 2:
            raise ValueError(f"a broken JPEG (segment length {n} at byte {i})")
        i += 2 + n
    raise ValueError("a JPEG without a frame header")


@dataclass
class _Stream:
    """One watchtower's frames of the open episode."""

    rows: list[tuple[int, float, float, float]] = field(default_factory=list)  # frame, t, stamp, received
    bad: int = 0
    dropped: int = 0
    first_problem: str | None = None
    on_arrival: bool | None = None  # stamped by the reader's clock (the camera sent no timestamp)


@dataclass
class EpisodeStreams:
    """What the reader wrote for one episode: frames per watchtower, bad messages (with the first reason), frames
    beyond the bounds, frames published that never arrived (when the publisher's count is known)."""

    folder: Path
    frames: dict[str, int]
    bad: dict[str, int]
    problems: dict[str, str]
    dropped: dict[str, int]
    missing: dict[str, int] = field(default_factory=dict)

    def report(self) -> dict[str, Any]:
        return {"frames": self.frames, "bad": self.bad, "problems": self.problems, "dropped": self.dropped,
                "missing": self.missing}


class EpisodeWriter:
    """Writes one episode's frames (events of the ``watch`` bridge) into ``folder`` (see the module); pure of
    threads and processes, so that every check is testable with events made by hand. ``on_frame(name, index,
    data, t)`` is told of each frame written (its file's index, its bytes, its episode time): online localisation
    detects it as it arrives (it must return at once: it runs on the reader's thread)."""

    def __init__(self, sources: list[CameraSource], folder: Path, origin: float, *,
                 max_frame_bytes: int = MAX_FRAME_BYTES, max_frames: int = MAX_FRAMES,
                 on_frame: Callable[[str, int, bytes, float], None] | None = None):
        self.sources = {s.name: s for s in sources}
        self.on_frame = on_frame
        self.folder, self.origin = Path(folder), float(origin)
        self.max_frame_bytes, self.max_frames = max_frame_bytes, max_frames
        self.streams = {name: _Stream() for name in self.sources}
        self.folder.mkdir(parents=True, exist_ok=True)

    def _problem(self, name: str, why: str) -> None:
        s = self.streams[name]
        s.bad += 1
        if s.first_problem is None:
            s.first_problem = why
            log.warning("watchtower %s: a bad message (%s); not recorded", name, why)

    def bad(self, ev: dict[str, Any]) -> None:
        """A message the bridge refused (not a compressed image): counted, with its one-line reason."""
        name = ev.get("name")
        if name in self.streams:
            self._problem(name, str(ev.get("detail", "unreadable"))[:300])

    def frame(self, ev: dict[str, Any]) -> None:
        """One frame event: checked, then written as the stream's next file."""
        name = ev.get("name")
        if name not in self.streams:
            return  # not a source of ours: the bridge subscribes to ours only
        s, src = self.streams[name], self.sources[name]
        data, fmt = ev.get("data"), ev.get("format")
        try:
            if not isinstance(data, bytes) or fmt not in ("jpeg", "png"):
                raise ValueError("not an image of format jpeg or png")
            if len(data) > self.max_frame_bytes:
                raise ValueError(f"a frame of {len(data)} bytes (at most {self.max_frame_bytes})")
            w, h = image_size(data, fmt)
            if (src.width, src.height) != (None, None) and (w, h) != (src.width, src.height):
                raise ValueError(f"a {w}×{h} frame; the calibration is for {src.width}×{src.height}")
            stamp, received = ev.get("stamp"), float(ev.get("wall", time.time()))
            if s.on_arrival is None:
                s.on_arrival = stamp is None
                if s.on_arrival:
                    log.warning("watchtower %s: frames carry no header.timestamp; stamped on arrival", name)
            if (stamp is None) != s.on_arrival:
                raise ValueError("header.timestamp given for some frames and not for others")
            clock = received if stamp is None else float(stamp)
            if not math.isfinite(clock):
                raise ValueError("the timestamp is not a finite number")
            if s.rows and clock <= s.rows[-1][2]:
                raise ValueError(f"the clock runs backwards or stands still ({s.rows[-1][2]:.6f} → {clock:.6f} s)")
        except ValueError as exc:
            self._problem(name, str(exc))
            return
        if len(s.rows) >= self.max_frames:
            s.dropped += 1
            if s.dropped == 1:
                log.warning("watchtower %s: more than %d frames in one episode; the rest are not recorded", name,
                            self.max_frames)
            return
        k = len(s.rows)
        folder = self.folder / name
        folder.mkdir(exist_ok=True)
        with open(folder / f"{k:06d}.{'jpg' if fmt == 'jpeg' else 'png'}", "xb") as fh:
            fh.write(data)
        s.rows.append((k, clock - self.origin, clock, received))
        if self.on_frame is not None:
            self.on_frame(name, k, data, clock - self.origin)

    def received(self) -> dict[str, int]:
        """Frames taken so far (written, refused or dropped) per watchtower."""
        return {n: len(s.rows) + s.bad + s.dropped for n, s in self.streams.items()}

    def finish(self, published: dict[str, int] | None = None) -> EpisodeStreams:
        """Write each stream's ``timestamps.csv`` (a watchtower that sent no frame gets no folder: localisation
        reads the ones that did) and say what happened."""
        for name, s in self.streams.items():
            if not s.rows:
                continue
            with open(self.folder / name / "timestamps.csv", "w", newline="") as fh:
                w = csv.writer(fh)
                w.writerow(["frame", "t", "stamp", "received"])
                w.writerows([(k, f"{t:.6f}", f"{st:.6f}", f"{r:.6f}") for k, t, st, r in s.rows])
        got = self.received()
        missing = {n: max(0, c - got.get(n, 0)) for n, c in (published or {}).items() if c > got.get(n, 0)}
        return EpisodeStreams(self.folder, {n: len(s.rows) for n, s in self.streams.items()},
                              {n: s.bad for n, s in self.streams.items() if s.bad},
                              {n: s.first_problem for n, s in self.streams.items() if s.first_problem},
                              {n: s.dropped for n, s in self.streams.items() if s.dropped}, missing)


class WatchtowerReader:
    """Subscribes to ``sources`` (one bridge, role ``watch``) and records them episode by episode (see the module).

    A thread reads the bridge all the time; frames that arrive outside an episode are not recorded (a topic's
    latest frame arrives as soon as one subscribes). ``begin(folder, origin)`` opens an episode whose clock starts
    at ``origin`` (the watchtowers' clock at the episode's t = 0), ``end()`` closes it.
    """

    def __init__(self, sources: list[CameraSource], *, python: str | Path | None = None, timeout: float = 20.0,
                 max_frame_bytes: int = MAX_FRAME_BYTES, max_frames: int = MAX_FRAMES):
        if not sources:
            raise ValueError("a watchtower reader needs at least one camera topic")
        self.sources = list(sources)
        self.max_frame_bytes, self.max_frames = max_frame_bytes, max_frames
        args = ["watch", "--max-bytes", str(max_frame_bytes), "--timeout", str(timeout)]
        for s in self.sources:
            args += ["--source", s.name, s.url, s.path]
        try:
            self.link = BridgeLink(args, python=python, start_timeout=timeout * len(self.sources) + 30.0,
                                   script=CAMERA_BRIDGE)
        except BridgeError as exc:
            raise ReaderError(f"the watchtower reader did not start: {exc.detail}"
                              + "".join(f"; {line}" for line in exc.stderr_tail[-2:])) from None
        self._lock = threading.Lock()
        self._writer: EpisodeWriter | None = None
        self._failure: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._pump, name="watchtower-reader", daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        while not self._stop.is_set():
            try:
                events = self.link.poll(time.monotonic() + 0.1)
            except BridgeError as exc:
                if not self._stop.is_set():
                    self._failure = f"the watchtower reader's bridge ended: {exc.detail}"
                return
            with self._lock:
                for ev in events:
                    kind = ev.get("ev")
                    if kind == "error":
                        self._failure = str(ev.get("detail"))[:300]
                    elif self._writer is not None and kind == "frame":
                        self._writer.frame(ev)
                    elif self._writer is not None and kind == "bad":
                        self._writer.bad(ev)

    def _check(self) -> None:
        if self._failure is not None:
            raise ReaderError(self._failure)

    def begin(self, folder: str | Path, origin: float,
              on_frame: Callable[[str, int, bytes, float], None] | None = None) -> None:
        """Record from now on into ``folder``; ``origin``: the watchtowers' clock [s] at the episode's t = 0;
        ``on_frame``: told of each frame written (:class:`EpisodeWriter`)."""
        self._check()
        with self._lock:
            if self._writer is not None:
                raise ReaderError("the watchtower reader records one episode at a time; one is still open")
            self._writer = EpisodeWriter(self.sources, Path(folder), origin, max_frame_bytes=self.max_frame_bytes,
                                         max_frames=self.max_frames, on_frame=on_frame)

    def end(self, published: dict[str, int] | None = None, *, grace: float = 1.0,
            timeout: float = 10.0) -> EpisodeStreams:
        """Close the episode: wait for frames still in flight (until each watchtower's ``published`` count
        arrived, at most ``timeout`` s; without counts, ``grace`` s), then write the timestamps."""
        deadline = time.monotonic() + (timeout if published else grace)
        while time.monotonic() < deadline and self._failure is None:
            with self._lock:
                got = self._writer.received() if self._writer is not None else {}
            if published and all(got.get(n, 0) >= c for n, c in published.items()):
                break
            time.sleep(0.02)
        with self._lock:
            writer, self._writer = self._writer, None
        if writer is None:
            raise ReaderError("the watchtower reader has no episode open")
        result = writer.finish(published)
        if result.missing:
            log.warning("watchtowers: frames published but never received: %s",
                        ", ".join(f"{n} {c}" for n, c in sorted(result.missing.items())))
        return result

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.link.close()


class WatchtowerServer:
    """Simulated watchtowers served as DTPS camera topics at ``http://host:port/<name>/sensor/camera/front_center/``
    (one bridge, role ``towers``; the port held by this user's :class:`~.link.PortLock` while it serves)."""

    def __init__(self, names: list[str], *, host: str = "127.0.0.1", port: int | None = None,
                 python: str | Path | None = None, start_timeout: float = 60.0, lock_timeout: float = 60.0):
        self.host, self.port = host, port if port is not None else free_port(host)
        self.lock = PortLock(self.port)
        try:
            self.lock.acquire(lock_timeout)
        except PortLockError as exc:
            raise ReaderError(str(exc)) from None
        args = ["towers", "--host", host, "--port", str(self.port)]
        for n in names:
            args += ["--name", n]
        try:
            self.link = BridgeLink(args, python=python, start_timeout=start_timeout, script=CAMERA_BRIDGE)
        except BridgeError as exc:
            self.lock.release()
            raise ReaderError(f"the simulated watchtowers' DTPS server did not start: {exc.detail}") from None
        except BaseException:
            self.lock.release()
            raise
        self.url = str(self.link.ready["url"])
        self.published: dict[str, int] = dict.fromkeys(names, 0)

    def address(self, name: str) -> str:
        """The watchtower's address as a lab.yaml names one (``HOST:PORT/NAME``)."""
        return f"{self.host}:{self.port}/{name}"

    def info(self, name: str, *, width: int, height: int, fov: float, frequency: float, K: list[float],
             D: list[float], distortion_model: str) -> None:
        """Publish a watchtower's ``parameters`` (its calibration's intrinsics, as ROS camera_info) and ``info``."""
        fx, _, cx, _, fy, cy, _, _, _ = K
        P = [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
        self.link.send(op="info", name=name, width=width, height=height, fov=fov, frequency=frequency, K=list(K),
                       D=list(D), P=P, R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                       distortion_model=distortion_model)

    def publish(self, name: str, jpeg: bytes, stamp: float, t: float) -> None:
        """One frame of watchtower ``name``, stamped ``stamp`` [s] on its clock (``t``: the episode's time)."""
        self.published[name] += 1
        self.link.send(op="frame", name=name, jpeg=jpeg, stamp=stamp, t=t, seq=self.published[name] - 1)

    def take_counts(self) -> dict[str, int]:
        """Frames published per watchtower since the last call."""
        counts, self.published = self.published, dict.fromkeys(self.published, 0)
        return counts

    @property
    def alive(self) -> bool:
        return self.link.alive

    def close(self) -> None:
        try:
            self.link.close()
        finally:
            self.lock.release()
