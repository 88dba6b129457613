"""Localisation online: each watchtower frame is detected as it arrives, while the episode runs (issue 36 item 4).

Offline (:func:`.localize.localize_log`) an episode's frames are all detected after it ends, so the lab waits for
the whole detection before it can score. Here an :class:`OnlineDetector` takes each frame the moment it is written
(a simulated watchtower's file, ``runner.streams`` observer; a DTPS frame the lab's reader received,
``autolab.live``), queues it and detects it on one worker thread, each stream in order with the same state as
offline (:class:`.localize.StreamView`: an unchanged view re-uses its detections), so that at the episode's end
only the pose graph is left: :meth:`OnlineEpisode.frames_for` gives ``localize_log(frames=…)`` the frames of the
episode's log, the same as offline detection of that log gives them.

The queue is bounded (``max_queue`` frames) and a frame offered to a full queue is **dropped**, never waited for:
the episode must not slow down because the lab's CPU is short. Drops are counted per watchtower and reported
(:meth:`OnlineEpisode.report`); a dropped frame is not localised (the watchtower's next frame still compares with
the view it last detected). How far behind the detection is (:class:`Lag`: frames queued, episode seconds between
the newest frame offered and the frame last detected) goes to ``report`` every ``every`` seconds of wall time,
which the Autolab evaluator logs. The worker is a thread: decoding and detecting release the GIL, so it takes a
core of its own where there is one, and it shares the evaluator's process, its frames never copied.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from proxybench.autolab.detect import Detector
from proxybench.autolab.localize import FrameResult, StreamView, detect_frame
from proxybench.autolab.logs import Frame, Log

__all__ = ["MAX_QUEUE", "Lag", "OnlineDetector", "OnlineEpisode"]

#: frames waiting for detection at most (all watchtowers together): ~2.4 s of the 43 watchtowers of the ETHZ
#: technical track at 5 Hz, ~50 MB of JPEG frames at the most
MAX_QUEUE = 512


@dataclass(frozen=True)
class Lag:
    """How far behind the detection is now: frames queued (all episodes), the episode time [s] between the newest
    frame offered and the frame last detected, and the open episode's frames detected and dropped so far."""

    queued: int
    behind_s: float
    detected: int
    dropped: int


@dataclass
class OnlineEpisode:
    """One episode's frames as detected online (see the module), by (watchtower, frame index of its folder)."""

    folder: Path
    results: dict[tuple[str, int], FrameResult | Exception] = field(default_factory=dict)
    views: dict[str, StreamView] = field(default_factory=dict)
    offered: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    max_queued: int = 0
    queued_sum: int = 0
    newest_t: float = 0.0
    detected_t: float = 0.0
    cpu_s: float = 0.0
    detected: int = 0  # frames the detector ran on (the others re-used their watchtower's unchanged view)
    ended: bool = False
    discarded: bool = False
    _pending: int = 0
    _owner: OnlineDetector | None = field(default=None, repr=False)

    def frame(self, camera: str, index: int, ref: str | bytes, t: float) -> None:
        """Frame ``index`` of watchtower ``camera`` (its file, or its bytes), at episode time ``t`` [s]; returns at
        once, queued or dropped (``runner.streams``' observer and the DTPS reader call this)."""
        if self._owner is None or self.ended:
            return
        self._owner._offer(self, camera, index, ref, t)

    def end(self) -> None:
        """No more frames: the episode ended (the queue's frames of it are still detected)."""
        self.ended = True

    def wait(self, poll: float = 0.2) -> None:
        """Until every queued frame of the episode is detected (the worker never gives up on a frame)."""
        owner = self._owner
        if owner is None:
            return
        with owner._cond:
            while self._pending and owner._alive():
                owner._cond.wait(poll)

    def frames_for(self, log: Log) -> list[FrameResult]:
        """The frames of ``log`` (this episode's streams, as read back from its folder, maybe cut short by a drill)
        as localisation takes them: a frame not in the log is left out, a dropped frame too, and a frame that failed
        raises its error (as offline detection would)."""
        self.wait()
        out: list[FrameResult] = []
        for k, s in enumerate(log.streams):
            for fr in s.frames:
                if isinstance(fr.ref, bytes):
                    raise ValueError(f"{fr.label}: online detection reads folder logs (frames as files), not bags")
                got = self.results.get((s.name, int(Path(fr.ref).stem)))
                if isinstance(got, Exception):
                    raise got
                if got is not None:
                    out.append(replace(got, stream=k, t=fr.t))
        return out

    def report(self) -> dict[str, Any]:
        """What the online detection did: frames offered, detected (the detector ran), dropped per watchtower,
        the most and the mean frames queued when a frame was offered, its CPU [s] (the worker thread's)."""
        done = sum(isinstance(r, FrameResult) for r in self.results.values())
        return {"frames": self.offered, "detected": self.detected, "localised": done,
                "dropped": dict(sorted(self.dropped.items())), "max_queued": self.max_queued,
                "mean_queued": round(self.queued_sum / self.offered, 2) if self.offered else 0.0,
                "cpu_s": round(self.cpu_s, 3)}


class OnlineDetector:
    """The worker and its bounded queue (see the module). ``begin(folder)`` opens an episode (several may be open:
    a batch of robots in one world); the worker starts with the first frame and ends at :meth:`close`, after the
    frames queued before it. ``detector``: a :class:`.detect.Detector` kind, or an object with ``detect(gray)``."""

    def __init__(self, detector: str | Any = "apriltag", decimate: float = 2.0, *, max_queue: int = MAX_QUEUE,
                 reuse: bool = True, report: Callable[[Lag], None] | None = None, every: float = 5.0):
        if max_queue < 1:
            raise ValueError(f"max_queue must be at least 1, got {max_queue}")
        self._kind, self._decimate = detector, decimate
        self.reuse, self.report, self.every = reuse, report, every
        self._queue: queue.Queue = queue.Queue(max_queue)
        self._cond = threading.Condition()
        self._episodes: dict[str, OnlineEpisode] = {}
        self._thread: threading.Thread | None = None
        self._closed = False
        self._last_report = time.monotonic()
        self._latest: OnlineEpisode | None = None

    def begin(self, folder: str | Path) -> OnlineEpisode:
        """A new episode whose streams are written into ``folder`` (one opened again for the same folder replaces
        it: a retried episode's frames are the new ones)."""
        key = str(Path(folder).resolve())
        ep = OnlineEpisode(Path(folder), _owner=self)
        with self._cond:
            old = self._episodes.get(key)
            if old is not None:
                old.discarded = True
            self._episodes[key] = ep
            self._latest = ep
        return ep

    def episode(self, folder: str | Path) -> OnlineEpisode | None:
        """The episode whose streams went into ``folder`` (None: none was observed)."""
        return self._episodes.get(str(Path(folder).resolve()))

    def lag(self) -> Lag:
        """How far behind the detection is now (the latest episode opened)."""
        ep = self._latest
        if ep is None:
            return Lag(self._queue.qsize(), 0.0, 0, 0)
        return Lag(self._queue.qsize(), max(0.0, ep.newest_t - ep.detected_t), ep.detected,
                   sum(ep.dropped.values()))

    def close(self) -> None:
        """No more episodes: the worker detects what is queued, then ends (this returns at once)."""
        with self._cond:
            self._closed, started = True, self._thread is not None
        if started:
            self._queue.put(None)  # waits only while the queue is full, which the worker is draining

    def _alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _offer(self, ep: OnlineEpisode, camera: str, index: int, ref: str | bytes, t: float) -> None:
        with self._cond:
            if self._closed:
                return
            if self._thread is None:
                self._thread = threading.Thread(target=self._work, name="online-localisation", daemon=True)
                self._thread.start()
            queued = self._queue.qsize()
            ep.offered += 1
            ep.queued_sum += queued
            ep.max_queued = max(ep.max_queued, queued)
            ep.newest_t = max(ep.newest_t, t)
            try:
                self._queue.put_nowait((ep, camera, index, ref, t))
            except queue.Full:
                ep.dropped[camera] = ep.dropped.get(camera, 0) + 1
                return
            ep._pending += 1

    def _detector(self):
        if isinstance(self._kind, str):
            self._kind = Detector(self._kind, self._decimate)
        return self._kind

    def _work(self) -> None:
        """The worker: each queued frame detected in its stream's order; an error is kept for the frame it hit."""
        while True:
            item = self._queue.get()
            if item is None:
                return
            ep, camera, index, ref, t = item
            c0 = time.thread_time()
            try:
                if not ep.discarded:
                    view = ep.views.setdefault(camera, StreamView())
                    label = ref if isinstance(ref, str) else f"{ep.folder / camera} frame {index}"
                    res = detect_frame(view, self._detector(), Frame(t, ref, label), -1, self.reuse)
                    ep.results[(camera, index)] = res
                    ep.detected += res.detected
            except Exception as exc:  # kept for the frame, raised by frames_for as offline detection would
                ep.results[(camera, index)] = exc
            ep.cpu_s += time.thread_time() - c0
            with self._cond:
                ep.detected_t = max(ep.detected_t, t)
                ep._pending -= 1
                self._cond.notify_all()
            self._tell()

    def _tell(self) -> None:
        """Report the lag every ``every`` s of wall time (the evaluator logs it)."""
        now = time.monotonic()
        if self.report is None or now - self._last_report < self.every:
            return
        self._last_report = now
        with contextlib.suppress(Exception):  # a failing report must not stop the detection
            self.report(self.lag())
