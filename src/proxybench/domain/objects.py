"""Map objects as simple upright shapes: for the camera renderer, the top-down view and collisions.

Every ``MapObject`` becomes one or more *primitives*, each a vertical cylinder or an upright box standing
on (or floating above) the ground, flat-coloured. Supported kinds (sizes at ``scale`` 1; ``height``
from the map file, if given, rescales the object's height, and ``scale`` all of its dimensions):

============================  =================================================  ============
kind                          shape                                              collision
============================  =================================================  ============
``duckie``                    yellow cylinder, r 0.04 m, h 0.06 m                duckie-like
``cone``                      orange cylinder, r 0.05 m, h 0.10 m                duckie-like
``barrier``                   red/white box 0.50 × 0.06 m, h 0.12 m              duckie-like
``sign_*`` (any sign kind)    grey pole r 0.01 m, h 0.16 m + plate 0.10 × 0.01   duckie-like
                              × 0.08 m on top (red for stop/yield, blue else)
``duckiebot``                 dark-blue box 0.18 × 0.13 m, h 0.10 m              robot-like
``house``, ``building``       box 0.40 × 0.40 m, h 0.30 m                        duckie-like
``tree``                      green cylinder r 0.10 m, h 0.30 m                  duckie-like
``bus``, ``truck``            box 0.40 × 0.16 m, h 0.16 m                        robot-like
``trafficlight``              dark box 0.08 × 0.08 m from 0.30 to 0.40 m (the    none
                              head; its stand is beside the road in a lab)
``floor_tag``                 AprilTag on the floor: a tag36h11 with a known id   none
                              is drawn with its bit pattern (``TAG``), its black
                              square the tag's ``size``, in a white ring of one
                              cell, 1 mm high; other tags as a plain black square
``checkerboard``              grey board 0.01 × 0.30 m, h 0.25 m                 duckie-like
anything else                 grey box 0.10 × 0.10 m, h 0.10 m                   duckie-like
                              (``map check`` warns once per unknown kind)
============================  =================================================  ============

Collision rule (AIDO): a robot collides with a *duckie-like* object when its centre comes within
``DUCKIE_MARGIN`` = 0.10 m of the object's footprint (circle or rectangle; for a sign, of its pole),
and with a *robot-like* object when its centre comes within ``ROBOT_MARGIN`` = 0.15 m of the object's
centre. Map objects are static; moving ones (NPC robots, pedestrians) and per-world extras are
``proxybench.domain.npcs``, drawn from the same primitives. Duckies and duckiebots take their colours from
the domain parameters ``duckie_rgb`` and ``duckiebot_rgb`` (their *material*), everything else keeps its own.

Robots (the ego and NPC robots, drawn for the watchtowers and for each other) carry a roof tag: a
tag36h11 of ``ROOF_TAG_SIZE`` on top of their body (``robot_primitives``).

``pack_objects`` returns the arrays the compiled code reads: ``prims`` (P, PF) for rendering and
``colliders`` (M, CF) for collisions, with the column indices in ``PF_*`` / ``CF_*``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba as nb
import numpy as np

from proxybench.domain import apriltags
from proxybench.domain.map_objects import AprilTag, object_family
from proxybench.domain.maps import MapObject
from proxybench.domain.params import DUCKIE_RGB, DUCKIEBOT_RGB

__all__ = [
    "DUCKIEBOT_RGB",
    "DUCKIE_MARGIN",
    "DUCKIE_RGB",
    "MATERIAL_PARAMS",
    "ROBOT_MARGIN",
    "ROOF_TAG_Z",
    "TAG",
    "ObjectArrays",
    "Primitive",
    "collision_check",
    "object_collides",
    "object_primitives",
    "pack_objects",
    "robot_primitives",
]

DUCKIE_MARGIN = 0.10
ROBOT_MARGIN = 0.15

CYLINDER, BOX, TAG = 0, 1, 2
# primitive columns: shape, centre x, y [m], cos/sin heading, half-size a (radius or half-length along
# the heading), half-size b (half-width across), z bottom, z top [m], colour r, g, b [0..255], material.
# A TAG is a box whose top face shows an AprilTag 36h11 (``apriltags``: 10 × 10 cells over 2a × 2b); its
# colour columns hold (36-bit code, -, -)
PF_SHAPE, PF_X, PF_Y, PF_COS, PF_SIN, PF_A, PF_B, PF_Z0, PF_Z1, PF_RED, PF_GREEN, PF_BLUE, PF_MATERIAL = range(13)
PF = 13
#: materials: a primitive of material 0 keeps its own colour; the others take the colour the robot's
#: domain parameters give them (``MATERIAL_PARAMS``), so object colours can differ per robot and episode
MAT_OWN, MAT_DUCKIE, MAT_DUCKIEBOT = 0, 1, 2
MATERIAL_PARAMS = ("", "duckie_rgb", "duckiebot_rgb")
# collider columns: centre x, y, cos, sin, half-size a, half-size b (0 for a circle of radius a), margin
CF_X, CF_Y, CF_COS, CF_SIN, CF_A, CF_B, CF_MARGIN = range(7)
CF = 7


@dataclass(frozen=True)
class Primitive:
    """One upright shape in the object's own frame (x along its heading), sizes in metres."""

    shape: int
    a: float
    b: float
    z0: float
    z1: float
    rgb: tuple[float, float, float]
    dx: float = 0.0  # offset of the primitive's centre in the object frame
    dy: float = 0.0
    material: int = MAT_OWN


def _tag(tag_id: int, size: float, z: float) -> Primitive:
    """A tag36h11 marker lying flat with its top at ``z`` [m]; ``size`` [m]: its black square."""
    half = 0.5 * size * apriltags.GRID / (apriltags.GRID - 2)
    return Primitive(TAG, half, half, z - 0.0005, z, (float(apriltags.CODES[tag_id]), 0.0, 0.0))


_GREY = (150.0, 150.0, 150.0)


def _shapes(kind: str, tag: AprilTag | None = None) -> tuple[list[Primitive], bool]:
    """(primitives at scale 1, robot-like?) for an object kind."""
    family = object_family(kind)
    k = kind.lower()
    if family == "duckie":
        return [Primitive(CYLINDER, 0.04, 0.04, 0.0, 0.06, DUCKIE_RGB, material=MAT_DUCKIE)], False
    if family == "cone":
        return [Primitive(CYLINDER, 0.05, 0.05, 0.0, 0.10, (245.0, 110.0, 20.0))], False
    if family == "barrier":
        return [Primitive(BOX, 0.25, 0.03, 0.0, 0.12, (220.0, 60.0, 50.0))], False
    if family == "sign":
        plate = (200.0, 30.0, 30.0) if ("stop" in k or "yield" in k) else (40.0, 80.0, 200.0)
        return [
            Primitive(CYLINDER, 0.01, 0.01, 0.0, 0.16, _GREY),
            Primitive(BOX, 0.005, 0.05, 0.16, 0.24, plate),
        ], False
    if family == "duckiebot":
        return [Primitive(BOX, 0.09, 0.065, 0.0, 0.10, DUCKIEBOT_RGB, material=MAT_DUCKIEBOT)], True
    if family in ("house", "building"):
        return [Primitive(BOX, 0.20, 0.20, 0.0, 0.30, (190.0, 120.0, 90.0))], False
    if family == "tree":
        return [Primitive(CYLINDER, 0.10, 0.10, 0.0, 0.30, (40.0, 110.0, 40.0))], False
    if family in ("bus", "truck"):
        return [Primitive(BOX, 0.20, 0.08, 0.0, 0.16, (230.0, 170.0, 30.0))], True
    if family == "trafficlight":
        # the head only: in a lab it hangs over the intersection from a stand beside the road
        return [Primitive(BOX, 0.04, 0.04, 0.30, 0.40, (40.0, 40.0, 40.0))], False
    if family == "floor_tag":
        if tag is not None and apriltags.known(tag.family, tag.tag_id):
            return [_tag(tag.tag_id, tag.size, 0.001)], False
        # an AprilTag of unknown pattern: its black square inside a white border (tag size / 0.8)
        half = 0.5 * (tag.size if tag is not None else 0.08)
        return [
            Primitive(BOX, half / 0.8, half / 0.8, 0.0, 0.0005, (235.0, 235.0, 235.0)),
            Primitive(BOX, half, half, 0.0, 0.001, (25.0, 25.0, 25.0)),
        ], False
    if family == "checkerboard":
        # the upright intrinsic-calibration board
        return [Primitive(BOX, 0.005, 0.15, 0.0, 0.25, (120.0, 120.0, 120.0))], False
    return [Primitive(BOX, 0.05, 0.05, 0.0, 0.10, _GREY)], False


#: kinds nothing collides with: a tag lying on the floor, and a traffic light (gym-duckietown's rule too)
NON_COLLIDING = ("floor_tag", "trafficlight")


def object_collides(kind: str) -> bool:
    """Whether robots can hit an object of this kind."""
    return object_family(kind) not in NON_COLLIDING


def object_primitives(obj: MapObject) -> tuple[list[Primitive], bool]:
    """The object's primitives, scaled by ``obj.scale`` and to ``obj.height``, and whether it is robot-like."""
    prims, robot = _shapes(obj.kind, obj.tag)
    s = obj.scale or 1.0
    top = max(p.z1 for p in prims) * s
    hz = (obj.height / top) if obj.height else 1.0
    out = [
        Primitive(p.shape, p.a * s, p.b * s, p.z0 * s * hz, p.z1 * s * hz, p.rgb, p.dx * s, p.dy * s, p.material)
        for p in prims
    ]
    return out, robot


#: height of a robot's roof tag above the ground [m] (the top of its body)
ROOF_TAG_Z = 0.1005


def robot_primitives(tag_id: int) -> np.ndarray:
    """(P, PF) a Duckiebot's body and its roof tag ``tag_id`` (centred over the wheel axle) at the origin,
    heading +x: the rows of ``pack_objects``, to be moved to where the robot is."""
    parts = [*_shapes("duckiebot")[0], _tag(tag_id, apriltags.ROOF_TAG_SIZE, ROOF_TAG_Z)]
    return np.array([[q.shape, q.dx, q.dy, 1.0, 0.0, q.a, q.b, q.z0, q.z1, *q.rgb, q.material] for q in parts],
                    dtype=np.float64).reshape(-1, PF)


@dataclass(frozen=True)
class ObjectArrays:
    """Packed objects: ``prims`` (P, PF) render primitives, ``colliders`` (M, CF), ``owner`` (P,) object index."""

    prims: np.ndarray
    colliders: np.ndarray
    owner: np.ndarray


def pack_objects(objects: Sequence[MapObject]) -> ObjectArrays:
    """Arrays of every object's primitives and collision footprint (see the module docstring)."""
    prims, cols, owner = [], [], []
    for i, obj in enumerate(objects):
        parts, robot = object_primitives(obj)
        c, s = math.cos(obj.heading), math.sin(obj.heading)
        for p in parts:
            x = obj.x + c * p.dx - s * p.dy
            y = obj.y + s * p.dx + c * p.dy
            prims.append([p.shape, x, y, c, s, p.a, p.b, p.z0, p.z1, *p.rgb, p.material])
            owner.append(i)
        if not object_collides(obj.kind):
            continue
        if robot:
            cols.append([obj.x, obj.y, c, s, 0.0, 0.0, ROBOT_MARGIN])
        else:
            # the footprint is the lowest primitive (the pole of a sign, the body otherwise)
            p = min(parts, key=lambda q: q.z0)
            x = obj.x + c * p.dx - s * p.dy
            y = obj.y + s * p.dx + c * p.dy
            cols.append([x, y, c, s, p.a, p.b if p.shape == BOX else 0.0, DUCKIE_MARGIN])
    return ObjectArrays(
        np.array(prims, dtype=np.float64).reshape(-1, PF),
        np.array(cols, dtype=np.float64).reshape(-1, CF),
        np.array(owner, dtype=np.int64),
    )


@nb.njit(cache=True, inline="always")
def footprint_distance(x, y, col):
    """Distance [m] from map point (x, y) to a collider's footprint (0 inside)."""
    dx = x - col[CF_X]
    dy = y - col[CF_Y]
    if col[CF_B] <= 0.0:  # circle of radius a
        return max(math.sqrt(dx * dx + dy * dy) - col[CF_A], 0.0)
    lx = abs(col[CF_COS] * dx + col[CF_SIN] * dy) - col[CF_A]
    ly = abs(-col[CF_SIN] * dx + col[CF_COS] * dy) - col[CF_B]
    ex = max(lx, 0.0)
    ey = max(ly, 0.0)
    return math.sqrt(ex * ex + ey * ey)


@nb.njit(cache=True)
def collision_check(xy, colliders, flags):
    """Set ``flags[n]`` if any of robot n's centres ``xy[n, k, 0:2]`` touches a collider (sticky)."""
    for n in range(xy.shape[0]):
        if flags[n]:
            continue
        for k in range(xy.shape[1]):
            x = xy[n, k, 0]
            y = xy[n, k, 1]
            for m in range(colliders.shape[0]):
                if footprint_distance(x, y, colliders[m]) < colliders[m, CF_MARGIN]:
                    flags[n] = True
                    break
            if flags[n]:
                break
