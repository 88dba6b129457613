"""The ``objects:`` of a map file, in every placement the Duckietown maps use, as map-frame poses.

A map object is placed in one of four ways (duckietown-world's ``get_transform`` reads the same keys):

- ``pos: [x, y]`` and ``rotate`` [deg]: gym-duckietown's, in tiles east and *down* the ``tiles:`` listing
  (the original gym-duckietown placement; duckietown-world-daffy puts these one tile lower, a known quirk
  of its row count, which proxybench does not copy);
- ``pose: {~SE2Transform: {p: [x, y], theta_deg: a}}``: metres in the map frame (x east, y north from the
  south-west corner), heading in degrees counter-clockwise (``theta`` in radians also works);
- ``place: {tile: [i, j], relative: {~SE2Transform: ...}}``: metres from the centre of tile (i, j), with j
  counted from the *bottom* row (duckietown-world's tile coordinates); the offset is not turned with the tile;
- ``attach: {tile: [i, j], slot: 0..7}``: one of the eight sign slots around the south-west corner of tile
  (i, j) (duckietown-world's ``get_xy_slot``), heading from ``rotate`` or from a ``pose`` without ``p``
  (the robotarium maps write it so; duckietown-world itself would put those signs at the map's origin).

Kinds: every kind the duckietown-world maps use has a shape (``proxybench.domain.objects``); others are
drawn as a grey box, with one warning per kind, never an error. ``tag: {~TagInstance: {family, tag_id,
size}}`` is kept (``floor_tag`` objects are AprilTags lying on the floor). Problems repeated over many
objects are reported once, with how many objects share them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import yaml

__all__ = ["KNOWN_KINDS", "SIGN_SLOTS", "AprilTag", "ObjectIssue", "object_family", "parse_objects"]

#: kinds with a shape of their own (any ``sign*`` kind and ``duckie*`` other than ``duckiebot`` too)
KNOWN_KINDS = (
    "duckie", "duckiebot", "cone", "barrier", "house", "building", "tree", "bus", "truck",
    "trafficlight", "floor_tag", "checkerboard",
)

#: duckietown-world's sign slots, in tiles from the south-west corner of the tile named by ``attach``
SIGN_SLOTS = {
    0: (0.09, 0.035), 1: (0.035, 0.09), 2: (-0.035, 0.09), 3: (-0.09, 0.035),
    4: (-0.09, -0.035), 5: (-0.035, -0.09), 6: (0.035, -0.09), 7: (0.09, -0.035),
}
_PLACEMENTS = ("pos", "pose", "place", "attach")
_NUM = (int, float)


def object_family(kind: str) -> str | None:
    """The shape family of an object kind (``'sign'`` for every sign), or None for an unknown kind."""
    k = kind.lower()
    if k.startswith("sign"):
        return "sign"
    if k.startswith("duckie") and k != "duckiebot":
        return "duckie"
    return k if k in KNOWN_KINDS else None


@dataclass(frozen=True)
class AprilTag:
    """An AprilTag printed on an object (duckietown-world's ``TagInstance``); ``size`` [m] of its black square."""

    family: str
    tag_id: int
    size: float


@dataclass(frozen=True)
class ObjectIssue:
    """A problem with one object; ``key`` groups the same problem over many objects."""

    label: str
    problem: str
    node: yaml.Node

    @property
    def key(self) -> str:
        return self.problem


@dataclass(frozen=True)
class _Placed:
    x: float
    y: float
    heading: float


def _number(v: Any) -> bool:
    return isinstance(v, _NUM) and not isinstance(v, bool) and math.isfinite(v)


def _pair(v: Any) -> bool:
    return isinstance(v, list) and len(v) == 2 and all(_number(p) for p in v)


def _se2(value: Any, what: str) -> tuple[float, float, float, bool] | str:
    """(x, y, θ [rad], has p) of ``{~SE2Transform: {p, theta_deg | theta}}`` (the tag may be left out), or an error."""
    if isinstance(value, dict) and set(value) == {"~SE2Transform"}:
        value = value["~SE2Transform"]
    if value is None:
        value = {}
    if not isinstance(value, dict):
        return f"'{what}' must be {{~SE2Transform: {{p: [x, y], theta_deg: a}}}}, got {value!r}"
    extra = sorted(set(value) - {"p", "theta", "theta_deg"})
    if extra:
        return f"'{what}' has unknown field(s) {', '.join(map(repr, extra))} (known: p, theta_deg, theta)"
    p = value.get("p", [0.0, 0.0])
    if not _pair(p):
        return f"'{what}.p' must be [x, y] in metres, got {p!r}"
    if "theta" in value and "theta_deg" in value:
        return f"'{what}' gives both 'theta' and 'theta_deg'"
    theta = value.get("theta")
    deg = value.get("theta_deg")
    for name, v in (("theta", theta), ("theta_deg", deg)):
        if v is not None and not _number(v):
            return f"'{what}.{name}' must be a number, got {v!r}"
    angle = float(theta) if theta is not None else math.radians(float(deg)) if deg is not None else 0.0
    return float(p[0]), float(p[1]), angle, "p" in value


def _tile_ref(value: Any, what: str, width: int, height: int, corner: bool = False) -> tuple[int, int] | str:
    """Tile (i, j) inside the map; with ``corner``, the grid point (i, j) (the tile's south-west corner),
    which may lie on the map's north or east edge."""
    if not (isinstance(value, list) and len(value) == 2 and all(isinstance(v, int) and not isinstance(v, bool)
                                                                 for v in value)):
        return f"'{what}' must be [i, j] (column, row from the bottom), got {value!r}"
    i, j = value
    if not (0 <= i < width + corner and 0 <= j < height + corner):
        return f"'{what}' {value} is outside the map ({width}×{height} tiles)"
    return i, j


def _place(obj: dict, ts: float, width: int, height: int) -> _Placed | str:
    """The object's map-frame pose from whichever placement it uses, or an error message."""
    rotate = obj.get("rotate", 0.0)
    if not _number(rotate):
        return f"'rotate' must be a number of degrees, got {rotate!r}"
    if "pos" in obj:
        pos = obj["pos"]
        if not (isinstance(pos, list) and len(pos) in (2, 3) and all(_number(p) for p in pos)):
            return f"'pos' must be [x, y] in tiles (y down the listing), got {pos!r}"
        return _Placed(float(pos[0]) * ts, (height - float(pos[1])) * ts, math.radians(float(rotate)))
    if "attach" in obj:
        att = obj["attach"]
        if not isinstance(att, dict) or set(att) - {"tile", "slot"} or "tile" not in att:
            return f"'attach' must be {{tile: [i, j], slot: 0-7}}, got {att!r}"
        tile = _tile_ref(att["tile"], "attach.tile", width, height, corner=True)
        if isinstance(tile, str):
            return tile
        slot = att.get("slot")
        if isinstance(slot, str) and slot.isdigit():
            slot = int(slot)
        if slot not in SIGN_SLOTS or isinstance(slot, bool):
            return f"'attach.slot' must be an integer 0-7, got {slot!r}"
        heading = math.radians(float(rotate))
        if "pose" in obj:
            se2 = _se2(obj["pose"], "pose")
            if isinstance(se2, str):
                return se2
            if se2[3]:
                return "'attach' and 'pose' with 'p' both place the object: give one of them"
            heading = se2[2]
        sx, sy = SIGN_SLOTS[slot]
        return _Placed((tile[0] + sx) * ts, (tile[1] + sy) * ts, heading)
    if "pose" in obj:
        se2 = _se2(obj["pose"], "pose")
        if isinstance(se2, str):
            return se2
        return _Placed(se2[0], se2[1], se2[2])
    if "place" in obj:
        pl = obj["place"]
        if not isinstance(pl, dict) or "tile" not in pl or set(pl) - {"tile", "relative"}:
            return f"'place' must be {{tile: [i, j], relative: {{~SE2Transform: ...}}}}, got {pl!r}"
        tile = _tile_ref(pl["tile"], "place.tile", width, height)
        if isinstance(tile, str):
            return tile
        se2 = _se2(pl.get("relative"), "place.relative")
        if isinstance(se2, str):
            return se2
        return _Placed((tile[0] + 0.5) * ts + se2[0], (tile[1] + 0.5) * ts + se2[1], se2[2])
    return ("no position: give 'pos: [x, y]' (tiles), 'pose: {~SE2Transform: {p: [x, y], theta_deg: a}}' "
            "(metres), 'place: {tile: [i, j], relative: ...}' or 'attach: {tile: [i, j], slot: n}'")


def _tag(value: Any) -> AprilTag | str:
    if isinstance(value, dict) and set(value) == {"~TagInstance"}:
        value = value["~TagInstance"]
    if not isinstance(value, dict):
        return f"'tag' must be {{~TagInstance: {{family, tag_id, size}}}}, got {value!r}"
    tag_id, size, family = value.get("tag_id"), value.get("size", 0.08), value.get("family", "36h11")
    if not isinstance(tag_id, int) or isinstance(tag_id, bool) or tag_id < 0:
        return f"'tag.tag_id' must be a non-negative integer, got {tag_id!r}"
    if not _number(size) or size <= 0:
        return f"'tag.size' must be a positive number of metres, got {size!r}"
    return AprilTag(str(family), tag_id, float(size))


def parse_objects(
    items: list[tuple[str | None, yaml.Node]], data: Callable[[yaml.Node], Any], ts: float, width: int, height: int,
    make: Callable[..., Any],
) -> tuple[list[Any], list[tuple[str, yaml.Node]], list[tuple[str, yaml.Node]]]:
    """(objects built by ``make(**fields)``, errors, warnings) for the ``objects:`` entries ``(name, node)``.

    Each error or warning is a message and the YAML node it is about. A problem shared by many objects
    (a whole map in a format this reader does not know) is one error that counts them, and an unknown
    kind one warning however many objects have it.
    """
    out: list[Any] = []
    issues: list[ObjectIssue] = []
    unknown: dict[str, list[yaml.Node]] = {}
    for idx, (name, node) in enumerate(items):
        label = f"object {name!r}" if name else f"objects[{idx}]"
        obj = data(node)
        if not isinstance(obj, dict):
            issues.append(ObjectIssue(label, "must be a mapping with 'kind' and a position", node))
            continue
        kind = obj.get("kind")
        if not isinstance(kind, str) or not kind.strip():
            issues.append(ObjectIssue(label, "missing or invalid 'kind'", node))
            continue
        placed = _place(obj, ts, width, height)
        if isinstance(placed, str):
            issues.append(ObjectIssue(label, placed, node))
            continue
        fields: dict[str, Any] = {}
        bad = False
        for key in ("height", "scale"):
            val = obj.get(key)
            if val is not None and (not _number(val) or val <= 0):
                issues.append(ObjectIssue(label, f"'{key}' must be a positive number, got {val!r}", node))
                bad = True
            fields[key] = float(val) if _number(val) else None
        if "tag" in obj:
            tag = _tag(obj["tag"])
            if isinstance(tag, str):
                issues.append(ObjectIssue(label, tag, node))
                bad = True
            else:
                fields["tag"] = tag
        if bad:
            continue
        if object_family(kind) is None:
            unknown.setdefault(kind, []).append(node)
        out.append(make(
            kind=kind, x=placed.x, y=placed.y, heading=placed.heading, optional=bool(obj.get("optional", False)),
            static=bool(obj.get("static", True)), name=name, **fields,
        ))
    warnings = [(f"unknown object kind {kind!r} ({len(nodes)} object(s)): drawn as a grey 0.1 m box that collides "
                 "like a duckie", nodes[0]) for kind, nodes in unknown.items()]
    return out, _grouped(issues), warnings


def _grouped(issues: list[ObjectIssue]) -> list[tuple[str, yaml.Node]]:
    """One message per problem, with how many more objects share it and where."""
    groups: dict[str, list[ObjectIssue]] = {}
    for iss in issues:
        groups.setdefault(iss.key, []).append(iss)
    out = []
    for group in groups.values():
        first, more = group[0], group[1:]
        extra = ""
        if more:
            lines = ", ".join(str(i.node.start_mark.line + 1) for i in more[:5])
            extra = f" (and {len(more)} more object(s) alike, at line(s) {lines}{', …' if len(more) > 5 else ''})"
        out.append((f"{first.label}: {first.problem}{extra}", first.node))
    return out
