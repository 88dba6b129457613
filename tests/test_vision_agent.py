"""The vision agent's compiled lane estimate is the NumPy pipeline it replaced (segment, project, lstsq fits)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from proxybench.agents.vision import (
    WHITE_OFFSET,
    YELLOW_OFFSET,
    AssumedCamera,
    _ground_grid,
    estimate_lane,
)
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator


def _fit_line_numpy(x, y, trim=0.03):
    if x.size < 6:
        return None
    for _ in range(2):
        A = np.stack([np.ones_like(x), x], axis=1)
        (a, b), *_ = np.linalg.lstsq(A, y, rcond=None)
        keep = np.abs(y - (a + b * x)) < trim
        if keep.sum() < 6 or keep.all():
            break
        x, y = x[keep], y[keep]
    return float(a), float(b)


def estimate_lane_numpy(img, cam, step=4, max_range=0.45):
    """The pipeline as it was written with NumPy array expressions and ``np.linalg.lstsq``."""
    h, w = img.shape[:2]
    gx, gy = _ground_grid(cam, w, h, step)
    sub = img[step // 2 :: step, step // 2 :: step][: gx.shape[0], : gx.shape[1]].astype(np.int16)
    r, g, b = sub[..., 0], sub[..., 1], sub[..., 2]
    lo, hi = np.minimum(np.minimum(r, g), b), np.maximum(np.maximum(r, g), b)
    white, yellow = (lo > 150) & (hi - lo < 50), (r > 140) & (g > 100) & (b < 110) & (r - b > 90)
    near = np.isfinite(gx) & (gx > 0.05) & (gx < max_range)
    out = []
    yl = yellow & near
    line_y = _fit_line_numpy(gx[yl], gy[yl])
    if line_y is not None:
        a, b_ = line_y
        out.append(((-(a - YELLOW_OFFSET * math.hypot(1.0, b_)), -math.atan(b_)), int(yl.sum())))
    wl = white & near & ((gy < line_y[0] + line_y[1] * gx - 0.1) if line_y is not None else (gy < 0.15))
    line_w = _fit_line_numpy(gx[wl], gy[wl])
    if line_w is not None:
        a, b_ = line_w
        out.append(((-(a + WHITE_OFFSET * math.hypot(1.0, b_)), -math.atan(b_)), int(wl.sum())))
    if not out:
        return None
    wsum = float(sum(n for _, n in out))
    return (sum(e[0] * n for e, n in out) / wsum, sum(e[1] * n for e, n in out) / wsum,
            out[0][1] if line_y is not None else 0, out[-1][1] if line_w is not None else 0)


def _frames():
    base = DomainParams(image_width=160, image_height=120)
    sim = Simulator("loop_3x3", [base, base.replace(camera_pitch=25.0, light_rgb=[1.2] * 3)])
    rng = np.random.default_rng(7)
    for k in range(12):
        for i in range(2):
            sim.reset(i, 100 * k + i)
        sim.step(rng.uniform(0.0, 0.6, (2, 2)))
        yield from sim.render()


@pytest.mark.parametrize("cam", [AssumedCamera(), AssumedCamera(pitch=15.0), AssumedCamera(fov_y=90.0)])
def test_compiled_estimate_equals_the_numpy_pipeline(cam):
    seen = 0
    for frame in _frames():
        got, ref = estimate_lane(frame, cam), estimate_lane_numpy(frame, cam)
        assert (got is None) == (ref is None)
        if ref is not None:
            seen += 1
            assert (got.n_yellow, got.n_white) == ref[2:]
            assert got.lateral == pytest.approx(ref[0], abs=1e-9)
            assert got.heading_error == pytest.approx(ref[1], abs=1e-9)
    assert seen >= 12  # the frames do show markings


def test_no_markings_no_estimate():
    assert estimate_lane(np.zeros((120, 160, 3), np.uint8), AssumedCamera()) is None
