"""Camera renderer: one fused, compiled per-pixel kernel for a whole batch of robots.

For every pixel the ground point is precomputed in the robot frame (``camera.CameraTable``), so a
frame costs one rotation + translation per pixel and sub-frame, a tile lookup, one texel fetch from the
mip level that matches the pixel's footprint, and a palette lookup. Light, contrast and the road
colours are folded into each robot's palette beforehand (they are linear), so the inner loop does no
colour arithmetic beyond ``palette * texture_noise * shade + offset``. No NumPy temporaries: the whole
pipeline (motion blur, light, vignetting, contrast, sensor noise) is one Numba loop over the image rows of
all robots (``render_rows``), run on one thread or on all (``render_parallel``) as
``proxybench.domain.parallelism`` decides from timing both.

Appearance is per robot (``Renderer.set_params``), so a batch can randomise it per episode.

The ground shading (texel, grain, noise) lives in ``proxybench.domain.render_ground``. Map objects are
drawn by the object path in ``proxybench.domain.render_objects``: only image rows that
some culled object's image box touches take it, so every other row is rendered by exactly the
object-free code, and frames without objects in view are bit-identical to frames of an empty map.
"""

from __future__ import annotations

import inspect
import math
import time
from collections.abc import Sequence

import numba as nb
import numpy as np

from proxybench.domain.camera import CameraTable, camera_table
from proxybench.domain.lanes import LaneArrays
from proxybench.domain.maps import MapObject
from proxybench.domain.objects import MATERIAL_PARAMS, ObjectArrays, pack_objects
from proxybench.domain.parallelism import (
    ThreadChoice,
    claim_threads,
    fetch_add,
    release_threads,
    threads_available,
)
from proxybench.domain.params import DomainParams
from proxybench.domain.render_ground import GRAIN, curve_row, gauss_from_hash, grain_table, mix64, span_row
from proxybench.domain.render_objects import OBJECT_RANGE, camera_row, cull_objects, draw_object_row, pixel_rays
from proxybench.domain.textures import marking_textures

__all__ = ["OBJECT_RANGE", "Renderer", "cull_objects", "render_parallel", "render_rows"]

# palette rows after the marking coverages: plain surfaces (indexed by LaneArrays.tile_base) and sky
_BASES = ("road_rgb", "grass_rgb", "floor_rgb", "asphalt_rgb", "outside_rgb")
_SKY, _HORIZON = 0, 1


@nb.njit(cache=True, fastmath=True, error_model="numpy", boundscheck=False, inline="always")
def _span_ends(x, y, cs, sn, gx_r, gy_r, w):
    """(X0, Y0, dX, dY): the map point of a straight ground row's first pixel and the step to the next, seen
    from the pose (x, y) with heading cosine ``cs`` and sine ``sn`` (the row's robot-frame ends ``gx_r``, ``gy_r``)."""
    du = 1.0 / (w - 1) if w > 1 else 0.0
    px0 = gx_r[0]
    py0 = gy_r[0]
    dpx = (gx_r[w - 1] - px0) * du
    dpy = (gy_r[w - 1] - py0) * du
    return x + cs * px0 - sn * py0, y + sn * px0 + cs * py0, cs * dpx - sn * dpy, sn * dpx + cs * dpy


@nb.njit(cache=True, fastmath=True, error_model="numpy", boundscheck=False)
def render_rows(
    lo, hi, out, poses, cam_index, linear, gx, gy, level_map, ground_from, sky_mix, vignette,
    tile_kind, tile_affine, tile_base, inv_ts, tex, tex_off, tex_size,
    palette, sky, offset, post, seeds, frames, k_count, grain, grain_index,
    rays, cams, prims, vis, nvis, obj_box, gain, mat_rgb, sky_slot, sky_cache,
):
    """Render image rows ``lo .. hi - 1`` of the batch (row r is row r % H of robot r // H) into ``out``.

    ``out[n]`` (H, W, 3 uint8) is robot n's frame from its K sub-frame poses ``poses[n]``.
    ``palette[n]`` holds robot n's colours already multiplied by light and contrast; ``offset[n]`` is
    the per-channel value added after (brightness and contrast pivot). ``level_map < 0`` marks sky;
    ``ground_from[c, v] < W`` if row v of camera c sees any ground. ``linear[c]``: camera c's rows are
    straight lines on the ground (pinhole, where a row is all sky or all ground), so the span
    renderer applies. ``post[n]`` = (texture_noise,
    noise_std, vignetting, -). Robot n averages the first ``k_count[n]`` sub-frames and reads surface
    grain ``grain[grain_index[n]]``.

    Objects: ``rays[c, v, u]`` is pixel (u, v)'s ray direction in the robot frame, ``cams`` the camera
    mountings, ``prims`` the object primitives and ``vis``, ``nvis``, ``obj_box`` their per robot and
    sub-frame culling (``cull_objects``); ``gain[n]`` is robot n's light × contrast and ``mat_rgb[n]`` its
    colours of the object materials (``objects.MATERIAL_PARAMS``). Rows no visible
    primitive's box touches take exactly the object-free path.

    Sky: row v of camera c is all sky and ``sky_slot[c, v] >= 0``: where this kernel would shade it
    without per-pixel effects, it copies ``sky_cache[n, sky_slot[c, v]]`` instead, the bytes this kernel
    wrote for that row before (``Renderer._fill_sky``: they depend on the robot's appearance only).
    """
    h, w = out.shape[1], out.shape[2]
    n_pal = palette.shape[1] - 5
    amp = np.empty(16)
    acc = np.empty((w, 3))
    tmp = np.empty((w, 3))
    tbest = np.empty(w)
    hit = np.zeros(w, dtype=np.bool_)
    amp_of = -1
    for row in range(lo, hi):
        n = row // h
        v = row % h
        if k_count[n] == 0:  # robot not rendered this frame (its episode has ended)
            continue
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
        if amp_of != n:
            amp_of = n
            for lv in range(16):
                amp[lv] = tex_noise / (1 << lv)  # averaging 4^L texels shrinks the grain by 2^L
        gx_r = gx[c, v]
        gy_r = gy[c, v]
        lv_r = level_map[c, v]
        is_ground = ground_from[c, v] < w
        any_obj = False
        for k in range(k_sub):
            for j in range(nvis[n, k]):
                if obj_box[n, k, j, 2] <= v < obj_box[n, k, j, 3]:
                    any_obj = True
        if any_obj:
            hit[:] = False
            mix_o = sky_mix[c, v]
            rays_r = rays[c, v]
            fwd = cams[c, 0]
            hgt = cams[c, 1]
            for k in range(k_sub):
                cs = math.cos(pose_n[k, 2])
                sn = math.sin(pose_n[k, 2])
                buf = acc if k == 0 else tmp  # sub-frame 0 is drawn in place, later ones are added
                if is_ground and linear[c]:
                    X0, Y0, dX, dY = _span_ends(pose_n[k, 0], pose_n[k, 1], cs, sn, gx_r, gy_r, w)
                    span_row(buf, True, X0, Y0, dX, dY, lv_r, 0, w, amp, pal, grain_n, inv_ts, tile_kind,
                              tile_affine, tile_base, tex, tex_off, tex_size, n_pal)
                else:
                    curve_row(buf, True, pose_n[k, 0], pose_n[k, 1], cs, sn, gx_r, gy_r, lv_r, amp, pal, grain_n,
                              inv_ts, tile_kind, tile_affine, tile_base, tex, tex_off, tex_size, n_pal)
                    for u in range(w):
                        if lv_r[u] < 0:
                            m = mix_o[u]
                            buf[u, 0] = sky[n, _HORIZON, 0] * (1.0 - m) + sky[n, _SKY, 0] * m
                            buf[u, 1] = sky[n, _HORIZON, 1] * (1.0 - m) + sky[n, _SKY, 1] * m
                            buf[u, 2] = sky[n, _HORIZON, 2] * (1.0 - m) + sky[n, _SKY, 2] * m
                draw_object_row(buf, hit, tbest, v, pose_n[k, 0] + cs * fwd, pose_n[k, 1] + sn * fwd, hgt, cs, sn,
                                rays_r, lv_r, prims, vis[n, k], obj_box[n, k], nvis[n, k], gain[n], mat_rgb[n],
                                rays[c])
                if k > 0:
                    for u in range(w):
                        acc[u, 0] += tmp[u, 0]
                        acc[u, 1] += tmp[u, 1]
                        acc[u, 2] += tmp[u, 2]
        elif is_ground and linear[c]:
            for k in range(k_sub):
                cs = math.cos(pose_n[k, 2])
                sn = math.sin(pose_n[k, 2])
                X0, Y0, dX, dY = _span_ends(pose_n[k, 0], pose_n[k, 1], cs, sn, gx_r, gy_r, w)
                span_row(acc, k == 0, X0, Y0, dX, dY, lv_r, 0, w, amp, pal, grain_n, inv_ts, tile_kind,
                          tile_affine, tile_base, tex, tex_off, tex_size, n_pal)
        elif is_ground:
            for k in range(k_sub):
                cs = math.cos(pose_n[k, 2])
                sn = math.sin(pose_n[k, 2])
                curve_row(acc, k == 0, pose_n[k, 0], pose_n[k, 1], cs, sn, gx_r, gy_r, lv_r, amp, pal, grain_n,
                          inv_ts, tile_kind, tile_affine, tile_base, tex, tex_off, tex_size, n_pal)
        mix_r = sky_mix[c, v]
        vig_r = vignette[c, v]
        out_r = out[n, v]
        o0 = offset[n, 0]
        o1 = offset[n, 1]
        o2 = offset[n, 2]
        if not any_obj and vig <= 0.0 and noise_std <= 0.0 and (not is_ground or linear[c]):
            # the common rows, all sky or all ground (pinhole), without per-pixel effects: branch-free loops
            # with the same arithmetic as the general one below
            if is_ground:
                # flat views and an int32 conversion (exact: the value is in [0.5, 255.5)) let the compiler
                # vectorise this loop
                acc_f = acc.reshape(3 * w)
                dst = out_r.reshape(3 * w)
                for u in range(w):
                    r = acc_f[3 * u] * inv_k
                    g = acc_f[3 * u + 1] * inv_k
                    b = acc_f[3 * u + 2] * inv_k
                    r += o0
                    g += o1
                    b += o2
                    dst[3 * u] = np.int32(min(max(r, 0.0), 255.0) + 0.5)
                    dst[3 * u + 1] = np.int32(min(max(g, 0.0), 255.0) + 0.5)
                    dst[3 * u + 2] = np.int32(min(max(b, 0.0), 255.0) + 0.5)
            elif sky_slot[c, v] >= 0:
                src = sky_cache[n, sky_slot[c, v]].reshape(3 * w)
                dst = out_r.reshape(3 * w)
                for i in range(3 * w):
                    dst[i] = src[i]
            else:
                h0, h1, h2 = sky[n, _HORIZON, 0], sky[n, _HORIZON, 1], sky[n, _HORIZON, 2]
                s0, s1, s2 = sky[n, _SKY, 0], sky[n, _SKY, 1], sky[n, _SKY, 2]
                for u in range(w):
                    m = mix_r[u]
                    r = h0 * (1.0 - m) + s0 * m
                    g = h1 * (1.0 - m) + s1 * m
                    b = h2 * (1.0 - m) + s2 * m
                    r += o0
                    g += o1
                    b += o2
                    out_r[u, 0] = np.uint8(min(max(r, 0.0), 255.0) + 0.5)
                    out_r[u, 1] = np.uint8(min(max(g, 0.0), 255.0) + 0.5)
                    out_r[u, 2] = np.uint8(min(max(b, 0.0), 255.0) + 0.5)
            continue
        for u in range(w):
            if lv_r[u] < 0 and not (any_obj and hit[u]):
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
                r += noise_std * gauss_from_hash(mix64(h0))
                g += noise_std * gauss_from_hash(mix64(h0 + np.uint64(1)))
                b += noise_std * gauss_from_hash(mix64(h0 + np.uint64(2)))
            out_r[u, 0] = np.uint8(min(max(r, 0.0), 255.0) + 0.5)
            out_r[u, 1] = np.uint8(min(max(g, 0.0), 255.0) + 0.5)
            out_r[u, 2] = np.uint8(min(max(b, 0.0), 255.0) + 0.5)


@nb.njit(cache=True, parallel=True)
def render_parallel(
    workers, counter, chunk, out, poses, cam_index, linear, gx, gy, level_map, ground_from, sky_mix, vignette,
    tile_kind, tile_affine, tile_base, inv_ts, tex, tex_off, tex_size,
    palette, sky, offset, post, seeds, frames, k_count, grain, grain_index,
    rays, cams, prims, vis, nvis, obj_box, gain, mat_rgb, sky_slot, sky_cache,
):
    """:func:`render_rows` of the whole batch on ``workers`` threads, each taking ``chunk`` rows at a time
    from ``counter[0]`` (0 on entry) until none are left (see ``proxybench.domain.parallelism``)."""
    total = out.shape[0] * out.shape[1]
    for _ in nb.prange(workers):
        while True:
            lo = fetch_add(counter, 0, chunk)
            if lo >= total:
                break
            render_rows(
                lo, min(lo + chunk, total), out, poses, cam_index, linear, gx, gy, level_map, ground_from, sky_mix,
                vignette, tile_kind, tile_affine, tile_base, inv_ts, tex, tex_off, tex_size, palette, sky, offset,
                post, seeds, frames, k_count, grain, grain_index, rays, cams, prims, vis, nvis, obj_box, gain,
                mat_rgb, sky_slot, sky_cache,
            )


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
    offsets = np.random.default_rng(0x7E57).integers(0, GRAIN, (w, h, 2)).astype(np.float64)
    return np.ascontiguousarray(np.concatenate([_QUARTER_TURNS[unturn], offsets], axis=-1))


def _as(a, dtype) -> np.ndarray:
    """``np.asarray(a).astype(dtype)``, without the copy when ``a`` already is such an array."""
    return a if isinstance(a, np.ndarray) and a.dtype == dtype else np.asarray(a).astype(dtype)


#: largest sky-row cache a renderer keeps [bytes] (beyond it, all sky rows are shaded at every frame)
SKY_CACHE_BYTES = 64 << 20
#: positions of the kernel's arguments after ``lo``, ``hi``, by name (derived: the list may change)
_ARG = {name: i for i, name in enumerate(list(inspect.signature(render_rows.py_func).parameters)[2:])}
#: the arrays indexed by robot
_ROBOT_ARGS = tuple(_ARG[name] for name in ("poses", "cam_index", "palette", "sky", "offset", "post", "seeds",
                                             "frames", "grain_index", "gain", "mat_rgb"))


class Renderer:
    """Renders camera frames for a batch of robots on one map.

    Robots may differ in every non-structural parameter; those sharing a camera share its table.
    Call :meth:`set_params` when a robot's θ changes (e.g. per-episode randomisation).

    ``objects`` (map objects, or already packed ``ObjectArrays``) are drawn as upright flat-shaded shapes
    (see ``proxybench.domain.objects``) that hide the ground behind them; only those within
    ``object_range`` [m] of the camera are drawn.
    """

    def __init__(
        self, lanes: LaneArrays, params: list[DomainParams],
        objects: Sequence[MapObject] | ObjectArrays | None = None, object_range: float = OBJECT_RANGE,
    ):
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
        self.gain = np.zeros((self.n, 3))
        self.mat_rgb = np.zeros((self.n, len(MATERIAL_PARAMS), 3))
        if objects is None:
            objects = ()
        self.objects = objects if isinstance(objects, ObjectArrays) else pack_objects(objects)
        self.object_range = float(object_range)
        self.cam_index = np.zeros(self.n, dtype=np.int64)
        self.grain_index = np.zeros(self.n, dtype=np.int64)
        self._grain_seeds: list[int] = []
        self._grain = np.zeros((0, GRAIN * GRAIN), dtype=np.float32)
        self._tables: list[CameraTable] = []
        self._stack: tuple[np.ndarray, ...] | None = None
        self._sky: tuple[np.ndarray, np.ndarray] = (np.full((0, self.height), -1, dtype=np.int64),
                                                    np.zeros((self.n, 0, self.width, 3), dtype=np.uint8))
        self._sky_stale = np.ones(self.n, dtype=np.bool_)
        self._any_stale = True  # ``_sky_stale.any()``, as a bool (read at every frame)
        self._empty_cull: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
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
        self._sky_stale[i] = self._any_stale = True
        self.gain[i] = np.asarray(p.light_rgb) * p.contrast
        self.mat_rgb[i, 1:] = [getattr(p, name) for name in MATERIAL_PARAMS[1:]]
        if p.texture_seed not in self._grain_seeds:
            self._grain_seeds.append(p.texture_seed)
            self._grain = np.concatenate([self._grain, grain_table(p.texture_seed)[None]])
        self.grain_index[i] = self._grain_seeds.index(p.texture_seed)
        table = camera_table(p)
        if not any(t is table for t in self._tables):
            self._tables.append(table)
            self._stack = None
        self.cam_index[i] = next(k for k, t in enumerate(self._tables) if t is table)

    def _no_objects(self, n_k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Empty culling arrays (vis, nvis, box) for ``n_k`` sub-frames, kept between frames."""
        cached = self._empty_cull
        if cached is None or cached[1].shape != (self.n, n_k):
            cached = self._empty_cull = (np.empty((self.n, n_k, 0), dtype=np.int64),
                                         np.zeros((self.n, n_k), dtype=np.int64),
                                         np.empty((self.n, n_k, 0, 4), dtype=np.int64))
        return cached

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
                np.array([t.model.rows_are_lines for t in self._tables]),
                np.stack([t.gx for t in self._tables]).astype(np.float64),
                np.stack([t.gy for t in self._tables]).astype(np.float64),
                np.stack(levels),
                np.stack([np.where((~t.sky).any(axis=1), 0, t.sky.shape[1]) for t in self._tables]).astype(np.int64),
                np.stack([t.sky_mix for t in self._tables]).astype(np.float32),
                np.stack([t.vignette for t in self._tables]).astype(np.float32),
                np.stack([pixel_rays(t.model) for t in self._tables]),
                np.array([camera_row(t.model) for t in self._tables]),
            )
            self._sky = self._sky_slots(self._stack[4])
            self._sky_stale[:] = self._any_stale = True
        return self._stack

    def _sky_slots(self, ground_from: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(sky_slot (C, H), an empty sky cache (N, S, W, 3)) for cameras whose all-sky rows are
        ``ground_from >= W``; no slots (all -1) when the cache would pass ``SKY_CACHE_BYTES``."""
        all_sky = ground_from >= self.width
        slots = np.where(all_sky, np.cumsum(all_sky, axis=1) - 1, -1).astype(np.int64)
        depth = int(all_sky.sum(axis=1).max(initial=0))
        if self.n * depth * self.width * 3 > SKY_CACHE_BYTES:
            slots[:] = -1
            depth = 0
        return slots, np.zeros((self.n, depth, self.width, 3), dtype=np.uint8)

    def _fill_sky(self, args: tuple) -> None:
        """Store the all-sky rows of the robots whose appearance changed in the sky cache, rendered by the
        kernel itself with the cache off, so that the copies are the bytes the kernel would compute."""
        slots, cache = self._sky
        stale = np.flatnonzero(self._sky_stale)
        self._sky_stale[:] = self._any_stale = False
        if cache.shape[1] == 0:
            return
        off = np.full_like(slots, -1)
        for n in stale.tolist():
            rows = np.flatnonzero(slots[self.cam_index[n]] >= 0)
            if not rows.size or self.post[n, 1] > 0.0 or self.post[n, 2] > 0.0:
                continue  # noise or vignetting: the kernel computes every pixel, never copies
            one = slice(n, n + 1)
            n_k = args[_ARG["poses"]].shape[1]
            a = list(args)
            a[_ARG["out"]] = scratch = np.empty((1, self.height, self.width, 3), dtype=np.uint8)
            for j in _ROBOT_ARGS:
                a[j] = args[j][one]
            a[_ARG["k_count"]] = np.ones(1, dtype=np.int64)
            a[_ARG["vis"]], a[_ARG["nvis"]], a[_ARG["obj_box"]] = (  # no objects
                np.empty((1, n_k, 0), dtype=np.int64), np.zeros((1, n_k), dtype=np.int64),
                np.empty((1, n_k, 0, 4), dtype=np.int64))
            a[_ARG["sky_slot"]] = off
            breaks = np.flatnonzero(np.diff(rows) != 1) + 1
            for run in np.split(rows, breaks):
                render_rows(int(run[0]), int(run[-1]) + 1, *a)
            cache[n, slots[self.cam_index[n], rows]] = scratch[0, rows]

    def render(
        self, poses: np.ndarray, seeds: np.ndarray, frames: np.ndarray, out: np.ndarray | None = None,
        k_count: np.ndarray | None = None, moving: np.ndarray | None = None, ranges: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frames (N, H, W, 3) uint8 for sub-frame poses (N, K, 3) [m, m, rad]; K > 1 averages (motion blur).

        ``seeds`` and ``frames`` (N,) key the sensor noise, so a frame is reproducible on its own;
        ``k_count`` (N,) limits how many of the K sub-frames each robot averages (default all); 0 skips the
        robot (its frame is left as it was in ``out``). ``out`` may have fewer rows than N: only those
        robots are drawn.

        ``moving`` (Q, PF) are primitives beside the map's objects that not every robot sees (each episode's
        own NPCs, pedestrians, extra duckies, at their current poses): robot n sees rows ``lo .. hi - 1`` of
        them less ``skip_lo .. skip_hi - 1``, with ``ranges[n]`` = (lo, hi, skip_lo, skip_hi).
        """
        poses = np.asarray(poses, dtype=np.float64).reshape(self.n, -1, 3)
        if k_count is None:
            k_count = np.full(self.n, poses.shape[1], dtype=np.int64)
        linear, gx, gy, level_map, ground_from, sky_mix, vignette, rays, cams = self._prepare()
        if out is None:
            out = np.empty((self.n, self.height, self.width, 3), dtype=np.uint8)
        la, tx = self.lanes, self.tex
        prims = self.objects.prims
        n_static = prims.shape[0]
        if moving is not None and moving.shape[0]:
            prims = np.concatenate([prims, moving])
            ranges = np.asarray(ranges, dtype=np.int64) + n_static
        else:
            ranges = np.zeros((self.n, 4), dtype=np.int64)
        k_count = np.asarray(k_count, dtype=np.int64)
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        if prims.shape[0]:
            n_k = poses.shape[1]
            vis = np.empty((self.n, n_k, prims.shape[0]), dtype=np.int64)
            nvis = np.zeros((self.n, n_k), dtype=np.int64)
            box = np.empty((self.n, n_k, prims.shape[0], 4), dtype=np.int64)
            cull_objects(poses, k_count, self.cam_index, cams, prims, n_static, ranges, self.object_range, self.width,
                         self.height, vis, nvis, box)
        else:  # nothing to draw: the kernel reads only ``nvis`` (all zero), so these are reused, never written
            vis, nvis, box = self._no_objects(poses.shape[1])
        args = (
            out, poses, self.cam_index, linear, gx, gy, level_map,
            ground_from, sky_mix, vignette, la.tile_kind, self._affine, self._base, 1.0 / la.tile_size,
            tx.texels, tx.offsets, tx.size, self.palette, self.sky, self.offset, self.post,
            _as(seeds, np.uint64), _as(frames, np.int64),
            k_count, self._grain, self.grain_index, rays, cams, prims, vis, nvis, box, self.gain, self.mat_rgb,
            *self._sky,
        )
        if self._any_stale:
            self._fill_sky(args)
        rows = out.shape[0] * self.height
        work = int(k_count[: out.shape[0]].sum()) * self.height * self.width
        # one thread or all, by timing both on batches of this size (domain.parallelism)
        threads = ThreadChoice.shared((rows, self.width, poses.shape[1]))
        parallel = threads.parallel(work) and claim_threads()
        t0 = time.perf_counter()
        if parallel:
            try:
                workers = threads_available()
                # about 16 chunks per thread: small enough that a parked thread holds up little of the frame
                chunk = max(1, rows // (16 * workers))
                render_parallel(workers, np.zeros(1, dtype=np.int64), chunk, *args)
            finally:
                release_threads()
        else:
            render_rows(0, rows, *args)
        threads.record(parallel, time.perf_counter() - t0, work)
        return out
