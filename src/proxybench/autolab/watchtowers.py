"""Watchtower layouts: where a lab's cameras stand, the calibration tags it put down, and what it calibrated.

A **layout file** (``proxybench-watchtowers/1``, strict: an unknown key is an error naming it) describes a lab::

    format: proxybench-watchtowers/1
    map: ETHZ_autolab_technical_track       # the map it was made for (checked when given)
    watchtowers:
      - {name: wt01, position: [0.6, 0.5, 0.8], yaw: 90, pitch: 89, resolution: [640, 480], fov_y: 60,
         frame_rate: 10, noise_std: 2}
    ground_tags:                              # calibration tags on the floor, beside the map's own floor tags
      - {id: 10, x: 1.46, y: 0.29, heading: 0, size: 0.065}
    robots: {400: ego}                        # roof tag id -> robot name (default: ego 400, npc0 401, ...)
    calibration_error: {position: 0.005, angle: 0.3, focal: 0.005, principal: 1.0, clock: 0.002, seed: 0}

``yaw`` [deg] is the heading of a watchtower's optical axis on the ground, ``pitch`` [deg] its tilt below the
horizontal (≤ 89), ``roll`` [deg] about its axis; ``fov_y`` [deg] a pinhole's vertical field of view, or
``intrinsics: [fx, fy, cx, cy]`` [px] with ``distortion`` and ``lens`` for a calibrated (fisheye) lens.

In simulation the layout is the truth. Each watchtower's **calibration** (what the lab measured, and all that
``proxybench localize`` knows) is the truth plus its own error, drawn from ``calibration_error`` (the θ of the
lab's calibration: 1σ of position [m], of each angle [deg], of the focal length [relative], of the principal
point [px], of the clock [s]; ``seed``). ``auto_layout`` generates a layout that covers a map's drivable tiles
with overlapping views (every point of the road seen by at least two watchtowers) and puts a calibration tag
on every non-drivable tile beside the road, as the Autolab fixes its calibration tags to the road layer.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Literal, TypeVar

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from proxybench.domain.apriltags import CODES, FAMILY, ROOF_TAG_BASE, ROOF_TAG_SIZE
from proxybench.domain.fixed_cameras import FixedCamera
from proxybench.domain.map_objects import AprilTag
from proxybench.domain.maps import Map, MapObject
from proxybench.domain.params import check_image_size
from proxybench.untrusted import UntrustedInputError, load_yaml_file, repeated

__all__ = ["FORMAT", "MAX_YAML_BYTES", "CalibrationError", "GroundTag", "Layout", "LayoutError", "UnsafeLogError",
           "Watchtower", "auto_layout", "ground_objects", "load_layout", "read_model", "resolve_layout", "robot_names",
           "write_layout"]

FORMAT = "proxybench-watchtowers/1"
M = TypeVar("M", bound=BaseModel)
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
#: the largest layout, log.yaml or calibration file read [bytes], and how deeply it may nest
MAX_YAML_BYTES = 4 << 20
MAX_YAML_DEPTH = 16


class LayoutError(ValueError):
    """A layout or calibration that cannot be used; the message names the file and field at fault."""


class UnsafeLogError(LayoutError):
    """Input from a lab's files refused as unsafe, not merely wrong (logs come from other people's machines):
    a name that would become a path outside the output folder, a link, a FIFO or device where a file belongs,
    a file too large or too deeply nested, too many frames. ``proxybench localize`` exits with code 2."""


class Watchtower(BaseModel):
    """One watchtower: where it stands, where it looks, its lens and its frame rate."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    position: tuple[float, float, float] = Field(description="optical centre x, y, z in the map frame [m]")
    yaw: float = Field(0.0, description="heading of the optical axis on the ground [deg]")
    pitch: float = Field(89.0, ge=5.0, le=89.0, description="tilt below the horizontal [deg]")
    roll: float = Field(0.0, ge=-45.0, le=45.0, description="rotation about the optical axis [deg]")
    resolution: tuple[int, int] = Field((640, 480), description="width, height [px]")
    fov_y: float = Field(60.0, gt=5.0, lt=170.0, description="vertical field of view of a pinhole lens [deg]")
    intrinsics: tuple[float, float, float, float] | None = Field(None, description="fx, fy, cx, cy [px]")
    distortion: tuple[float, float, float, float, float] | None = None
    lens: Literal["plumb_bob", "equidistant"] = "plumb_bob"
    frame_rate: float = Field(10.0, gt=0.0, le=60.0, description="frames per second [Hz]")
    noise_std: float = Field(2.0, ge=0.0, le=64.0, description="sensor noise std [0..255]")

    @field_validator("name")
    @classmethod
    def _plain(cls, v: str) -> str:
        if not _NAME.match(v):
            raise ValueError(f"{v!r}: a watchtower name is letters, digits, '_', '-', '.' (it names a folder)")
        return v

    _size = field_validator("resolution")(check_image_size)

    def camera(self) -> FixedCamera:
        """The renderer's camera for this watchtower (where it truly is)."""
        fx, fy, cx, cy = self.intrinsics or (0.0, 0.0, 0.0, 0.0)
        return FixedCamera(self.name, *self.position, math.radians(self.yaw), self.pitch, *self.resolution,
                           fov_y=self.fov_y, roll=self.roll, fx=fx, fy=fy, cx=cx, cy=cy, distortion=self.distortion,
                           lens=self.lens, noise_std=self.noise_std)


class GroundTag(BaseModel):
    """A calibration tag the lab fixed to the floor (36h11), at (x, y) [m] with ``heading`` [deg]."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    id: int = Field(ge=0, lt=len(CODES))
    x: float
    y: float
    heading: float = 0.0
    size: float = Field(ROOF_TAG_SIZE, gt=0.0, le=1.0, description="edge of the black square [m]")


class CalibrationError(BaseModel):
    """θ of a lab's calibration: 1σ of each watchtower's error (drawn once per watchtower from ``seed``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: float = Field(0.005, ge=0.0, le=0.5, description="optical centre [m], each axis")
    angle: float = Field(0.3, ge=0.0, le=10.0, description="yaw, pitch and roll [deg], each")
    focal: float = Field(0.005, ge=0.0, le=0.2, description="focal length [relative]")
    principal: float = Field(1.0, ge=0.0, le=50.0, description="principal point [px], each axis")
    clock: float = Field(0.002, ge=0.0, le=1.0, description="clock offset [s]")
    seed: int = Field(0, ge=0)


class Layout(BaseModel):
    """A lab's watchtowers, its calibration tags, its robots' roof tags and its calibration's θ."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: Literal["proxybench-watchtowers/1"] = FORMAT
    map: str | None = None
    watchtowers: list[Watchtower] = Field(min_length=1)
    ground_tags: list[GroundTag] = Field(default_factory=list)
    robots: dict[int, str] = Field(default_factory=dict, description="roof tag id -> robot name")
    calibration_error: CalibrationError = CalibrationError()

    @model_validator(mode="after")
    def _unique(self) -> Layout:
        dup = repeated(w.name for w in self.watchtowers)
        if dup:
            raise ValueError(f"watchtowers: the name(s) {', '.join(dup)} are used twice")
        ids = [t.id for t in self.ground_tags]
        dup_ids = repeated(ids)
        if dup_ids:
            raise ValueError(f"ground_tags: tag id(s) {', '.join(map(str, dup_ids))} are placed twice")
        clash = sorted(set(ids) & set(self.robots))
        if clash:
            raise ValueError(f"robots: tag id(s) {', '.join(map(str, clash))} are also ground tags")
        return self


def read_model(path: Path, model: type[M], fmt: str, overrides: dict | None = None, missing_ok: bool = False,
               follow_links: bool = True) -> M:
    """A strict YAML file as ``model`` (``overrides``: fields given otherwise, which win); :class:`LayoutError`
    naming the file and the field otherwise. ``missing_ok``: a missing file is an empty one. Read by the
    bounded loader (:func:`proxybench.untrusted.load_yaml_file`: a regular file of at most ``MAX_YAML_BYTES``,
    nested at most ``MAX_YAML_DEPTH`` deep, a link only with ``follow_links``); a refusal is an
    :class:`UnsafeLogError`."""
    from proxybench.targets.manifest import format_errors

    data: object = {}
    if not missing_ok or os.path.lexists(path):
        if not missing_ok and not os.path.lexists(path):
            raise LayoutError(f"{path}: cannot read as YAML (no such file)")
        try:
            data = load_yaml_file(path, max_bytes=MAX_YAML_BYTES, max_depth=MAX_YAML_DEPTH,
                                  follow_links=follow_links)
        except UntrustedInputError as exc:
            raise UnsafeLogError(" ".join(str(exc).split())) from None
        data = {} if data is None else data
    if not isinstance(data, dict):
        raise LayoutError(f"{path}: expected a mapping of fields (format: {fmt}), got {type(data).__name__}")
    data.update({k: v for k, v in (overrides or {}).items() if v is not None})
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise LayoutError(format_errors(exc, str(path), model)) from None


def load_layout(path: str | Path) -> Layout:
    """Read a layout file; :class:`LayoutError` naming the file and field otherwise."""
    return read_model(Path(path), Layout, FORMAT)


def write_layout(path: str | Path, layout: Layout) -> Path:
    """Write a layout file (readable by :func:`load_layout`)."""
    path = Path(path)
    path.write_text(yaml.safe_dump(layout.model_dump(mode="json", exclude_none=True), sort_keys=False))
    return path


def ground_objects(layout: Layout) -> tuple[MapObject, ...]:
    """The layout's calibration tags as map objects (``floor_tag``), to put into the simulated world."""
    return tuple(MapObject("floor_tag", t.x, t.y, math.radians(t.heading), name=f"ground_tag_{t.id}",
                           tag=AprilTag(FAMILY, t.id, t.size)) for t in layout.ground_tags)


def robot_names(layout: Layout | None, npcs: int = 0) -> dict[int, str]:
    """Roof tag id -> robot name: the layout's, else the simulator's (ego ``ROOF_TAG_BASE``, then NPC robots)."""
    if layout is not None and layout.robots:
        return dict(layout.robots)
    return {ROOF_TAG_BASE: "ego", **{ROOF_TAG_BASE + 1 + j: f"npc{j}" for j in range(npcs)}}


def _footprint(height: float, pitch: float, fov_y: float, aspect: float) -> tuple[float, float]:
    """Ground extent (across, along) [m] a down-looking pinhole covers (pitch near 90°)."""
    half_v = math.radians(fov_y) / 2
    half_h = math.atan(math.tan(half_v) * aspect)
    return 2 * height * math.tan(half_h), 2 * height * math.tan(half_v)


#: how far neighbouring rows of generated watchtowers see the same floor [m]: a roof tag (8 cm with its white ring)
#: must lie whole in one view wherever the robot is (with 9 cm, the ETHZ technical track lost its robot for
#: 1.7 s on a seam)
SEAM = 0.25


def auto_layout(m: Map, *, height: float = 0.8, fov_y: float = 60.0, resolution: tuple[int, int] = (640, 480),
                frame_rate: float = 5.0, error: CalibrationError | None = None) -> Layout:
    """A layout covering every drivable tile of ``m`` with at least two overlapping views (see the module).

    Watchtowers look straight down (pitch 89°) from ``height`` [m], on a grid whose spacing is half a view
    across (so each road point is in two views side by side) and a view less ``SEAM`` along; only those whose view holds
    some drivable tile are kept. At 5 Hz a robot at 0.3 m/s moves 6 cm between a watchtower's frames; two
    views with unsynchronised clocks sample it about ten times a second. Calibration tags: one at the centre of
    each non-drivable tile beside the road (ids from 1, skipping the map's own floor tags).
    """
    ts = m.tile_size
    across, along = _footprint(height, 89.0, fov_y, resolution[0] / resolution[1])
    drivable = [(t.i, t.j) for t in m.drivable_tiles()]
    if not drivable:
        raise LayoutError(f"map {m.name!r} has no drivable tile: nothing to watch")
    lo = np.min(drivable, axis=0) * ts
    hi = (np.max(drivable, axis=0) + 1) * ts
    step_x, step_y = 0.5 * across * 0.95, along - SEAM
    nx = max(2, math.ceil((hi[0] - lo[0]) / step_x) + 1)
    ny = max(1, math.ceil((hi[1] - lo[1]) / step_y))
    xs = lo[0] + (hi[0] - lo[0] - (nx - 1) * step_x) / 2 + step_x * np.arange(nx)
    ys = lo[1] + (hi[1] - lo[1] - (ny - 1) * step_y) / 2 + step_y * np.arange(ny)
    towers = []
    for y in ys:
        for x in xs:
            if any(_overlaps(x, y, across / 2, along / 2, i * ts, j * ts, ts) for i, j in drivable):
                # the image's long side across x: the optical axis (image up) heads north
                towers.append(Watchtower(name=f"wt{len(towers) + 1:02d}", position=(round(float(x), 4),
                                         round(float(y), 4), height), yaw=90.0, pitch=89.0, resolution=resolution,
                                         fov_y=fov_y, frame_rate=frame_rate))
    taken = {o.tag.tag_id for o in m.objects if o.tag is not None}
    ids = (k for k in range(1, ROOF_TAG_BASE) if k not in taken)
    tags = []
    for t in m.iter_tiles():
        if t.drivable or t.kind == "empty":
            continue
        if any(m.tile(t.i + di, t.j + dj) is not None and m.tile(t.i + di, t.j + dj).drivable
               for di in (-1, 0, 1) for dj in (-1, 0, 1)):
            tags.append(GroundTag(id=next(ids), x=(t.i + 0.5) * ts, y=(t.j + 0.5) * ts))
    return Layout(map=m.name, watchtowers=towers, ground_tags=tags, calibration_error=error or CalibrationError())


def _overlaps(cx: float, cy: float, hx: float, hy: float, x0: float, y0: float, ts: float) -> bool:
    """Whether the box centred at (cx, cy) with half sizes (hx, hy) overlaps the tile at (x0, y0)."""
    return cx + hx > x0 and cx - hx < x0 + ts and cy + hy > y0 and cy - hy < y0 + ts


def resolve_layout(spec: str, m: Map) -> Layout:
    """``auto`` (the layout file beside the map file, ``<map>.watchtowers.yaml``, if there is one, else
    :func:`auto_layout`) or a layout file; a layout made for another map is refused."""
    if spec == "auto":
        beside = Path(m.path).with_suffix(".watchtowers.yaml") if m.path else None
        layout = load_layout(beside) if beside is not None and beside.is_file() else auto_layout(m)
    else:
        layout = load_layout(spec)
    if layout.map is not None and layout.map not in (m.name, m.path):
        raise LayoutError(f"{spec}: map: the layout is for {layout.map!r}, the run is on {m.name!r}")
    return layout
