"""Top-down views: the map as an image (cached per map and appearance) with robots drawn on top.

Used by the env's ``top_down`` render mode, the video writer and ``proxybench map show`` (which adds
the lane centre lines with matplotlib). Image row 0 is the north edge of the map.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import DRIVABLE_KINDS, GROUND_KINDS, Map
from proxybench.domain.objects import CYLINDER, MATERIAL_PARAMS, PF_MATERIAL, TAG, pack_objects
from proxybench.domain.params import DomainParams
from proxybench.domain.textures import marking_textures

__all__ = ["draw_objects", "draw_robots", "map_image", "save_map_plot", "top_down"]

_BASE_COLOUR = {"grass": "grass_rgb", "floor": "floor_rgb", "asphalt": "asphalt_rgb"}


@lru_cache(maxsize=16)
def _map_image(m: Map, px_per_tile: int, p: DomainParams) -> np.ndarray:
    tex = marking_textures(p.texture_size)
    level = max(0, min(tex.levels - 1, round(math.log2(tex.size / px_per_tile))))
    s = tex.size >> level
    paint = np.array([p.white_rgb, p.yellow_rgb, p.red_rgb])
    road = np.asarray(p.road_rgb)
    img = np.empty((m.height * s, m.width * s, 3))
    img[:] = p.outside_rgb
    for t in m.iter_tiles():
        rows = slice((m.height - 1 - t.j) * s, (m.height - t.j) * s)
        cols = slice(t.i * s, (t.i + 1) * s)
        if t.drivable:
            cov = tex.level_image(t.kind, level)  # rows south → north, drawn heading north
            rgb = road * (1.0 - cov.sum(axis=-1, keepdims=True)) + cov @ paint
            img[rows, cols] = np.rot90(np.flipud(rgb), k=(int(t.orientation) - 1) % 4)
        elif t.kind in GROUND_KINDS:
            img[rows, cols] = getattr(p, _BASE_COLOUR[GROUND_KINDS[t.kind]])
    assert len(DRIVABLE_KINDS) > 0
    out = np.clip(img * np.asarray(p.light_rgb), 0, 255).astype(np.uint8)
    if s != px_per_tile:
        size = (m.width * px_per_tile, m.height * px_per_tile)
        out = np.asarray(Image.fromarray(out).resize(size, Image.Resampling.BILINEAR))
    out.setflags(write=False)
    return out


def map_image(m: Map, px_per_tile: int = 64, params: DomainParams | None = None) -> np.ndarray:
    """(H, W, 3) uint8 top-down picture of the map, ``px_per_tile`` pixels per tile edge (read-only, cached)."""
    return _map_image(m, px_per_tile, params or DomainParams())


def draw_robots(
    img: np.ndarray, m: Map, poses: np.ndarray, px_per_tile: int, colours: Sequence[tuple[int, int, int]] | None = None
) -> np.ndarray:
    """Copy of ``img`` with a robot footprint (and heading notch) at each (x, y, θ) pose."""
    pil = Image.fromarray(np.ascontiguousarray(img))
    draw = ImageDraw.Draw(pil)
    scale = px_per_tile / m.tile_size  # pixels per metre
    h_px = img.shape[0]
    body = np.array([[0.1, 0.0], [0.05, 0.065], [-0.1, 0.065], [-0.1, -0.065], [0.05, -0.065]])
    for k, (x, y, th) in enumerate(np.asarray(poses).reshape(-1, 3)):
        c, s = math.cos(th), math.sin(th)
        pts = [(x + c * bx - s * by, y + s * bx + c * by) for bx, by in body]
        px = [(u * scale, h_px - v * scale) for u, v in pts]
        colour = tuple(colours[k % len(colours)]) if colours else (40, 90, 230)
        draw.polygon(px, fill=colour, outline=(0, 0, 0))
    return np.asarray(pil)


def draw_objects(img: np.ndarray, m: Map, px_per_tile: int, light: Sequence[float] = (1.0, 1.0, 1.0),
                 prims: np.ndarray | None = None, params: DomainParams | None = None) -> np.ndarray:
    """Copy of ``img`` with the map objects (or the primitives ``prims`` (P, PF)) drawn as filled circles /
    rectangles in their colours (duckies and duckiebots in those of ``params``).

    Parts are drawn bottom to top, so a sign shows its plate over its pole.
    """
    pil = Image.fromarray(np.ascontiguousarray(img))
    draw = ImageDraw.Draw(pil)
    scale = px_per_tile / m.tile_size
    h_px = img.shape[0]
    prims = pack_objects(m.objects).prims if prims is None else prims
    p_ = params or DomainParams()
    materials = [None, *(getattr(p_, name) for name in MATERIAL_PARAMS[1:])]
    for p in sorted(prims.tolist(), key=lambda q: q[7]):
        shape, x, y, c, s, a, b = p[:7]
        rgb = (25.0, 25.0, 25.0) if shape == TAG else materials[int(p[PF_MATERIAL])] or p[9:12]
        colour = tuple(int(min(max(v * g, 0.0), 255.0)) for v, g in zip(rgb, light, strict=True))
        if shape != CYLINDER:  # a box, or a tag (drawn as its black square)
            pts = [(x + c * sx * a - s * sy * b, y + s * sx * a + c * sy * b) for sx, sy in
                   ((1, 1), (-1, 1), (-1, -1), (1, -1))]
            draw.polygon([(u * scale, h_px - v * scale) for u, v in pts], fill=colour)
        else:
            r = max(a * scale, 1.0)
            draw.ellipse([x * scale - r, h_px - y * scale - r, x * scale + r, h_px - y * scale + r], fill=colour)
    return np.asarray(pil)


@lru_cache(maxsize=16)
def _map_with_objects(m: Map, px_per_tile: int, p: DomainParams) -> np.ndarray:
    img = map_image(m, px_per_tile, p)
    if m.objects:
        img = draw_objects(img, m, px_per_tile, p.light_rgb, params=p)
        img.setflags(write=False)
    return img


def top_down(m: Map, poses: np.ndarray, px_per_tile: int = 64, params: DomainParams | None = None,
             objects: np.ndarray | None = None, npc_poses: np.ndarray | None = None) -> np.ndarray:
    """Top-down frame of the map with its objects and the robots at ``poses`` (N, 3).

    An episode's own world (``Simulator.world_view``) adds ``objects`` (primitives (P, PF): extra duckies,
    pedestrians) and NPC robots at ``npc_poses`` (M, 3), drawn in the duckiebot colour.
    """
    p = params or DomainParams()
    img = _map_with_objects(m, px_per_tile, p)
    if objects is not None and len(objects):
        img = draw_objects(img, m, px_per_tile, p.light_rgb, prims=objects, params=p)
    if npc_poses is not None and len(npc_poses):
        img = draw_robots(img, m, npc_poses, px_per_tile, [tuple(int(v) for v in p.duckiebot_rgb)])
    return draw_robots(img, m, poses, px_per_tile)


def save_map_plot(m: Map, path: str | Path, px_per_tile: int = 96, dpi: int = 120) -> Path:
    """PNG of the map with every lane centre curve (arrow = driving direction) and the map objects."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    net = LaneNetwork(m)
    w, h = m.size_m
    fig, ax = plt.subplots(figsize=(max(4.0, 1.4 * m.width + 1), max(4.0, 1.4 * m.height + 1)))
    ax.imshow(map_image(m, px_per_tile), extent=(0, w, 0, h), origin="upper", interpolation="bilinear")
    cmap = {"straight": "tab:cyan", "left": "tab:orange", "right": "tab:pink"}
    for seg in net.segments:
        pts = seg.sample(24)
        ax.plot(pts[:, 0], pts[:, 1], color=cmap[seg.kind_name], lw=1.2)
        mid = seg.position(0.5 * seg.length)
        hd = seg.heading_at(0.5 * seg.length)
        ax.annotate(
            "", xy=(mid[0] + 0.03 * math.cos(hd), mid[1] + 0.03 * math.sin(hd)), xytext=mid,
            arrowprops={"arrowstyle": "->", "color": cmap[seg.kind_name], "lw": 1.2},
        )
    for obj in m.objects:
        ax.plot(obj.x, obj.y, marker="o", ms=6, mec="k", mfc="gold")
        ax.annotate(obj.kind, (obj.x, obj.y), textcoords="offset points", xytext=(4, 4), fontsize=7)
    if m.start_pose is not None:
        x, y, th = m.start_pose
        ax.arrow(x, y, 0.1 * math.cos(th), 0.1 * math.sin(th), width=0.015, color="tab:blue")
    ax.set_xticks(np.arange(m.width + 1) * m.tile_size, labels=[str(i) for i in range(m.width + 1)])
    ax.set_yticks(np.arange(m.height + 1) * m.tile_size, labels=[str(j) for j in range(m.height + 1)])
    ax.set_xlabel("x [tiles]")
    ax.set_ylabel("y [tiles]")
    ax.set_title(f"{m.name}: {m.summary()}", fontsize=8)
    ax.set_xlim(0, w)
    ax.set_ylim(0, h)
    path = Path(path)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return path
