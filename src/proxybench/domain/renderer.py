"""Camera renderer: one fused, compiled per-pixel kernel for a whole batch of robots.

For every pixel the ground point is precomputed in the robot frame (``camera.CameraTable``), so a
frame costs one rotation + translation per pixel and sub-frame, a tile lookup, one texel fetch from the
mip level that matches the pixel's footprint, and a palette lookup. Light, contrast and the road
colours are folded into each robot's palette beforehand (they are linear), so the inner loop does no
colour arithmetic beyond ``palette * texture_noise * shade + offset``. No NumPy temporaries: the whole
pipeline (motion blur, light, vignetting, contrast, sensor noise) is one Numba loop, parallel over the
image rows of all robots.

Appearance is per robot (``Renderer.set_params``), so a batch can randomise it per episode.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from proxybench.domain.camera import CameraTable, camera_table
from proxybench.domain.lanes import LaneArrays
from proxybench.domain.params import DomainParams
from proxybench.domain.textures import marking_textures

__all__ = ["Renderer", "render_kernel"]

# palette rows after the marking coverages: plain surfaces (indexed by LaneArrays.tile_base) and sky
_BASES = ("road_rgb", "grass_rgb", "floor_rgb", "asphalt_rgb", "outside_rgb")
_SKY, _HORIZON = 0, 1


@nb.njit(cache=True, inline="always")
def _mix64(z):
    """splitmix64 finaliser: a counter-based random stream, identical for any batch layout."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@nb.njit(cache=True, inline="always")
def _gauss_from_hash(h):
    """Approximately standard normal from 64 random bits (Irwin–Hall of four 16-bit uniforms)."""
    m = np.uint64(0xFFFF)
    s = (
        float(h & m)
        + float((h >> np.uint64(16)) & m)
        + float((h >> np.uint64(32)) & m)
        + float((h >> np.uint64(48)) & m)
    )
    return (s / 65535.0 - 2.0) * 1.7320508075688772


@nb.njit(cache=True, inline="always")
def _texel_noise(ti, tj, tx, ty, level, seed):
    """Uniform in [-1, 1) fixed to one texel of one tile: the surface grain, the same every frame."""
    h = (tx * 0x9E3779B1 + ty * 0x85EBCA77 + ti * 0xC2B2AE3D + tj * 0x27D4EB2F + level * 0x165667B1 + seed)
    h &= 0xFFFFFFFF
    h ^= h >> 15
    h = (h * 0x2C1B3C6D) & 0xFFFFFFFF
    h ^= h >> 12
    h = (h * 0x297A2D39) & 0xFFFFFFFF
    h ^= h >> 15
    return float(h) * (2.0 / 4294967296.0) - 1.0


@nb.njit(cache=True, inline="always")
def _ground_index(X, Y, level, inv_ts, tile_kind, tile_unturn, tile_base, tex, tex_off, tex_size, n_pal):
    """Palette row of map point (X, Y) at mip ``level``, plus the texel's tile and coordinates."""
    fi = X * inv_ts
    fj = Y * inv_ts
    if fi < 0.0 or fj < 0.0 or fi >= tile_kind.shape[0] or fj >= tile_kind.shape[1]:
        return n_pal + 4, -1, -1, 0, 0
    ti = int(fi)
    tj = int(fj)
    lx = fi - ti
    ly = fj - tj
    s = tex_size >> level
    kind = tile_kind[ti, tj]
    if kind < 0:
        return n_pal + tile_base[ti, tj], ti, tj, min(int(lx * s), s - 1), min(int(ly * s), s - 1)
    q = tile_unturn[ti, tj]  # quarter turns that bring the tile back to its north drawing
    if q == 0:
        u = lx
        v = ly
    elif q == 1:
        u = 1.0 - ly
        v = lx
    elif q == 2:
        u = 1.0 - lx
        v = 1.0 - ly
    else:
        u = ly
        v = 1.0 - lx
    tx = min(int(u * s), s - 1)
    ty = min(int(v * s), s - 1)
    return int(tex[tex_off[kind, level] + ty * s + tx]), ti, tj, tx, ty


@nb.njit(cache=True, parallel=True, fastmath=True, error_model="numpy", boundscheck=False)
def render_kernel(
    out, poses, cam_index, gx, gy, level_map, sky_mix, vignette,
    tile_kind, tile_unturn, tile_base, inv_ts, tex, tex_off, tex_size,
    palette, sky, offset, post, seeds, frames, k_count,
):
    """Render ``out[n]`` (H, W, 3 uint8) for every robot n from its K sub-frame poses ``poses[n]``.

    ``palette[n]`` holds robot n's colours already multiplied by light and contrast; ``offset[n]`` is
    the per-channel value added after (brightness and contrast pivot). ``level_map < 0`` marks sky.
    ``post[n]`` = (texture_noise, noise_std, vignetting, texture_seed). Robot n averages the first
    ``k_count[n]`` sub-frames.
    """
    n_envs, h, w, _ = out.shape
    n_pal = palette.shape[1] - 5
    for row in nb.prange(n_envs * h):
        n = row // h
        v = row % h
        c = cam_index[n]
        pal = palette[n]
        tex_noise = post[n, 0]
        noise_std = post[n, 1]
        vig = post[n, 2]
        tseed = int(post[n, 3])
        o0 = offset[n, 0]
        o1 = offset[n, 1]
        o2 = offset[n, 2]
        seed = seeds[n] ^ (np.uint64(frames[n]) * np.uint64(0x9E3779B97F4A7C15))
        pose_n = poses[n]
        k_sub = k_count[n]
        inv_k = 1.0 / k_sub
        cosk = np.empty(k_sub)
        sink = np.empty(k_sub)
        for k in range(k_sub):
            cosk[k] = math.cos(pose_n[k, 2])
            sink[k] = math.sin(pose_n[k, 2])
        gx_r = gx[c, v]
        gy_r = gy[c, v]
        lv_r = level_map[c, v]
        mix_r = sky_mix[c, v]
        vig_r = vignette[c, v]
        out_r = out[n, v]
        for u in range(w):
            level = lv_r[u]
            if level < 0:
                m = mix_r[u]
                r = sky[n, _HORIZON, 0] * (1.0 - m) + sky[n, _SKY, 0] * m
                g = sky[n, _HORIZON, 1] * (1.0 - m) + sky[n, _SKY, 1] * m
                b = sky[n, _HORIZON, 2] * (1.0 - m) + sky[n, _SKY, 2] * m
            else:
                px = gx_r[u]
                py = gy_r[u]
                r = 0.0
                g = 0.0
                b = 0.0
                for k in range(k_sub):
                    X = pose_n[k, 0] + cosk[k] * px - sink[k] * py
                    Y = pose_n[k, 1] + sink[k] * px + cosk[k] * py
                    idx, ti, tj, tx, ty = _ground_index(
                        X, Y, level, inv_ts, tile_kind, tile_unturn, tile_base, tex, tex_off, tex_size, n_pal
                    )
                    f = 1.0
                    if tex_noise > 0.0 and ti >= 0:
                        f += tex_noise * _texel_noise(ti, tj, tx, ty, level, tseed) / (1 << level)
                    r += pal[idx, 0] * f
                    g += pal[idx, 1] * f
                    b += pal[idx, 2] * f
                if k_sub > 1:
                    r *= inv_k
                    g *= inv_k
                    b *= inv_k
            if vig > 0.0:
                shade = 1.0 - vig * vig_r[u]
                r *= shade
                g *= shade
                b *= shade
            r += o0
            g += o1
            b += o2
            if noise_std > 0.0:
                h0 = seed + np.uint64((v * w + u) * 3)
                r += noise_std * _gauss_from_hash(_mix64(h0))
                g += noise_std * _gauss_from_hash(_mix64(h0 + np.uint64(1)))
                b += noise_std * _gauss_from_hash(_mix64(h0 + np.uint64(2)))
            out_r[u, 0] = np.uint8(min(max(r, 0.0), 255.0) + 0.5)
            out_r[u, 1] = np.uint8(min(max(g, 0.0), 255.0) + 0.5)
            out_r[u, 2] = np.uint8(min(max(b, 0.0), 255.0) + 0.5)


def _appearance(p: DomainParams, coverage: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(palette, sky, offset, post) of one robot: colours with light and contrast folded in."""
    gain = np.asarray(p.light_rgb) * p.contrast
    paint = np.array([p.white_rgb, p.yellow_rgb, p.red_rgb])
    road = np.asarray(p.road_rgb)
    marked = road * (1.0 - coverage.sum(axis=1, keepdims=True)) + coverage @ paint
    bases = np.array([getattr(p, name) for name in _BASES])
    palette = np.concatenate([marked, bases]) * gain
    sky = np.array([p.sky_rgb, p.horizon_rgb]) * gain
    offset = np.full(3, 127.5 * (1.0 - p.contrast) + p.brightness)
    post = np.array([p.texture_noise, p.noise_std, p.vignetting, p.texture_seed & 0xFFFFFFF], dtype=np.float64)
    return palette, sky, offset, post


class Renderer:
    """Renders camera frames for a batch of robots on one map.

    Robots may differ in every non-structural parameter; those sharing a camera share its table.
    Call :meth:`set_params` when a robot's θ changes (e.g. per-episode randomisation).
    """

    def __init__(self, lanes: LaneArrays, params: list[DomainParams]):
        first = params[0]
        self.width, self.height = first.image_width, first.image_height
        self.lanes = lanes
        self.tex = marking_textures(first.texture_size)
        # level-0 texel edge is tile_size / tex.size: this bias turns log2(footprint [m]) into a mip level
        self.tex_bias = math.log2(self.tex.size / lanes.tile_size)
        # per tile: quarter turns (CCW) that bring the tile back to the way its texture is drawn (north)
        self._unturn = ((1 - lanes.tile_orient.astype(np.int64)) % 4).astype(np.int8)
        # ground material row of each tile; empty cells look like the world outside the map
        self._base = np.where(lanes.tile_base < 0, _BASES.index("outside_rgb"), lanes.tile_base).astype(np.int8)
        self.n = len(params)
        n_pal = self.tex.palette.shape[0] + len(_BASES)
        self.palette = np.zeros((self.n, n_pal, 3))
        self.sky = np.zeros((self.n, 2, 3))
        self.offset = np.zeros((self.n, 3))
        self.post = np.zeros((self.n, 4))
        self.cam_index = np.zeros(self.n, dtype=np.int64)
        self._tables: list[CameraTable] = []
        self._stack: tuple[np.ndarray, ...] | None = None
        for i, p in enumerate(params):
            self.set_params(i, p)

    def set_params(self, i: int, p: DomainParams) -> None:
        """Use θ = ``p`` for robot ``i`` from the next frame on."""
        if (p.image_width, p.image_height) != (self.width, self.height):
            raise ValueError(
                f"all robots of a batch must share the image size: robot {i} has "
                f"{p.image_width}×{p.image_height}, the batch {self.width}×{self.height}"
            )
        if p.texture_size != self.tex.size and 1 << round(math.log2(p.texture_size)) != self.tex.size:
            raise ValueError(f"all robots of a batch must share texture_size ({self.tex.size})")
        self.palette[i], self.sky[i], self.offset[i], self.post[i] = _appearance(p, self.tex.palette)
        table = camera_table(p)
        if not any(t is table for t in self._tables):
            self._tables.append(table)
            self._stack = None
        self.cam_index[i] = next(k for k, t in enumerate(self._tables) if t is table)

    def _prepare(self) -> tuple[np.ndarray, ...]:
        if self._stack is None:
            used = sorted(set(self.cam_index.tolist()))
            remap = {old: new for new, old in enumerate(used)}
            self._tables = [self._tables[k] for k in used]
            self.cam_index = np.array([remap[k] for k in self.cam_index.tolist()], dtype=np.int64)
            levels = []
            for t in self._tables:
                lv = np.floor(np.log2(np.maximum(t.footprint, 1e-12)) + self.tex_bias)
                lv = np.clip(np.nan_to_num(lv, posinf=self.tex.levels - 1), 0, self.tex.levels - 1)
                levels.append(np.where(t.sky, -1, lv).astype(np.int8))
            self._stack = (
                np.stack([t.gx for t in self._tables]).astype(np.float32),
                np.stack([t.gy for t in self._tables]).astype(np.float32),
                np.stack(levels),
                np.stack([t.sky_mix for t in self._tables]).astype(np.float32),
                np.stack([t.vignette for t in self._tables]).astype(np.float32),
            )
        return self._stack

    def render(
        self, poses: np.ndarray, seeds: np.ndarray, frames: np.ndarray, out: np.ndarray | None = None,
        k_count: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frames (N, H, W, 3) uint8 for sub-frame poses (N, K, 3) [m, m, rad]; K > 1 averages (motion blur).

        ``seeds`` and ``frames`` (N,) key the sensor noise, so a frame is reproducible on its own;
        ``k_count`` (N,) limits how many of the K sub-frames each robot averages (default all).
        """
        poses = np.asarray(poses, dtype=np.float64).reshape(self.n, -1, 3)
        if k_count is None:
            k_count = np.full(self.n, poses.shape[1], dtype=np.int64)
        gx, gy, level_map, sky_mix, vignette = self._prepare()
        if out is None:
            out = np.empty((self.n, self.height, self.width, 3), dtype=np.uint8)
        la, tx = self.lanes, self.tex
        render_kernel(
            out, np.ascontiguousarray(poses, dtype=np.float64), self.cam_index, gx, gy, level_map, sky_mix,
            vignette, la.tile_kind, self._unturn, self._base, 1.0 / la.tile_size, tx.texels, tx.offsets,
            tx.size, self.palette, self.sky, self.offset, self.post,
            np.asarray(seeds).astype(np.uint64), np.asarray(frames).astype(np.int64),
            np.asarray(k_count, dtype=np.int64),
        )
        return out
