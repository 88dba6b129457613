"""Cameras fixed in the map frame (a lab's watchtowers), rendered by the robots' renderer.

A ``FixedCamera`` is a camera on a pole: its optical centre at (x, y, z) [m] in the map frame, turned to
``yaw`` [rad] (the heading of its optical axis on the ground, counter-clockwise from +x) and tilted down by
``pitch`` [deg], with a pinhole or fisheye lens. It is rendered as a "robot" of the renderer standing at
(x, y, yaw) whose camera is mounted at height z, no offset, that pitch: the same kernel, textures, light and
objects as the robots' cameras (``proxybench.domain.renderer``), so what a watchtower sees is what the
simulated world is.

``FixedCameraRig.render(sim, world)`` draws every camera's view of one world of a ``Simulator``: the map and
its objects (floor tags with their bit patterns), that world's extra duckies and pedestrians, and every robot
of the world (the ego and its NPC robots) with its roof tag (``objects.robot_primitives``: the ego carries
tag ``ROOF_TAG_BASE``, NPC robot j ``ROOF_TAG_BASE + 1 + j``). Light and colours are the world's θ; each
camera adds its own sensor noise. Not motion-blurred (a watchtower's exposure is short).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from proxybench.domain.apriltags import ROOF_TAG_BASE
from proxybench.domain.objects import PF_COS, PF_SIN, PF_X, PF_Y, robot_primitives
from proxybench.domain.params import DomainParams
from proxybench.domain.renderer import Renderer

__all__ = ["FixedCamera", "FixedCameraRig", "robot_tag_id"]

#: how far from a fixed camera objects are drawn [m] (a watchtower sees the whole of its view)
FIXED_RANGE = 12.0


def robot_tag_id(npc: int | None = None) -> int:
    """The roof tag of a world's ego robot (``npc=None``) or of its NPC robot ``npc``."""
    return ROOF_TAG_BASE if npc is None else ROOF_TAG_BASE + 1 + npc


@dataclass(frozen=True)
class FixedCamera:
    """A camera fixed in the map frame. Lengths [m], ``yaw`` [rad], ``pitch``/``roll`` [deg], sizes [px].

    ``fx, fy, cx, cy`` (all 0: a pinhole of ``fov_y`` [deg]) and ``distortion`` (plumb-bob k1, k2, p1, p2, k3,
    or equidistant k1..k4 with ``lens``) at this resolution. ``noise_std`` [0..255]: sensor noise.
    """

    name: str
    x: float
    y: float
    z: float
    yaw: float
    pitch: float
    width: int
    height: int
    fov_y: float = 75.0
    roll: float = 0.0
    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0
    distortion: tuple[float, float, float, float, float] | None = None
    lens: str = "plumb_bob"
    noise_std: float = 0.0

    def params(self, world: DomainParams) -> DomainParams:
        """θ to render this camera with in a world of θ ``world`` (its light and colours, this lens)."""
        lens: dict = {"fisheye": False, "camera_fov_y": self.fov_y}
        if self.fx > 0.0:
            # the renderer's calibrated lens is given at 640×480 and scaled to the image: scale it back
            sx, sy = 640.0 / self.width, 480.0 / self.height
            lens = {"fisheye": True, "intrinsics": (self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy),
                    "distortion": self.distortion or (0.0, 0.0, 0.0, 0.0, 0.0), "lens_model": self.lens}
        return world.replace(
            image_width=self.width, image_height=self.height, camera_pitch=self.pitch, camera_height=self.z,
            camera_forward=0.0, camera_yaw=0.0, camera_roll=self.roll, blur_time=0.0, noise_std=self.noise_std,
            vignetting=0.0, **lens)

    def intrinsics(self) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) [px] of this camera (a pinhole's from its field of view)."""
        if self.fx > 0.0:
            return self.fx, self.fy, self.cx, self.cy
        f = 0.5 * self.height / math.tan(math.radians(self.fov_y) / 2)
        return f, f, 0.5 * self.width, 0.5 * self.height


class FixedCameraRig:
    """Renders the views of fixed cameras into the worlds of a simulator (see the module docstring).

    Cameras of one image size share a renderer; ``render`` returns every camera's frame in ``cameras`` order.
    """

    def __init__(self, sim, cameras: tuple[FixedCamera, ...] | list[FixedCamera]):
        if not cameras:
            raise ValueError("a fixed-camera rig needs at least one camera")
        self.sim = sim
        self.cameras = tuple(cameras)
        self._world_params: list[DomainParams | None] = [None] * sim.n
        sizes: dict[tuple[int, int], list[int]] = {}
        for i, c in enumerate(self.cameras):
            sizes.setdefault((c.width, c.height), []).append(i)
        first = sim.params[0]
        self._groups = [(idx, Renderer(sim.arrays, [self.cameras[i].params(first) for i in idx], sim.objects,
                                       object_range=FIXED_RANGE)) for idx in sizes.values()]
        self._params_of: DomainParams = first
        self._poses = {id(r): np.array([[[self.cameras[i].x, self.cameras[i].y, self.cameras[i].yaw]] for i in idx])
                       for idx, r in self._groups}
        self._seeds = np.array([hash((c.name, c.x, c.y)) & 0x7FFFFFFF for c in self.cameras], dtype=np.uint64)
        self._templates: dict[int, np.ndarray] = {}  # a robot's primitives at the origin, per roof tag id

    def _robot_rows(self, tag_id: int, pose: np.ndarray) -> np.ndarray:
        """Primitives of the robot carrying ``tag_id`` at ``pose`` (x, y, θ)."""
        tpl = self._templates.get(tag_id)
        if tpl is None:
            tpl = self._templates[tag_id] = robot_primitives(tag_id)
        x, y, th = pose
        c, s = math.cos(th), math.sin(th)
        out = tpl.copy()
        out[:, PF_X] = x + c * tpl[:, PF_X] - s * tpl[:, PF_Y]
        out[:, PF_Y] = y + s * tpl[:, PF_X] + c * tpl[:, PF_Y]
        out[:, PF_COS], out[:, PF_SIN] = c, s
        return out

    def world_primitives(self, world: int) -> np.ndarray:
        """(P, PF) world ``world`` beyond the map's objects, now: extras, pedestrians, its robots with roof tags."""
        sim = self.sim
        w = sim.worlds
        if w.shared_tags is not None:  # a lab's shared world: every robot, each under its own roof tag
            return np.ascontiguousarray(w.moving_prims(sim._state, sim.tick, sim.params[0].physics_dt).copy())
        rows = [self._robot_rows(robot_tag_id(), sim.state[world, :3])]
        for j, r in enumerate(range(w.robot_lo[world], w.robot_hi[world])):
            rows.append(self._robot_rows(robot_tag_id(j), sim.npc_state[r - sim.n, :3]))
        if w.active:
            extras, _ = sim.world_view(world)
            rows.append(extras)
        return np.ascontiguousarray(np.concatenate(rows))

    def render(self, world: int = 0, frame: int = 0, only: list[int] | None = None) -> list[np.ndarray | None]:
        """Every camera's (H, W, 3) uint8 view of world ``world`` at the simulator's current state (with ``only``,
        those cameras' views; None for the others)."""
        p = self.sim.params[world]
        moving = self.world_primitives(world)
        out: list[np.ndarray | None] = [None] * len(self.cameras)
        wanted = set(range(len(self.cameras)) if only is None else only)
        for idx, r in self._groups:
            if not wanted.intersection(idx):
                continue
            if self._world_params[world] is not p:
                for k, i in enumerate(idx):
                    r.set_params(k, self.cameras[i].params(p))
            n = len(idx)
            ranges = np.zeros((n, 4), dtype=np.int64)
            ranges[:, 1] = moving.shape[0]
            counts = np.array([1 if i in wanted else 0 for i in idx], dtype=np.int64)  # 0: not rendered
            frames = r.render(self._poses[id(r)], self._seeds[idx], np.full(n, frame, dtype=np.int64),
                              k_count=counts, moving=moving, ranges=ranges)
            for k, i in enumerate(idx):
                if i in wanted:
                    out[i] = frames[k]
        self._world_params[world] = p
        return out  # type: ignore[return-value]
