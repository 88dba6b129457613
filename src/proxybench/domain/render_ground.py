"""Ground shading of the camera renderer: the texel, grain and noise helpers of its kernel.

``span_row`` shades a run of pixels whose ground points lie on one line (a pinhole camera's row), tile
by tile, at two multiply-adds per pixel; ``curve_row`` shades a row pixel by pixel (the general path, for
lenses whose rows are curves). Surface grain is a small tileable table read at a per-tile offset, and
sensor noise a counter-based hash, so every pixel is reproducible on its own, whatever the batch.
All but ``curve_row`` are inlined into ``renderer.render_rows``, which calls ``curve_row`` (after editing
one, delete the Numba cache: ``find src -name '*.nbi' -delete``). Helpers that take arrays are called once
per row, never per pixel (see ``curve_row``: per pixel, their arguments' reference counting costs more
than the shading).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = ["GRAIN", "curve_row", "gauss_from_hash", "grain_table", "mix64", "span_row"]


@nb.njit(cache=True, inline="always")
def mix64(z):
    """splitmix64 finaliser: a counter-based random stream, identical for any batch layout."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@nb.njit(cache=True, inline="always")
def gauss_from_hash(h):
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
GRAIN = 64


def grain_table(seed: int) -> np.ndarray:
    """(_GRAIN², ) uniform [-1, 1) surface grain, fixed by the texture seed."""
    return np.random.default_rng(seed).uniform(-1.0, 1.0, GRAIN * GRAIN).astype(np.float32)


@nb.njit(cache=True, inline="always")
def span_row(
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
            f = 1.0 + grain_amp[level] * grain_n[(((ty + goy) & (GRAIN - 1)) << 6) | ((tx + gox) & (GRAIN - 1))]
            if first:
                acc[k, 0] = pal[idx, 0] * f
                acc[k, 1] = pal[idx, 1] * f
                acc[k, 2] = pal[idx, 2] * f
            else:
                acc[k, 0] += pal[idx, 0] * f
                acc[k, 1] += pal[idx, 1] * f
                acc[k, 2] += pal[idx, 2] * f
        u = end


@nb.njit(cache=True, fastmath=True, error_model="numpy", boundscheck=False)
def curve_row(
    acc, first, px, py, cs, sn, gx_r, gy_r, lv_r, grain_amp, pal, grain_n,
    inv_ts, tile_kind, tile_affine, tile_base, tex, tex_off, tex_size, n_pal,
):
    """Add (or, if ``first``, store) the ground colour of the ground pixels (``lv_r >= 0``) of one row into
    ``acc``; sky pixels are left as they are. The general path, for lenses whose rows are curves: pixel u's
    ground point is (``gx_r[u]``, ``gy_r[u]``) in the robot frame, placed on the map by the pose
    (``px``, ``py``, cos ``cs``, sin ``sn``).

    The per-pixel shading is written out in this loop on purpose. Numba inlines an ``inline="always"``
    helper at its own IR level, where each array argument becomes a new reference: the former per-pixel
    helper (``pixel_ground``) paid atomic reference-count pairs for its eight arrays at every pixel, 3.9×
    the time of a whole 160×120 fisheye frame (4.8× with 3 blur sub-frames) in the serial kernel. Per
    row, as here and in ``span_row``, that cost is lost in the noise.

    Called, not inlined: inlined, this loop made the kernel's pinhole rows ~1 % slower (code layout);
    called, it is itself ~1 % slower. Its flags are the kernel's (``fastmath`` included): the frames are
    bit-identical to those of the per-pixel helper.
    """
    n_i = tile_kind.shape[0]
    n_j = tile_kind.shape[1]
    outside = n_pal + 4
    for u in range(gx_r.shape[0]):
        level = lv_r[u]
        if level < 0:
            continue
        X = px + cs * gx_r[u] - sn * gy_r[u]
        Y = py + sn * gx_r[u] + cs * gy_r[u]
        fi = X * inv_ts
        fj = Y * inv_ts
        if fi < 0.0 or fj < 0.0 or fi >= n_i or fj >= n_j:
            r = pal[outside, 0]
            g = pal[outside, 1]
            b = pal[outside, 2]
        else:
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
            f = 1.0 + grain_amp[level] * grain_n[(((ty + goy) & (GRAIN - 1)) << 6) | ((tx + gox) & (GRAIN - 1))]
            r = pal[idx, 0] * f
            g = pal[idx, 1] * f
            b = pal[idx, 2] * f
        if first:
            acc[u, 0] = r
            acc[u, 1] = g
            acc[u, 2] = b
        else:
            acc[u, 0] += r
            acc[u, 1] += g
            acc[u, 2] += b
