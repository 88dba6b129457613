"""Camera renderer: one fused, compiled per-pixel kernel for a whole batch of robots.

For every pixel the ground point is precomputed in the robot frame (``camera.CameraTable``), so a
frame costs one rotation + translation per pixel and sub-frame, a tile lookup, one texel fetch from the
mip level that matches the pixel's footprint, and a palette lookup. Light, contrast and the road
colours are folded into each robot's palette beforehand (they are linear), so the inner loop does no
colour arithmetic beyond ``palette * texture_noise * shade + offset``. No NumPy temporaries: the whole
pipeline (motion blur, light, vignetting, contrast, sensor noise) is one Numba loop, parallel over the
image rows of all robots.

Appearance is per robot (``Renderer.set_params``), so a batch can randomise it per episode.

Map objects (``proxybench.domain.objects``) are upright cylinders and boxes, flat-shaded. Per robot and
sub-frame, ``cull_objects`` keeps those within ``OBJECT_RANGE`` of the camera whose bounding box projects
into the image, with its image box (pinhole; a fisheye camera tests them over the whole image). Only
image rows some box touches take the object path: the row's ground (or sky) colour is computed as usual,
then each pixel in a box casts its ray (``rays`` table, robot frame, turned into the map frame) against
the primitive and takes its colour where the hit is nearer than the ground. Every other row is rendered
by exactly the object-free code, so frames without objects in view are bit-identical to before.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba as nb
import numpy as np

from proxybench.domain.camera import CameraModel, CameraTable, camera_table
from proxybench.domain.lanes import LaneArrays
from proxybench.domain.maps import MapObject
from proxybench.domain.objects import BOX, ObjectArrays, pack_objects
from proxybench.domain.params import DomainParams
from proxybench.domain.textures import marking_textures

__all__ = ["OBJECT_RANGE", "Renderer", "cull_objects", "render_kernel"]

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

#: light direction for flat-shading objects (map frame, unit), and the ambient share of their colour
_LX, _LY, _LZ = 0.3713906763541037, 0.5570860145311556, 0.7427813527082074
_AMBIENT = 0.6
#: objects farther than this from the camera [m] are not drawn
OBJECT_RANGE = 3.0


@nb.njit(cache=True, inline="always")
def _slab(p, d, half):
    """(hit possible, t_enter, t_exit) of the ray p + t·d through the slab |x| <= half (±inf when parallel)."""
    if abs(d) < 1e-12:
        if p < -half or p > half:
            return False, 0.0, 0.0
        return True, -np.inf, np.inf
    t1 = (-half - p) / d
    t2 = (half - p) / d
    if t1 > t2:
        t1, t2 = t2, t1
    return True, t1, t2


@nb.njit(cache=True, inline="always")
def _hit_primitive(ox, oy, oz, dx, dy, dz, prim):
    """(t, nx, ny, nz): first hit of the ray O + t D (t > 0) with an upright cylinder or box; t = inf on a miss."""
    inf = np.inf
    rx = ox - prim[1]
    ry = oy - prim[2]
    z0 = prim[7]
    z1 = prim[8]
    # vertical slab
    if abs(dz) < 1e-12:
        if oz < z0 or oz > z1:
            return inf, 0.0, 0.0, 0.0
        tz_lo = -inf
        tz_hi = inf
    else:
        ta = (z0 - oz) / dz
        tb = (z1 - oz) / dz
        tz_lo = min(ta, tb)
        tz_hi = max(ta, tb)
    nzc = 1.0 if dz < 0.0 else -1.0  # normal of the cap the ray enters through
    if prim[0] == BOX:
        c = prim[3]
        s = prim[4]
        lx = c * rx + s * ry
        ly = -s * rx + c * ry
        ldx = c * dx + s * dy
        ldy = -s * dx + c * dy
        t_in = tz_lo
        t_out = tz_hi
        nx = 0.0
        ny = 0.0
        nz = nzc
        ok, t1, t2 = _slab(lx, ldx, prim[5])
        if not ok:
            return inf, 0.0, 0.0, 0.0
        if t1 > t_in:
            t_in = t1
            sg = -1.0 if ldx > 0.0 else 1.0
            nx = sg * c
            ny = sg * s
            nz = 0.0
        t_out = min(t_out, t2)
        ok, t1, t2 = _slab(ly, ldy, prim[6])
        if not ok:
            return inf, 0.0, 0.0, 0.0
        if t1 > t_in:
            t_in = t1
            sg = -1.0 if ldy > 0.0 else 1.0
            nx = -sg * s
            ny = sg * c
            nz = 0.0
        t_out = min(t_out, t2)
        if t_in >= t_out or t_in <= 0.0:
            return inf, 0.0, 0.0, 0.0
        return t_in, nx, ny, nz
    r = prim[5]
    qa = dx * dx + dy * dy
    qc = rx * rx + ry * ry - r * r
    if qa < 1e-18:
        if qc > 0.0:
            return inf, 0.0, 0.0, 0.0
        t_in = tz_lo
        t_out = tz_hi
        side = False
    else:
        qb = rx * dx + ry * dy
        disc = qb * qb - qa * qc
        if disc < 0.0:
            return inf, 0.0, 0.0, 0.0
        sq = math.sqrt(disc)
        ts0 = (-qb - sq) / qa
        ts1 = (-qb + sq) / qa
        side = ts0 >= tz_lo
        t_in = max(ts0, tz_lo)
        t_out = min(ts1, tz_hi)
    if t_in >= t_out or t_in <= 0.0:
        return inf, 0.0, 0.0, 0.0
    if side:
        return t_in, (rx + t_in * dx) / r, (ry + t_in * dy) / r, 0.0
    return t_in, 0.0, 0.0, nzc


@nb.njit(cache=True)
def cull_objects(poses, k_count, cam_index, cams, prims, max_range, w, h, vis, nvis, box):
    """Per robot n and sub-frame k: the primitives worth testing, ``vis[n, k, :nvis[n, k]]``, and each one's
    image box ``box[n, k, j]`` = (u0, u1, v0, v1) (end exclusive).

    ``cams[c]`` = (forward, height, sin pitch, cos pitch, fx, fy, cx, cy, pinhole). A primitive is kept if it
    is within ``max_range`` of the camera and, for a pinhole camera, if its bounding box projects into the
    image (its projected corners, clipped at the near plane, bound it, plus a pixel). Fisheye cameras get
    the whole image as the box.
    """
    near = 1e-3
    cxs = np.empty(8)
    cys = np.empty(8)
    czs = np.empty(8)
    for n in range(poses.shape[0]):
        c = cam_index[n]
        fwd = cams[c, 0]
        hgt = cams[c, 1]
        sa = cams[c, 2]
        ca = cams[c, 3]
        fx = cams[c, 4]
        fy = cams[c, 5]
        cx = cams[c, 6]
        cy = cams[c, 7]
        pinhole = cams[c, 8] > 0.5
        for k in range(k_count[n]):
            px = poses[n, k, 0]
            py = poses[n, k, 1]
            cs = math.cos(poses[n, k, 2])
            sn = math.sin(poses[n, k, 2])
            ox = px + cs * fwd
            oy = py + sn * fwd
            cnt = 0
            for p in range(prims.shape[0]):
                pa = prims[p, 5]
                pb = prims[p, 6]
                rad = math.sqrt(pa * pa + pb * pb)
                ddx = prims[p, 1] - ox
                ddy = prims[p, 2] - oy
                if math.sqrt(ddx * ddx + ddy * ddy) - rad > max_range:
                    continue
                u0, u1, v0, v1 = 0, w, 0, h
                if pinhole:
                    pc = prims[p, 3]
                    ps = prims[p, 4]
                    # camera-frame corners (x right, y down, z forward) of the primitive's bounding box
                    for corner in range(8):
                        lx = pa if (corner & 1) else -pa
                        ly = pb if (corner & 2) else -pb
                        z = prims[p, 8] if (corner & 4) else prims[p, 7]
                        wx = prims[p, 1] + pc * lx - ps * ly - px
                        wy = prims[p, 2] + ps * lx + pc * ly - py
                        xr = cs * wx + sn * wy - fwd
                        zr = z - hgt
                        cxs[corner] = -(-sn * wx + cs * wy)
                        cys[corner] = -xr * sa - zr * ca
                        czs[corner] = xr * ca - zr * sa
                    umin = np.inf
                    umax = -np.inf
                    vmin = np.inf
                    vmax = -np.inf
                    front = 0
                    for corner in range(8):
                        if czs[corner] >= near:
                            front += 1
                            uu = fx * cxs[corner] / czs[corner] + cx
                            vv = fy * cys[corner] / czs[corner] + cy
                            umin = min(umin, uu)
                            umax = max(umax, uu)
                            vmin = min(vmin, vv)
                            vmax = max(vmax, vv)
                    if front == 0:
                        continue
                    if front < 8:  # clip the box's edges at the near plane: the crossing points bound it too
                        for a0 in range(8):
                            for bit in (1, 2, 4):
                                a1 = a0 | bit
                                if a1 == a0 or (czs[a0] >= near) == (czs[a1] >= near):
                                    continue
                                f = (near - czs[a0]) / (czs[a1] - czs[a0])
                                uu = fx * (cxs[a0] + f * (cxs[a1] - cxs[a0])) / near + cx
                                vv = fy * (cys[a0] + f * (cys[a1] - cys[a0])) / near + cy
                                umin = min(umin, uu)
                                umax = max(umax, uu)
                                vmin = min(vmin, vv)
                                vmax = max(vmax, vv)
                    u0 = max(int(math.floor(max(umin, -1e6))) - 1, 0)
                    u1 = min(int(math.floor(min(umax, 1e6))) + 2, w)
                    v0 = max(int(math.floor(max(vmin, -1e6))) - 1, 0)
                    v1 = min(int(math.floor(min(vmax, 1e6))) + 2, h)
                    if u0 >= u1 or v0 >= v1:
                        continue
                vis[n, k, cnt] = p
                box[n, k, cnt, 0] = u0
                box[n, k, cnt, 1] = u1
                box[n, k, cnt, 2] = v0
                box[n, k, cnt, 3] = v1
                cnt += 1
            nvis[n, k] = cnt


@nb.njit(cache=True, inline="always")
def _draw_objects(tmp, hit, tbest, v, ox, oy, oz, cs, sn, rays_r, lv_r, prims, vis_nk, box_nk, n_vis, gain_n):
    """Overwrite the pixels of row ``v`` (sub-frame colours ``tmp``) whose ray meets an object before the ground."""
    w = tmp.shape[0]
    for u in range(w):
        tbest[u] = np.inf
    for j in range(n_vis):
        if v < box_nk[j, 2] or v >= box_nk[j, 3]:
            continue
        prim = prims[vis_nk[j]]
        for u in range(box_nk[j, 0], box_nk[j, 1]):
            drx = rays_r[u, 0]
            dry = rays_r[u, 1]
            dz = rays_r[u, 2]
            dx = cs * drx - sn * dry
            dy = sn * drx + cs * dry
            t_lim = tbest[u]
            if lv_r[u] >= 0 and dz < -1e-9:
                t_lim = min(t_lim, oz / -dz)
            t, nx, ny, nz = _hit_primitive(ox, oy, oz, dx, dy, dz, prim)
            if t < t_lim:
                tbest[u] = t
                shade = _AMBIENT + (1.0 - _AMBIENT) * max(nx * _LX + ny * _LY + nz * _LZ, 0.0)
                tmp[u, 0] = prim[9] * shade * gain_n[0]
                tmp[u, 1] = prim[10] * shade * gain_n[1]
                tmp[u, 2] = prim[11] * shade * gain_n[2]
                hit[u] = True


@nb.njit(cache=True, parallel=True, fastmath=True, error_model="numpy", boundscheck=False)
def render_kernel(
    out, poses, cam_index, linear, gx, gy, level_map, ground_from, sky_mix, vignette,
    tile_kind, tile_affine, tile_base, inv_ts, tex, tex_off, tex_size,
    palette, sky, offset, post, seeds, frames, k_count, grain, grain_index,
    rays, cams, prims, vis, nvis, obj_box, gain,
):
    """Render ``out[n]`` (H, W, 3 uint8) for every robot n from its K sub-frame poses ``poses[n]``.

    ``palette[n]`` holds robot n's colours already multiplied by light and contrast; ``offset[n]`` is
    the per-channel value added after (brightness and contrast pivot). ``level_map < 0`` marks sky;
    ``ground_from[c, v] < W`` if row v of camera c sees any ground. ``linear[c]``: camera c's rows are
    straight lines on the ground (pinhole, where a row is all sky or all ground), so the span
    renderer applies. ``post[n]`` = (texture_noise,
    noise_std, vignetting, -). Robot n averages the first ``k_count[n]`` sub-frames and reads surface
    grain ``grain[grain_index[n]]``.

    Objects: ``rays[c, v, u]`` is pixel (u, v)'s ray direction in the robot frame, ``cams`` the camera
    mountings, ``prims`` the object primitives and ``vis``, ``nvis``, ``obj_box`` their per robot and
    sub-frame culling (``cull_objects``); ``gain[n]`` is robot n's light × contrast. Rows no visible
    primitive's box touches take exactly the object-free path.
    """
    n_envs, h, w, _ = out.shape
    n_pal = palette.shape[1] - 5
    for row in nb.prange(n_envs * h):
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
        amp = np.empty(16)
        for lv in range(16):
            amp[lv] = tex_noise / (1 << lv)  # averaging 4^L texels shrinks the grain by 2^L
        gx_r = gx[c, v]
        gy_r = gy[c, v]
        lv_r = level_map[c, v]
        acc = np.empty((w, 3))
        is_ground = ground_from[c, v] < w
        any_obj = False
        for k in range(k_sub):
            for j in range(nvis[n, k]):
                if obj_box[n, k, j, 2] <= v < obj_box[n, k, j, 3]:
                    any_obj = True
        hit = np.zeros(w if any_obj else 1, dtype=np.bool_)
        if any_obj:
            tmp = np.empty((w, 3))
            tbest = np.empty(w)
            mix_o = sky_mix[c, v]
            rays_r = rays[c, v]
            fwd = cams[c, 0]
            hgt = cams[c, 1]
            for k in range(k_sub):
                cs = math.cos(pose_n[k, 2])
                sn = math.sin(pose_n[k, 2])
                buf = acc if k == 0 else tmp  # sub-frame 0 is drawn in place, later ones are added
                if is_ground and linear[c]:
                    du = 1.0 / (w - 1) if w > 1 else 0.0
                    px0 = gx_r[0]
                    py0 = gy_r[0]
                    dpx = (gx_r[w - 1] - px0) * du
                    dpy = (gy_r[w - 1] - py0) * du
                    X0 = pose_n[k, 0] + cs * px0 - sn * py0
                    Y0 = pose_n[k, 1] + sn * px0 + cs * py0
                    dX = cs * dpx - sn * dpy
                    dY = sn * dpx + cs * dpy
                    _span_row(buf, True, X0, Y0, dX, dY, lv_r, 0, w, amp, pal, grain_n, inv_ts, tile_kind,
                              tile_affine, tile_base, tex, tex_off, tex_size, n_pal)
                else:
                    for u in range(w):
                        level = lv_r[u]
                        if level < 0:
                            m = mix_o[u]
                            buf[u, 0] = sky[n, _HORIZON, 0] * (1.0 - m) + sky[n, _SKY, 0] * m
                            buf[u, 1] = sky[n, _HORIZON, 1] * (1.0 - m) + sky[n, _SKY, 1] * m
                            buf[u, 2] = sky[n, _HORIZON, 2] * (1.0 - m) + sky[n, _SKY, 2] * m
                            continue
                        X = pose_n[k, 0] + cs * gx_r[u] - sn * gy_r[u]
                        Y = pose_n[k, 1] + sn * gx_r[u] + cs * gy_r[u]
                        r, g, b = _pixel_ground(X, Y, level, amp, pal, grain_n, inv_ts, tile_kind, tile_affine,
                                                tile_base, tex, tex_off, tex_size, n_pal)
                        buf[u, 0] = r
                        buf[u, 1] = g
                        buf[u, 2] = b
                _draw_objects(buf, hit, tbest, v, pose_n[k, 0] + cs * fwd, pose_n[k, 1] + sn * fwd, hgt, cs, sn,
                              rays_r, lv_r, prims, vis[n, k], obj_box[n, k], nvis[n, k], gain[n])
                if k > 0:
                    for u in range(w):
                        acc[u, 0] += tmp[u, 0]
                        acc[u, 1] += tmp[u, 1]
                        acc[u, 2] += tmp[u, 2]
        elif is_ground and linear[c]:
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


def _pixel_rays(model: CameraModel) -> np.ndarray:
    """(H, W, 3) robot-frame ray direction of every pixel centre (same scale as ``CameraModel.rays``)."""
    v, u = np.meshgrid(np.arange(model.height) + 0.5, np.arange(model.width) + 0.5, indexing="ij")
    return np.ascontiguousarray(model.rays(u, v), dtype=np.float64)


def _camera_row(model: CameraModel) -> list[float]:
    """(forward, height, sin pitch, cos pitch, fx, fy, cx, cy, pinhole) for ``cull_objects``."""
    a = math.radians(model.pitch)
    return [model.forward, model.mount_height, math.sin(a), math.cos(a), model.fx, model.fy, model.cx, model.cy,
            1.0 if model.distortion is None else 0.0]


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
        if objects is None:
            objects = ()
        self.objects = objects if isinstance(objects, ObjectArrays) else pack_objects(objects)
        self.object_range = float(object_range)
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
        self.gain[i] = np.asarray(p.light_rgb) * p.contrast
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
                np.stack([_pixel_rays(t.model) for t in self._tables]),
                np.array([_camera_row(t.model) for t in self._tables]),
            )
        return self._stack

    def render(
        self, poses: np.ndarray, seeds: np.ndarray, frames: np.ndarray, out: np.ndarray | None = None,
        k_count: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frames (N, H, W, 3) uint8 for sub-frame poses (N, K, 3) [m, m, rad]; K > 1 averages (motion blur).

        ``seeds`` and ``frames`` (N,) key the sensor noise, so a frame is reproducible on its own;
        ``k_count`` (N,) limits how many of the K sub-frames each robot averages (default all); 0 skips the
        robot (its frame is left as it was in ``out``).
        """
        poses = np.asarray(poses, dtype=np.float64).reshape(self.n, -1, 3)
        if k_count is None:
            k_count = np.full(self.n, poses.shape[1], dtype=np.int64)
        linear, gx, gy, level_map, ground_from, sky_mix, vignette, rays, cams = self._prepare()
        if out is None:
            out = np.empty((self.n, self.height, self.width, 3), dtype=np.uint8)
        la, tx = self.lanes, self.tex
        prims = self.objects.prims
        k_count = np.asarray(k_count, dtype=np.int64)
        n_k = poses.shape[1]
        vis = np.empty((self.n, n_k, prims.shape[0]), dtype=np.int64)
        nvis = np.zeros((self.n, n_k), dtype=np.int64)
        box = np.empty((self.n, n_k, prims.shape[0], 4), dtype=np.int64)
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        if prims.shape[0]:
            cull_objects(poses, k_count, self.cam_index, cams, prims, self.object_range, self.width, self.height,
                         vis, nvis, box)
        render_kernel(
            out, poses, self.cam_index, linear, gx, gy, level_map,
            ground_from, sky_mix, vignette, la.tile_kind, self._affine, self._base, 1.0 / la.tile_size,
            tx.texels, tx.offsets, tx.size, self.palette, self.sky, self.offset, self.post,
            np.asarray(seeds).astype(np.uint64), np.asarray(frames).astype(np.int64),
            k_count, self._grain, self.grain_index, rays, cams, prims, vis, nvis, box, self.gain,
        )
        return out
