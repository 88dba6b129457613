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


#: side of the tileable surface-grain table; each tile reads it at its own pseudo-random offset
_GRAIN = 64


def grain_table(seed: int) -> np.ndarray:
    """(_GRAIN², ) uniform [-1, 1) surface grain, fixed by the texture seed."""
    return np.random.default_rng(seed).uniform(-1.0, 1.0, _GRAIN * _GRAIN).astype(np.float32)


@nb.njit(cache=True, inline="always")
def _span_row(
    acc, first, X0, Y0, dX, dY, lv_r, u0, u1, grain_amp, pal, grain_n,
    inv_ts, tile_kind, tile_affine, tile_base, tex, tex_off, tex_size, n_pal,
):
    """Add (or, if ``first``, store) the ground colour of pixels u0..u1-1 of one row into ``acc``.

    For a pinhole camera the ground points of a row lie on a line, X(u) = X0 + u dX, so the row is cut
    into spans that stay on one tile; per span the texture coordinates are linear in u too, and a
    pixel costs two multiply-adds, a texel fetch and a palette fetch.
    """
    n_i = tile_kind.shape[0]
    n_j = tile_kind.shape[1]
    dfi = dX * inv_ts
    dfj = dY * inv_ts
    u = u0
    while u < u1:
        fi = (X0 + u * dX) * inv_ts
        fj = (Y0 + u * dY) * inv_ts
        ti = int(math.floor(fi))
        tj = int(math.floor(fj))
        # last pixel whose centre is still in this tile (the cell between integer grid lines)
        end = u1
        if dfi > 1e-12:
            end = min(end, u + int(math.ceil((ti + 1 - fi) / dfi)))
        elif dfi < -1e-12:
            end = min(end, u + int(math.ceil((ti - fi) / dfi + 1e-9)))
        if dfj > 1e-12:
            end = min(end, u + int(math.ceil((tj + 1 - fj) / dfj)))
        elif dfj < -1e-12:
            end = min(end, u + int(math.ceil((tj - fj) / dfj + 1e-9)))
        end = max(end, u + 1)
        if ti < 0 or tj < 0 or ti >= n_i or tj >= n_j:
            row = n_pal + 4
            for k in range(u, end):
                if first:
                    acc[k, 0] = pal[row, 0]
                    acc[k, 1] = pal[row, 1]
                    acc[k, 2] = pal[row, 2]
                else:
                    acc[k, 0] += pal[row, 0]
                    acc[k, 1] += pal[row, 1]
                    acc[k, 2] += pal[row, 2]
            u = end
            continue
        lx0 = fi - ti - u * dfi  # tile-local coordinates at u = 0 of this span's line
        ly0 = fj - tj - u * dfj
        kind = tile_kind[ti, tj]
        if kind < 0:
            a0, a1, a2, b0, b1, b2 = 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
        else:
            a0 = tile_affine[ti, tj, 0]
            a1 = tile_affine[ti, tj, 1]
            a2 = tile_affine[ti, tj, 2]
            b0 = tile_affine[ti, tj, 3]
            b1 = tile_affine[ti, tj, 4]
            b2 = tile_affine[ti, tj, 5]
        tu0 = a0 + a1 * lx0 + a2 * ly0
        tv0 = b0 + b1 * lx0 + b2 * ly0
        dtu = a1 * dfi + a2 * dfj
        dtv = b1 * dfi + b2 * dfj
        gox = int(tile_affine[ti, tj, 6])
        goy = int(tile_affine[ti, tj, 7])
        base_row = n_pal + tile_base[ti, tj]
        for k in range(u, end):
            level = lv_r[k]
            sz = tex_size >> level
            tx = min(max(int((tu0 + k * dtu) * sz), 0), sz - 1)
            ty = min(max(int((tv0 + k * dtv) * sz), 0), sz - 1)
            idx = base_row if kind < 0 else int(tex[tex_off[kind, level] + ty * sz + tx])
            f = 1.0 + grain_amp[level] * grain_n[(((ty + goy) & (_GRAIN - 1)) << 6) | ((tx + gox) & (_GRAIN - 1))]
            if first:
                acc[k, 0] = pal[idx, 0] * f
                acc[k, 1] = pal[idx, 1] * f
                acc[k, 2] = pal[idx, 2] * f
            else:
                acc[k, 0] += pal[idx, 0] * f
                acc[k, 1] += pal[idx, 1] * f
                acc[k, 2] += pal[idx, 2] * f
        u = end


@nb.njit(cache=True, inline="always")
def _pixel_ground(X, Y, level, grain_amp, pal, grain_n, inv_ts, tile_kind, tile_affine, tile_base, tex, tex_off,
                  tex_size, n_pal):
    """Ground colour of one map point: the general path, for cameras whose rows are not lines."""
    fi = X * inv_ts
    fj = Y * inv_ts
    if fi < 0.0 or fj < 0.0 or fi >= tile_kind.shape[0] or fj >= tile_kind.shape[1]:
        row = n_pal + 4
        return pal[row, 0], pal[row, 1], pal[row, 2]
    ti = int(fi)
    tj = int(fj)
    lx = fi - ti
    ly = fj - tj
    sz = tex_size >> level
    kind = tile_kind[ti, tj]
    if kind < 0:
        tu = lx
        tv = ly
    else:
        tu = tile_affine[ti, tj, 0] + tile_affine[ti, tj, 1] * lx + tile_affine[ti, tj, 2] * ly
        tv = tile_affine[ti, tj, 3] + tile_affine[ti, tj, 4] * lx + tile_affine[ti, tj, 5] * ly
    tx = min(max(int(tu * sz), 0), sz - 1)
    ty = min(max(int(tv * sz), 0), sz - 1)
    idx = n_pal + tile_base[ti, tj] if kind < 0 else int(tex[tex_off[kind, level] + ty * sz + tx])
    gox = int(tile_affine[ti, tj, 6])
    goy = int(tile_affine[ti, tj, 7])
    f = 1.0 + grain_amp[level] * grain_n[(((ty + goy) & (_GRAIN - 1)) << 6) | ((tx + gox) & (_GRAIN - 1))]
    return pal[idx, 0] * f, pal[idx, 1] * f, pal[idx, 2] * f


@nb.njit(cache=True, parallel=True, fastmath=True, error_model="numpy", boundscheck=False)
def render_kernel(
    out, poses, cam_index, linear, gx, gy, level_map, ground_from, sky_mix, vignette,
    tile_kind, tile_affine, tile_base, inv_ts, tex, tex_off, tex_size,
    palette, sky, offset, post, seeds, frames, k_count, grain, grain_index,
):
    """Render ``out[n]`` (H, W, 3 uint8) for every robot n from its K sub-frame poses ``poses[n]``.

    ``palette[n]`` holds robot n's colours already multiplied by light and contrast; ``offset[n]`` is
    the per-channel value added after (brightness and contrast pivot). ``level_map < 0`` marks sky;
    ``ground_from[c, v] < W`` if row v of camera c sees any ground. ``linear[c]``: camera c's rows are
    straight lines on the ground (pinhole, where a row is all sky or all ground), so the span
    renderer applies. ``post[n]`` = (texture_noise,
    noise_std, vignetting, -). Robot n averages the first ``k_count[n]`` sub-frames and reads surface
    grain ``grain[grain_index[n]]``.
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
        grain_n = grain[grain_index[n]]
        seed = seeds[n] ^ (np.uint64(frames[n]) * np.uint64(0x9E3779B97F4A7C15))
        pose_n = poses[n]
        k_sub = k_count[n]
        inv_k = 1.0 / k_sub
        amp = np.empty(16)
        for lv in range(16):
            amp[lv] = tex_noise / (1 << lv)  # averaging 4^L texels shrinks the grain by 2^L
        gx_r = gx[c, v]
        gy_r = gy[c, v]
        lv_r = level_map[c, v]
        acc = np.empty((w, 3))
        is_ground = ground_from[c, v] < w
        if is_ground and linear[c]:
            du = 1.0 / (w - 1) if w > 1 else 0.0
            for k in range(k_sub):
                cs = math.cos(pose_n[k, 2])
                sn = math.sin(pose_n[k, 2])
                px0 = gx_r[0]
                py0 = gy_r[0]
                dpx = (gx_r[w - 1] - px0) * du
                dpy = (gy_r[w - 1] - py0) * du
                X0 = pose_n[k, 0] + cs * px0 - sn * py0
                Y0 = pose_n[k, 1] + sn * px0 + cs * py0
                dX = cs * dpx - sn * dpy
                dY = sn * dpx + cs * dpy
                _span_row(acc, k == 0, X0, Y0, dX, dY, lv_r, 0, w, amp, pal, grain_n, inv_ts, tile_kind,
                          tile_affine, tile_base, tex, tex_off, tex_size, n_pal)
        elif is_ground:
            for k in range(k_sub):
                cs = math.cos(pose_n[k, 2])
                sn = math.sin(pose_n[k, 2])
                for u in range(w):
                    level = lv_r[u]
                    if level < 0:
                        continue
                    X = pose_n[k, 0] + cs * gx_r[u] - sn * gy_r[u]
                    Y = pose_n[k, 1] + sn * gx_r[u] + cs * gy_r[u]
                    r, g, b = _pixel_ground(X, Y, level, amp, pal, grain_n, inv_ts, tile_kind, tile_affine,
                                            tile_base, tex, tex_off, tex_size, n_pal)
                    if k == 0:
                        acc[u, 0] = r
                        acc[u, 1] = g
                        acc[u, 2] = b
                    else:
                        acc[u, 0] += r
                        acc[u, 1] += g
                        acc[u, 2] += b
        mix_r = sky_mix[c, v]
        vig_r = vignette[c, v]
        out_r = out[n, v]
        o0 = offset[n, 0]
        o1 = offset[n, 1]
        o2 = offset[n, 2]
        for u in range(w):
            if lv_r[u] < 0:
                m = mix_r[u]
                r = sky[n, _HORIZON, 0] * (1.0 - m) + sky[n, _SKY, 0] * m
                g = sky[n, _HORIZON, 1] * (1.0 - m) + sky[n, _SKY, 1] * m
                b = sky[n, _HORIZON, 2] * (1.0 - m) + sky[n, _SKY, 2] * m
            else:
                r = acc[u, 0] * inv_k
                g = acc[u, 1] * inv_k
                b = acc[u, 2] * inv_k
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
    post = np.array([p.texture_noise, p.noise_std, p.vignetting, 0.0], dtype=np.float64)
    return palette, sky, offset, post


_QUARTER_TURNS = np.array([  # (u, v) of the north drawing from tile-local (lx, ly), per CCW quarter turn
    [0, 1, 0, 0, 0, 1],
    [1, 0, -1, 0, 1, 0],
    [1, -1, 0, 1, 0, -1],
    [0, 0, 1, 1, -1, 0],
], dtype=np.float64)


def _tile_affine(lanes: LaneArrays) -> np.ndarray:
    """(W, H, 8): per tile the affine map to its texture drawing, then a grain-table offset (x, y)."""
    unturn = (1 - lanes.tile_orient.astype(np.int64)) % 4  # quarter turns back to the north drawing
    unturn = np.where(lanes.tile_kind >= 0, unturn, 0)
    w, h = unturn.shape
    offsets = np.random.default_rng(0x7E57).integers(0, _GRAIN, (w, h, 2)).astype(np.float64)
    return np.ascontiguousarray(np.concatenate([_QUARTER_TURNS[unturn], offsets], axis=-1))


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
        self._affine = _tile_affine(lanes)
        # ground material row of each tile; empty cells look like the world outside the map
        self._base = np.where(lanes.tile_base < 0, _BASES.index("outside_rgb"), lanes.tile_base).astype(np.int8)
        self.n = len(params)
        n_pal = self.tex.palette.shape[0] + len(_BASES)
        self.palette = np.zeros((self.n, n_pal, 3))
        self.sky = np.zeros((self.n, 2, 3))
        self.offset = np.zeros((self.n, 3))
        self.post = np.zeros((self.n, 4))
        self.cam_index = np.zeros(self.n, dtype=np.int64)
        self.grain_index = np.zeros(self.n, dtype=np.int64)
        self._grain_seeds: list[int] = []
        self._grain = np.zeros((0, _GRAIN * _GRAIN), dtype=np.float32)
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
        if p.texture_seed not in self._grain_seeds:
            self._grain_seeds.append(p.texture_seed)
            self._grain = np.concatenate([self._grain, grain_table(p.texture_seed)[None]])
        self.grain_index[i] = self._grain_seeds.index(p.texture_seed)
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
                np.array([t.model.distortion is None for t in self._tables]),
                np.stack([t.gx for t in self._tables]).astype(np.float64),
                np.stack([t.gy for t in self._tables]).astype(np.float64),
                np.stack(levels),
                np.stack([np.where((~t.sky).any(axis=1), 0, t.sky.shape[1]) for t in self._tables]).astype(np.int64),
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
        linear, gx, gy, level_map, ground_from, sky_mix, vignette = self._prepare()
        if out is None:
            out = np.empty((self.n, self.height, self.width, 3), dtype=np.uint8)
        la, tx = self.lanes, self.tex
        render_kernel(
            out, np.ascontiguousarray(poses, dtype=np.float64), self.cam_index, linear, gx, gy, level_map,
            ground_from, sky_mix, vignette, la.tile_kind, self._affine, self._base, 1.0 / la.tile_size,
            tx.texels, tx.offsets, tx.size, self.palette, self.sky, self.offset, self.post,
            np.asarray(seeds).astype(np.uint64), np.asarray(frames).astype(np.int64),
            np.asarray(k_count, dtype=np.int64), self._grain, self.grain_index,
        )
        return out
