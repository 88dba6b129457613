"""A lab description, ``lab.yaml`` (``proxybench-lab/1``): what an Autolab evaluator drives and watches.

Strict: an unknown key is an error naming it, and so is a value of the wrong kind; paths are relative to the
file's folder and made absolute when it is read, so that the description can travel to an evaluator's worker
as it is. See docs/autolab.md ("A lab") for an example::

    format: proxybench-lab/1
    name: home-lab
    map: loop_3x3
    robots:
      - {name: db1, virtual: true}                  # a virtual DB21J (the simulator), or
      # - {name: db2, dtps: 192.168.1.20/db2}       # a DTPS robot, or
      # - {name: db3, command: python3 bridge.py}   # a robot node (robot protocol)
    watchtowers:
      layout: auto                                  # a layout file (docs/autolab.md) or auto: simulated towers
      # serve: dtps                                 # simulated towers served as DTPS camera topics, read back
      # streams:                                    # or a lab's own, each with its ROS camera_info calibration
      #   - {name: wt01, dtps: 192.168.1.31/wt01, calibration: cal/wt01.yaml}
      #   - {name: wt02, recorded: rec/wt02, calibration: cal/wt02.yaml}
    reset: {mode: teleport}                         # operator | teleport (virtual robots) | pose_file (+ poses)
    # world: shared                                 # the virtual robots share one floor (default own: one each)
    # operator: {folder: lab.operator, timeout_s: 600}      # where a person confirms placements, intervenes
    limits: {lost_s: 1.0, light_change: 0.2, end_slack_s: 1.0, max_episode_s: 120}
    # drills: {streams_stop_s: 1.5, streams_stop: [wt01], streams_stop_attempts: 1}   # faults played on purpose

The watchtower layout is the existing layout model (:mod:`.watchtowers`); a calibration is the existing
calibration file (:mod:`.calibration`: intrinsics as ROS's ``camera_info`` writes them, extrinsics in the map
frame).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

from proxybench.autolab.watchtowers import GroundTag, Layout, LayoutError, read_model, resolve_layout
from proxybench.domain.apriltags import CODES, ROOF_TAG_BASE
from proxybench.untrusted import repeated

if TYPE_CHECKING:
    from proxybench.autolab.validate import Thresholds

__all__ = ["LAB_FORMAT", "Drills", "Lab", "LabError", "LabLimits", "LabOperator", "LabRobot", "LabWatchtowers", "Reset",
           "StreamSource", "check_lab", "load_lab"]

LAB_FORMAT = "proxybench-lab/1"
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


class LabError(LayoutError):
    """A lab description that cannot be used; the message names the file and the field at fault."""


def _plain_name(v: str) -> str:
    """A robot's or watchtower's name becomes a folder name: one plain path component."""
    if not _NAME.match(v) or v in (".", ".."):
        raise ValueError(f"{v!r}: a name is 1 to 64 letters, digits, '_', '-' or '.' (it names a folder)")
    return v


def _dtps_address(v: str) -> str:
    from proxybench.dtps.robot_options import parse_address

    parse_address(v)  # a ValueError saying what is wrong
    return v


#: a lab's, robot's or watchtower's name (:func:`_plain_name`)
PlainName = Annotated[str, AfterValidator(_plain_name)]
#: a DTPS robot's or camera's address, ``HOST[:PORT]/PATH`` (``dtps.robot_options.parse_address``)
DtpsAddress = Annotated[str, AfterValidator(_dtps_address)]


class LabRobot(BaseModel):
    """One robot of the lab: exactly one of ``virtual`` (a virtual DB21J: the simulator behind DTPS), ``dtps``
    (a DTPS robot, ``HOST[:PORT]/PATH``) and ``command`` (a robot node speaking the robot protocol); ``roof_tag``:
    the AprilTag id on its roof (default 400 + its index in ``robots``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: PlainName
    virtual: bool = False
    dtps: DtpsAddress | None = None
    command: str | None = Field(None, min_length=1)
    roof_tag: int | None = Field(None, ge=0, lt=len(CODES))

    @model_validator(mode="after")
    def _one_kind(self) -> LabRobot:
        kinds = [k for k, on in (("virtual", self.virtual), ("dtps", self.dtps is not None),
                                 ("command", self.command is not None)) if on]
        if len(kinds) != 1:
            raise ValueError(f"robot {self.name!r}: give exactly one of virtual: true, dtps: ADDRESS, command: CMD "
                             f"(got {', '.join(kinds) or 'none'})")
        return self

    @property
    def kind(self) -> Literal["virtual", "dtps", "command"]:
        return "virtual" if self.virtual else "dtps" if self.dtps is not None else "command"


class StreamSource(BaseModel):
    """A lab's own watchtower: its images from a DTPS camera topic (``dtps``) or a recorded folder
    (``recorded``: ``timestamps.csv`` and frames, as docs/autolab.md's logs), and its ``calibration`` file."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: PlainName
    dtps: DtpsAddress | None = None  # the camera topic is PATH/sensor/camera/front_center/jpeg
    recorded: Path | None = None
    calibration: Path

    @model_validator(mode="after")
    def _one_source(self) -> StreamSource:
        if (self.dtps is None) == (self.recorded is None):
            raise ValueError(f"watchtower {self.name!r}: give exactly one of dtps: TOPIC, recorded: FOLDER")
        return self


class LabWatchtowers(BaseModel):
    """The lab's watchtowers: a ``layout`` file (or ``auto``: generated for the map), simulated, or ``streams``
    of its own cameras with ``ground_tags`` (its calibration tags on the floor). ``serve``: how the simulated
    watchtowers' frames reach localisation: ``files`` (written by the simulator) or ``dtps`` (served as DTPS camera
    topics and read back by the lab's reader, as a lab's own streams are: :mod:`.live`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    layout: str | None = None
    serve: Literal["files", "dtps"] = "files"
    streams: list[StreamSource] = Field(default_factory=list)
    ground_tags: list[GroundTag] = Field(default_factory=list)

    @model_validator(mode="after")
    def _one_source(self) -> LabWatchtowers:
        if (self.layout is None) == (not self.streams):
            raise ValueError("give exactly one of layout: FILE|auto (simulated watchtowers) and streams: [...]")
        if self.serve != "files" and self.layout is None:
            raise ValueError("serve: only simulated watchtowers (layout) are served; streams are a lab's own")
        if self.layout is not None and self.ground_tags:
            raise ValueError("ground_tags: a layout file holds its own ground tags; give them there")
        dup = repeated(s.name for s in self.streams)
        if dup:
            raise ValueError(f"streams: the name(s) {', '.join(dup)} are used twice")
        return self


class Reset(BaseModel):
    """How a robot is put at an episode's start: ``operator`` (a person places it and confirms), ``teleport``
    (virtual robots only: the simulator puts it there), ``pose_file`` (``poses``: start poses per episode,
    as ``--start-poses`` of DTPS targets reads them, replacing the benchmark's)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    mode: Literal["operator", "teleport", "pose_file"] = "teleport"
    poses: Path | None = None

    @model_validator(mode="after")
    def _poses(self) -> Reset:
        if (self.mode == "pose_file") != (self.poses is not None):
            raise ValueError("poses: give a file exactly when mode is pose_file")
        return self


class LabOperator(BaseModel):
    """The lab's operator, for robots no program can place or stop (``reset.mode: operator``, interventions):
    ``folder`` is where the evaluator asks and the operator answers (``proxybench autolab ready`` / ``intervene``:
    :mod:`.operator`; default ``<name>.operator`` beside ``lab.yaml``); ``timeout_s``: how long a placement may
    wait for its confirmation before the job ends as the lab's fault."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    folder: Path | None = None
    timeout_s: float = Field(600.0, gt=0.0, le=86400.0)


class LabLimits(BaseModel):
    """What the lab accepts: a run is invalid when the robot is unseen longer than ``lost_s`` [s], the light
    changes more than ``light_change`` (relative) or the recording ends ``end_slack_s`` [s] early (the DTA's
    validation); episodes longer than ``max_episode_s`` [s] are refused."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    lost_s: float = Field(1.0, gt=0.0, le=60.0)
    light_change: float = Field(0.2, gt=0.0, le=10.0)
    end_slack_s: float = Field(1.0, ge=0.0, le=60.0)
    max_episode_s: float = Field(120.0, gt=0.0, le=3600.0)

    def thresholds(self) -> Thresholds:
        """The DTA's validation thresholds of this lab (validate imports the detector: loaded when needed)."""
        from proxybench.autolab.validate import Thresholds

        return Thresholds(self.lost_s, self.light_change, self.end_slack_s)


class Drills(BaseModel):
    """Faults a lab plays on purpose, so that its operators (and tests) see how its evaluator handles them:
    ``streams_stop_s``: the watchtowers named in ``streams_stop`` (default: all) deliver no frame after this episode
    time [s], as a camera whose network or driver stopped mid-episode (simulated watchtowers' recordings, and a lab's
    own streams as the evaluator recorded them: the cameras themselves run on);
    ``streams_stop_attempts``: only in the first this many attempts at each episode (default: every attempt), so
    that a run made invalid is valid when the benchmark's ``invalid_retries`` runs it again."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    streams_stop_s: float | None = Field(None, gt=0.0, le=3600.0)
    streams_stop: list[str] = Field(default_factory=list)
    streams_stop_attempts: int | None = Field(None, ge=1, le=100)

    @model_validator(mode="after")
    def _named(self) -> Drills:
        if self.streams_stop and self.streams_stop_s is None:
            raise ValueError("streams_stop: give streams_stop_s, the time they stop")
        if self.streams_stop_attempts is not None and self.streams_stop_s is None:
            raise ValueError("streams_stop_attempts: give streams_stop_s, the time they stop")
        return self

    def stops_streams(self, attempt: int) -> bool:
        """Whether the streams stop in this attempt (1: the first run) at an episode."""
        return self.streams_stop_s is not None and (self.streams_stop_attempts is None
                                                    or attempt <= self.streams_stop_attempts)


class Lab(BaseModel):
    """A lab: its map, robots, watchtowers, how robots are reset and its limits (see the module)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: Literal["proxybench-lab/1"] = LAB_FORMAT
    name: PlainName = "lab"
    map: str
    robots: list[LabRobot] = Field(min_length=1, max_length=64)
    watchtowers: LabWatchtowers
    reset: Reset = Reset()
    operator: LabOperator = LabOperator()
    limits: LabLimits = LabLimits()
    drills: Drills = Drills()
    #: ``shared``: the lab's virtual robots share one world (they see and can hit each other; runner.lab_world);
    #: ``own``: each robot is the ego of a world of its own (the default)
    world: Literal["own", "shared"] = "own"

    @model_validator(mode="after")
    def _consistent(self) -> Lab:
        dup = repeated(r.name for r in self.robots)
        if dup:
            raise ValueError(f"robots: the name(s) {', '.join(dup)} are used twice")
        tags = list(self.roof_tags())
        dup_tags = repeated(tags)
        if dup_tags:
            raise ValueError(f"robots: roof tag id(s) {', '.join(map(str, dup_tags))} are used twice")
        clash = sorted(set(tags) & {g.id for g in self.watchtowers.ground_tags})
        if clash:
            raise ValueError(f"robots: roof tag id(s) {', '.join(map(str, clash))} are also ground tags")
        if self.watchtowers.layout is None:  # a layout's names are checked against it (check_lab: it needs the map)
            unknown = sorted(set(self.drills.streams_stop) - {s.name for s in self.watchtowers.streams})
            if unknown:
                raise ValueError(f"drills.streams_stop: no watchtower {', '.join(map(repr, unknown))} in "
                                 "watchtowers.streams")
        if self.world == "shared" and self.watchtowers.layout is None:
            raise ValueError("world: a shared world's watchtowers are simulated: give watchtowers.layout")
        if self.world == "shared" and self.watchtowers.serve != "files":
            # the shared world's server records every tower itself; serving them as well would localise from
            # a second, per-robot copy of the towers that sees only one robot
            raise ValueError("world: a shared world's watchtowers are written by its own server: "
                             "watchtowers.serve must be files (the default), not dtps")
        if self.reset.mode == "teleport":
            real = [r.name for r in self.robots if not r.virtual]
            if real:
                raise ValueError(f"reset: teleport moves virtual robots only; robot(s) {', '.join(real)} are not "
                                 "(use operator or pose_file)")
        return self

    def roof_tags(self) -> dict[int, str]:
        """Roof tag id -> robot name (a robot without ``roof_tag``: 400 + its index)."""
        return {(r.roof_tag if r.roof_tag is not None else ROOF_TAG_BASE + k): r.name
                for k, r in enumerate(self.robots)}

    def robot(self, name: str | None = None) -> LabRobot:
        """The named robot, or the first."""
        if name is None:
            return self.robots[0]
        for r in self.robots:
            if r.name == name:
                return r
        raise KeyError(f"lab {self.name!r} has no robot {name!r} (it has {', '.join(r.name for r in self.robots)})")

    def layout(self, m) -> Layout:
        """The simulated watchtowers' layout on map ``m`` (a layout made for another map is refused), with this
        lab's robots' roof tags."""
        if self.watchtowers.layout is None:
            raise LabError(f"lab {self.name!r}: its watchtowers are streams of its own, not a simulated layout")
        layout = resolve_layout(self.watchtowers.layout, m)
        try:  # the layout's checks again, with this lab's roof tags (one may clash with a ground tag)
            return Layout.model_validate({**layout.model_dump(), "robots": self.roof_tags()})
        except ValueError as exc:
            raise LabError(f"robots: {' '.join(str(exc).split())}") from None


def _absolute(value: Path | str | None, base: Path) -> Path | None:
    if value is None:
        return None
    p = Path(value).expanduser()
    return p if p.is_absolute() else (base / p)


def load_lab(path: str | Path) -> Lab:
    """Read ``lab.yaml`` (bounded, strict) with its paths made absolute; :class:`LabError` naming the file and the
    field otherwise."""
    path = Path(path)
    try:
        lab = read_model(path, Lab, LAB_FORMAT)
    except LabError:
        raise
    except LayoutError as exc:
        raise LabError(str(exc)) from None
    base = path.resolve().parent
    w = lab.watchtowers
    layout = w.layout if w.layout in (None, "auto") else str(_absolute(w.layout, base))
    streams = [s.model_copy(update={"recorded": _absolute(s.recorded, base),
                                    "calibration": _absolute(s.calibration, base)}) for s in w.streams]
    reset = lab.reset.model_copy(update={"poses": _absolute(lab.reset.poses, base)})
    operator = lab.operator.model_copy(update={"folder": _absolute(lab.operator.folder, base)
                                               or base / f"{lab.name}.operator"})
    return lab.model_copy(update={"watchtowers": w.model_copy(update={"layout": layout, "streams": streams}),
                                  "reset": reset, "operator": operator})


def check_lab(lab: Lab, origin: str = "lab.yaml") -> list[str]:
    """What the lab's files say, one line each; :class:`LabError` naming the file and field at fault: the map
    loads, the layout is for it, every calibration and recorded folder is there, the pose file reads."""
    from proxybench.autolab.calibration import load_calibration
    from proxybench.domain.maps import MapError, load_map

    lines = []
    try:
        m = load_map(lab.map)
    except (MapError, FileNotFoundError, ValueError) as exc:
        raise LabError(f"{origin}: map: {exc}") from None
    lines.append(f"map {m.name}: {m.width} × {m.height} tiles")
    kinds = ", ".join(f"{r.name} ({r.kind}, roof tag {tag})" for tag, r in
                      zip(lab.roof_tags(), lab.robots, strict=True))
    lines.append(f"robots: {kinds}")
    if lab.watchtowers.layout is not None:
        try:
            layout = lab.layout(m)
        except LayoutError as exc:
            raise LabError(f"{origin}: watchtowers.layout: {exc}") from None
        lines.append(f"watchtowers: {len(layout.watchtowers)} simulated ({lab.watchtowers.layout}), "
                     f"{len(layout.ground_tags)} ground tags"
                     + (", served as DTPS camera topics" if lab.watchtowers.serve == "dtps" else ""))
        unknown = sorted(set(lab.drills.streams_stop) - {w.name for w in layout.watchtowers})
        if unknown:
            raise LabError(f"{origin}: drills.streams_stop: no watchtower {', '.join(map(repr, unknown))} in the "
                           "layout")
    for s in lab.watchtowers.streams:
        try:
            load_calibration(s.calibration)
        except LayoutError as exc:
            raise LabError(f"{origin}: watchtowers.streams[{s.name}].calibration: {exc}") from None
        if s.recorded is not None and not (s.recorded / "timestamps.csv").is_file():
            raise LabError(f"{origin}: watchtowers.streams[{s.name}].recorded: {s.recorded} holds no timestamps.csv")
        lines.append(f"watchtower {s.name}: {'DTPS ' + s.dtps if s.dtps else f'recorded {s.recorded}'}, calibrated")
    if lab.drills.streams_stop_s is not None:
        which = ", ".join(lab.drills.streams_stop) or "all"
        first = lab.drills.streams_stop_attempts
        lines.append(f"drill: watchtower stream(s) {which} stop at t = {lab.drills.streams_stop_s:g} s"
                     + ("" if first is None else f" in the first {first} attempt(s) at each episode"))
    if lab.reset.poses is not None:
        from proxybench.dtps.robot_options import load_start_poses

        try:
            load_start_poses(lab.reset.poses, [])
        except ValueError as exc:
            raise LabError(f"{origin}: reset.poses: {exc}") from None
    lines.append(f"reset: {lab.reset.mode}; limits: lost {lab.limits.lost_s:g} s, light change "
                 f"{100 * lab.limits.light_change:.0f} %, episodes ≤ {lab.limits.max_episode_s:g} s")
    return lines
