"""The object path of the camera renderer: culling map objects per robot and drawing them into rows.

Objects (``proxybench.domain.objects``) are upright cylinders and boxes, flat-shaded. Per robot and
sub-frame, ``cull_objects`` keeps those within ``OBJECT_RANGE`` of the camera whose bounding box projects
into the image, with its image box (pinhole; a fisheye camera tests them over the whole image). The
renderer's kernel (``proxybench.domain.renderer``) sends only image rows some box touches through
``draw_object_row``: each pixel in a box casts its ray (``pixel_rays``, robot frame, turned into the map
frame) against the primitive and takes its colour where the hit is nearer than the ground. A tag
(``objects.TAG``: an AprilTag lying flat) is sampled 4 × 4 times per pixel (``_tag_pixel``), so its cell
edges are anti-aliased as a camera's pixels average them: a detector finds their corners to a fraction of a
pixel, as it does in real images.

Kept apart from the ground renderer so that each stays readable; the kernels here are inlined into
``render_rows`` (after editing one, delete the Numba cache: ``find src -name '*.nbi' -delete``).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from proxybench.domain.apriltags import GRID
from proxybench.domain.camera import CameraModel
from proxybench.domain.objects import BOX, TAG

__all__ = ["OBJECT_RANGE", "camera_row", "cull_objects", "draw_object_row", "pixel_rays"]

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
def _box_sides(p, d, half, ax, ay, t_in, t_out, nx, ny, nz):
    """A box's pair of sides |p + t·d| <= half (box frame) clipping the ray's span ``t_in .. t_out``: (hit
    possible, t_in, t_out, nx, ny, nz), the normal ±(ax, ay, 0) (map frame) where the ray enters through them."""
    ok, t1, t2 = _slab(p, d, half)
    if not ok:
        return False, t_in, t_out, nx, ny, nz
    if t1 > t_in:
        t_in = t1
        sg = -1.0 if d > 0.0 else 1.0
        nx = sg * ax
        ny = sg * ay
        nz = 0.0
    return True, t_in, min(t_out, t2), nx, ny, nz


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
    if prim[0] >= BOX:  # a box, or a tag (a thin box)
        c = prim[3]
        s = prim[4]
        lx = c * rx + s * ry
        ly = -s * rx + c * ry
        ldx = c * dx + s * dy
        ldy = -s * dx + c * dy
        ok, t_in, t_out, nx, ny, nz = _box_sides(lx, ldx, prim[5], c, s, tz_lo, tz_hi, 0.0, 0.0, nzc)
        if not ok:
            return inf, 0.0, 0.0, 0.0
        ok, t_in, t_out, nx, ny, nz = _box_sides(ly, ldy, prim[6], -s, c, t_in, t_out, nx, ny, nz)
        if not ok:
            return inf, 0.0, 0.0, 0.0
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
def cull_objects(poses, k_count, cam_index, cams, prims, n_static, ranges, max_range, w, h, vis, nvis, box):
    """Per robot n and sub-frame k: the primitives worth testing, ``vis[n, k, :nvis[n, k]]``, and each one's
    image box ``box[n, k, j]`` = (u0, u1, v0, v1) (end exclusive).

    Robot n looks at the static primitives ``0 .. n_static - 1`` (the map's objects, shared by all) and at
    ``lo .. hi - 1`` less ``skip_lo .. skip_hi - 1`` with ``ranges[n]`` = (lo, hi, skip_lo, skip_hi): the
    objects of its own world (each episode of a batch has its own NPCs), less its own body.

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
            lo = ranges[n, 0]
            for q in range(n_static + ranges[n, 1] - lo):
                p = q if q < n_static else lo + q - n_static
                if ranges[n, 2] <= p < ranges[n, 3]:
                    continue
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


#: grey levels of a tag's white and black cells (printed paper, matte ink)
_TAG_WHITE, _TAG_BLACK = 235.0, 25.0
_TAG_SUB = 4  # samples per pixel edge


@nb.njit(cache=True)
def _tag_cell_white(code, cx, cy):
    """Whether cell (cx, cy) (column, row from the top, 0..GRID-1) of the tag with ``code`` is white."""
    if cx == 0 or cy == 0 or cx == GRID - 1 or cy == GRID - 1:
        return True
    if cx == 1 or cy == 1 or cx == GRID - 2 or cy == GRID - 2:
        return False
    k = (cy - 2) * (GRID - 4) + (cx - 2)
    return ((code >> (35 - k)) & 1) == 1


@nb.njit(cache=True)
def _tag_pixel(prim, ox, oy, oz, cs, sn, rays_c, u, v, prev):
    """Grey level of pixel (u, v) over the tag ``prim``: the mean of 4 × 4 sub-pixel rays (robot-frame rays
    interpolated between pixel centres, exact for a pinhole); a sample off the tag counts as ``prev``."""
    h, w = rays_c.shape[0], rays_c.shape[1]
    u1 = u + 1 if u + 1 < w else u - 1
    v1 = v + 1 if v + 1 < h else v - 1
    su = 1.0 if u + 1 < w else -1.0
    sv = 1.0 if v + 1 < h else -1.0
    code = np.int64(prim[9])
    half_a = prim[5]
    half_b = prim[6]
    z = prim[8]
    c = prim[3]
    s = prim[4]
    total = 0.0
    for i in range(_TAG_SUB):
        du = ((i + 0.5) / _TAG_SUB - 0.5) * su
        for j in range(_TAG_SUB):
            dv = ((j + 0.5) / _TAG_SUB - 0.5) * sv
            rx = rays_c[v, u, 0] + du * (rays_c[v, u1, 0] - rays_c[v, u, 0]) + dv * (rays_c[v1, u, 0] - rays_c[v, u, 0])
            ry = rays_c[v, u, 1] + du * (rays_c[v, u1, 1] - rays_c[v, u, 1]) + dv * (rays_c[v1, u, 1] - rays_c[v, u, 1])
            rz = rays_c[v, u, 2] + du * (rays_c[v, u1, 2] - rays_c[v, u, 2]) + dv * (rays_c[v1, u, 2] - rays_c[v, u, 2])
            if rz > -1e-12:
                total += prev
                continue
            t = (z - oz) / rz
            hx = ox + t * (cs * rx - sn * ry) - prim[1]
            hy = oy + t * (sn * rx + cs * ry) - prim[2]
            lx = c * hx + s * hy
            ly = -s * hx + c * hy
            fx = (lx + half_a) / (2.0 * half_a) * GRID
            fy = (half_b - ly) / (2.0 * half_b) * GRID
            if fx < 0.0 or fy < 0.0 or fx >= GRID or fy >= GRID:
                total += prev
            elif _tag_cell_white(code, int(fx), int(fy)):
                total += _TAG_WHITE
            else:
                total += _TAG_BLACK
    return total / (_TAG_SUB * _TAG_SUB)


@nb.njit(cache=True, inline="always")
def draw_object_row(tmp, hit, tbest, v, ox, oy, oz, cs, sn, rays_r, lv_r, prims, vis_nk, box_nk, n_vis, gain_n,
                    mat_n, rays_c):
    """Overwrite the pixels of row ``v`` (sub-frame colours ``tmp``) whose ray meets an object before the ground.

    A primitive of material m > 0 takes the robot's colour ``mat_n[m]`` instead of its own; a tag is drawn
    with its bit pattern, sampled by the rays ``rays_c`` (H, W, 3) of the whole camera.
    """
    w = tmp.shape[0]
    for u in range(w):
        tbest[u] = np.inf
    for j in range(n_vis):
        if v < box_nk[j, 2] or v >= box_nk[j, 3]:
            continue
        prim = prims[vis_nk[j]]
        mat = int(prim[12])
        red = prim[9] if mat == 0 else mat_n[mat, 0]
        green = prim[10] if mat == 0 else mat_n[mat, 1]
        blue = prim[11] if mat == 0 else mat_n[mat, 2]
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
                if prim[0] == TAG:  # the grey of its cells (off its edge: white paper)
                    red = green = blue = _tag_pixel(prim, ox, oy, oz, cs, sn, rays_c, u, v,
                                                    _TAG_WHITE) if nz > 0.5 else _TAG_WHITE
                tmp[u, 0] = red * shade * gain_n[0]
                tmp[u, 1] = green * shade * gain_n[1]
                tmp[u, 2] = blue * shade * gain_n[2]
                hit[u] = True


def pixel_rays(model: CameraModel) -> np.ndarray:
    """(H, W, 3) robot-frame ray direction of every pixel centre (same scale as ``CameraModel.rays``)."""
    v, u = np.meshgrid(np.arange(model.height) + 0.5, np.arange(model.width) + 0.5, indexing="ij")
    return np.ascontiguousarray(model.rays(u, v), dtype=np.float64)


def camera_row(model: CameraModel) -> list[float]:
    """(forward, height, sin pitch, cos pitch, fx, fy, cx, cy, pinhole) for ``cull_objects``; a camera with yaw
    or roll counts as not pinhole there (its objects are tested over the whole image)."""
    a = math.radians(model.pitch)
    return [model.forward, model.mount_height, math.sin(a), math.cos(a), model.fx, model.fy, model.cx, model.cy,
            1.0 if model.distortion is None and model.yaw == 0.0 and model.roll == 0.0 else 0.0]
