"""Road markings as mip-mapped coverage textures, drawn procedurally from the road geometry.

Each drivable tile kind is drawn once, heading north, as the fraction of every texel covered by white,
yellow and red paint (supersampled, so edges are anti-aliased). Coverage averages correctly into the
mip levels that keep distant road from shimmering.

Only a few hundred distinct coverage triplets occur, so texels hold a uint16 index into ``palette``
(P, 3) coverages. The renderer turns the palette into colours once per robot whenever its light or
colours change, and a texel fetch is then one index and one colour lookup. Row ``ty`` runs south to
north.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from proxybench.domain.lanes import ROAD, RoadGeometry
from proxybench.domain.maps import DRIVABLE_KINDS

__all__ = ["MarkingTextures", "marking_coverage", "marking_textures"]

_SUPERSAMPLE = 4


def _dashed(s: np.ndarray, period: float) -> np.ndarray:
    """Dashes centred in each period, so the pattern meets itself across tile edges either way."""
    f = np.mod(s / period, 1.0)
    return (f >= 0.25) & (f < 0.75)


def _straight(x, y, g: RoadGeometry):
    ax = np.abs(x)
    white = (ax >= g.white_inner) & (ax <= g.white_outer)
    yellow = (ax <= g.yellow_half_width) & _dashed(y + 0.5, 2 * g.dash_length)
    return white, yellow, np.zeros_like(white)


def _curve_left(x, y, g: RoadGeometry):
    """Road from the south edge to the west edge, turning around the south-west corner."""
    rho = np.hypot(x + 0.5, y + 0.5)
    d = np.abs(rho - 0.5)
    white = (d >= g.white_inner) & (d <= g.white_outer)
    arc = 0.5 * np.arctan2(y + 0.5, x + 0.5)  # along the road centre, 0..π/4
    n = max(1, round((math.pi / 4) / (2 * g.dash_length)))
    yellow = (d <= g.yellow_half_width) & _dashed(arc, (math.pi / 4) / n)
    return white, yellow, np.zeros_like(white)


def _rotate_ccw(x, y, quarter_turns: int):
    for _ in range(quarter_turns % 4):
        x, y = -y, x
    return x, y


# open edges of each intersection drawn heading north (see maps._OPEN_EDGES_NORTH); E=0 N=1 W=2 S=3
_INTERSECTION_EDGES = {"3way_left": (3, 1, 2), "3way_right": (3, 1, 0), "4way": (0, 1, 2, 3)}


def _intersection(x, y, g: RoadGeometry, open_edges):
    white = np.zeros(x.shape, bool)
    red = np.zeros(x.shape, bool)
    for edge in range(4):
        # turn the tile so that this edge lies south, then draw as for a south edge
        rx, ry = _rotate_ccw(x, y, (3 - edge) % 4)
        ax = np.abs(rx)
        band = ry <= -0.5 + g.stop_line_depth
        if edge in open_edges:
            white |= band & (ax >= g.white_inner) & (ax <= g.white_outer)
            red |= band & (rx >= g.yellow_half_width) & (rx <= g.white_inner)
        else:
            white |= (-ry >= g.white_inner) & (-ry <= g.white_outer)
    return white, np.zeros_like(white), red


def marking_coverage(kind: str, x: np.ndarray, y: np.ndarray, g: RoadGeometry = ROAD):
    """Boolean (white, yellow, red) masks at tile-local points in [-0.5, 0.5]², tile drawn heading north."""
    if kind == "straight":
        return _straight(x, y, g)
    if kind == "curve_left":
        return _curve_left(x, y, g)
    if kind == "curve_right":
        return _curve_left(-x, y, g)
    return _intersection(x, y, g, _INTERSECTION_EDGES[kind])


@dataclass(frozen=True)
class MarkingTextures:
    """Mip pyramids of every drivable kind in one flat array of palette indices.

    ``offsets[kind, level]`` indexes ``texels``; level ``L`` is ``size >> L`` texels square;
    ``palette[texels[i]]`` is the (white, yellow, red) coverage in [0, 1] of texel ``i``.
    """

    size: int
    levels: int
    texels: np.ndarray  # uint16 palette indices
    offsets: np.ndarray  # (n_kinds, levels) int64
    palette: np.ndarray  # (P, 3) float64 coverage

    def level_image(self, kind: str, level: int = 0) -> np.ndarray:
        """(S, S, 3) float coverage in [0, 1], rows south → north; for inspection and top-down views."""
        k = DRIVABLE_KINDS.index(kind)
        s = self.size >> level
        flat = self.texels[self.offsets[k, level] : self.offsets[k, level] + s * s].reshape(s, s)
        return self.palette[flat]


def _downsample(cov: np.ndarray) -> np.ndarray:
    s = cov.shape[0] // 2
    return cov.reshape(s, 2, s, 2, -1).mean(axis=(1, 3))


@lru_cache(maxsize=8)
def marking_textures(size: int = 256, geometry: RoadGeometry = ROAD) -> MarkingTextures:
    """Build (and cache) the marking textures at ``size`` texels per tile edge (rounded to a power of 2)."""
    size = 1 << max(4, round(math.log2(size)))
    levels = int(math.log2(size)) + 1
    n = size * _SUPERSAMPLE
    c = (np.arange(n) + 0.5) / n - 0.5
    yy, xx = np.meshgrid(c, c, indexing="ij")  # row = y (south → north)
    chunks, offsets, pos = [], np.zeros((len(DRIVABLE_KINDS), levels), np.int64), 0
    for k, kind in enumerate(DRIVABLE_KINDS):
        masks = marking_coverage(kind, xx, yy, geometry)
        cov = np.stack(masks, axis=-1).astype(np.float32)
        cov = cov.reshape(size, _SUPERSAMPLE, size, _SUPERSAMPLE, 3).mean(axis=(1, 3))
        for level in range(levels):
            offsets[k, level] = pos
            q = np.clip(np.rint(cov * 255.0), 0, 255).astype(np.uint32).reshape(-1, 3)
            chunks.append(q[:, 0] | (q[:, 1] << 8) | (q[:, 2] << 16))
            pos += q.shape[0]
            if cov.shape[0] > 1:
                cov = _downsample(cov)
    packed = np.concatenate(chunks)
    keys, index = np.unique(packed, return_inverse=True)
    if keys.size > np.iinfo(np.uint16).max:
        raise RuntimeError("too many distinct texel coverages for a uint16 palette")
    palette = np.stack([(keys >> (8 * ch)) & 0xFF for ch in range(3)], axis=-1) / 255.0
    return MarkingTextures(size, levels, index.astype(np.uint16), offsets, palette)
