"""A lab's watchtowers read over DTPS while its episodes run: simulated ones served as a real lab's, or a lab's own.

``lab.yaml`` says where a lab's watchtower images come from (:mod:`.lab`):

- ``watchtowers: {layout: …, serve: dtps}``: the simulated watchtowers are **served** as DTPS camera topics
  (:class:`~proxybench.dtps.cameras.WatchtowerServer`, one server on a free port of 127.0.0.1, each watchtower's
  ``parameters`` its drawn calibration's intrinsics) and read back by the lab's reader, exactly as a lab's own;
- ``watchtowers: {streams: [{name, dtps: HOST[:PORT]/PATH, calibration}]}``: a lab's own cameras, read by the same
  reader from ``PATH/sensor/camera/front_center/jpeg``.

Either way :func:`live_streams` gives the runner a ``StreamSpec`` whose sink (:class:`DtpsSink`) opens the reader's
episode when an episode's stream recorder starts and closes it when it ends, so each episode's ``JobResult.streams``
is the folder the reader wrote: what localisation reads. Simulated watchtowers stamp their frames with a clock
that started at the episode's wall-clock start plus the episode time (and each watchtower's drawn clock error);
the reader takes that start as the episode's clock origin. A lab's own watchtowers stamp with their own clocks, and
the origin is the wall clock when the episode's recording began.

With an :class:`~.online.OnlineDetector` (``live_streams(…, online)``) each frame the reader writes is also queued
for detection as it arrives (:mod:`.online`), so that at an episode's end only its pose graph is left.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

from proxybench.autolab.calibration import draw_calibrations, load_calibration, stream_spec
from proxybench.autolab.lab import Lab
from proxybench.autolab.logs import LogManifest, write_log_manifest
from proxybench.autolab.online import OnlineDetector, OnlineEpisode
from proxybench.autolab.watchtowers import Layout, ground_objects
from proxybench.dtps.cameras import EpisodeStreams, WatchtowerReader, WatchtowerServer, camera_source

__all__ = ["DtpsSink", "LiveStreams", "live_streams", "write_stream_log"]


@dataclass
class DtpsSink:
    """The runner's stream sink for watchtowers read over DTPS (see the module): one episode at a time."""

    reader: WatchtowerReader
    server: WatchtowerServer | None = None
    kind: str = "dtps"
    episodes: list[EpisodeStreams] = field(default_factory=list)
    online: OnlineDetector | None = None  # detects each frame the reader writes, as it arrives (autolab.online)
    _origin: float | None = None
    _online_episode: OnlineEpisode | None = None

    def begin(self, out: Path) -> None:
        self._origin = time.time()
        if self.server is not None:
            self.server.take_counts()  # frames of an episode that failed before its end are not this one's
        ep = self._online_episode = self.online.begin(out) if self.online is not None else None
        self.reader.begin(out, self._origin, on_frame=ep.frame if ep is not None else None)

    def frame(self, camera: str, jpeg: bytes, stamp: float, t: float) -> None:
        if self.server is None or self._origin is None:
            raise RuntimeError(f"watchtower {camera}: a frame to publish, but no simulated watchtowers are served")
        self.server.publish(camera, jpeg, self._origin + stamp, t)

    def end(self) -> None:
        result = self.reader.end(self.server.take_counts() if self.server is not None else None)
        if self._online_episode is not None:
            self._online_episode.end()
            self._online_episode = None
        self._origin = None
        (result.folder / "reader.json").write_text(json.dumps(result.report(), sort_keys=True) + "\n")
        self.episodes.append(result)


@dataclass
class LiveStreams:
    """What :func:`live_streams` started: the runner's spec (its sink), and the processes to close."""

    spec: object
    sink: DtpsSink
    names: list[str]

    def close(self) -> None:
        try:
            self.sink.reader.close()
        finally:
            if self.sink.server is not None:
                self.sink.server.close()

    def __enter__(self) -> LiveStreams:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _served(layout: Layout, port: int | None = None) -> tuple[WatchtowerServer, list]:
    """The layout's simulated watchtowers served over DTPS (on ``port`` of 127.0.0.1, None: a free one), each with
    its calibration's intrinsics published."""
    cals, _ = draw_calibrations(layout)
    server = WatchtowerServer([w.name for w in layout.watchtowers], port=port)
    try:
        sources = []
        for w in layout.watchtowers:
            cal = cals[w.name]
            fov = 2 * math.atan(math.hypot(cal.image_width, cal.image_height) / 2 / cal.camera_matrix.data[0])
            server.info(w.name, width=cal.image_width, height=cal.image_height, fov=fov, frequency=w.frame_rate,
                        K=list(cal.camera_matrix.data), D=list(cal.distortion_coefficients.data),
                        distortion_model="plumb_bob" if cal.distortion_model == "none" else cal.distortion_model)
            sources.append(camera_source(w.name, server.address(w.name), cal.image_width, cal.image_height))
    except BaseException:
        server.close()
        raise
    return server, sources


def live_streams(lab: Lab, layout: Layout | None, online: OnlineDetector | None = None) -> LiveStreams | None:
    """The lab's watchtowers read over DTPS (see the module), or None where they are recorded as files (a layout
    without ``serve: dtps``). ``layout``: the lab's simulated layout on its map (None: the lab's own streams);
    ``online``: detects each frame read as it arrives (:mod:`.online`)."""
    from proxybench.runner.streams import StreamSpec

    w = lab.watchtowers
    if layout is not None:
        if w.serve != "dtps":
            return None
        server, sources = _served(layout)
        try:
            reader = WatchtowerReader(sources)
        except BaseException:
            server.close()
            raise
        sink = DtpsSink(reader, server, online=online)
        base = stream_spec(layout)
        spec = StreamSpec(base.cameras, base.rates, base.clock_offsets, base.fixtures, sink=sink)
        return LiveStreams(spec, sink, [s.name for s in sources])
    sources = []
    for s in w.streams:
        if s.dtps is None:
            raise ValueError(f"watchtower {s.name}: a recorded folder is not read live; give dtps: HOST[:PORT]/PATH")
        cal = load_calibration(s.calibration)
        sources.append(camera_source(s.name, s.dtps, cal.image_width, cal.image_height))
    sink = DtpsSink(WatchtowerReader(sources), online=online)
    fixtures = ground_objects(Layout.model_construct(ground_tags=list(w.ground_tags)))
    return LiveStreams(StreamSpec((), (), (), fixtures, sink=sink), sink, [s.name for s in sources])


def write_stream_log(root: str | Path, lab: Lab, streams: str | Path, manifest: LogManifest) -> Path:
    """Make ``root`` a log of a run recorded from the lab's own streams: move them to ``root/watchtowers`` and put
    each watchtower's calibration file (the lab's) beside its frames, and the manifest with the lab's ground tags."""
    root, streams = Path(root), Path(streams)
    towers = root / "watchtowers"
    if streams.resolve() != towers.resolve():
        if towers.exists():
            shutil.rmtree(towers)
        shutil.move(str(streams), str(towers))
    for s in lab.watchtowers.streams:
        if (towers / s.name).is_dir():
            shutil.copyfile(s.calibration, towers / s.name / "calibration.yaml")
    update = {"ground_tags": list(lab.watchtowers.ground_tags), "robots": manifest.robots or lab.roof_tags()}
    return write_log_manifest(root, manifest.model_copy(update=update))
