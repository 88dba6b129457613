"""Plots people would rather look at than read: trajectories on the map, metric comparisons."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from proxybench.domain.maps import Map
    from proxybench.tasks.trajectory import Trajectory

__all__ = ["plot_deviation_curves", "plot_trajectories", "pyplot", "save_figure"]


def pyplot():
    """matplotlib's pyplot, drawing off-screen (no display on servers and CI)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: Path) -> Path:
    """PNG at 110 dpi and, beside a PNG, an SVG (reports embed the PNG; the SVG is for papers); the figure is
    closed."""
    fig.savefig(path, dpi=110)
    if path.suffix == ".png":
        fig.savefig(path.with_suffix(".svg"))
    pyplot().close(fig)
    return path


def plot_trajectories(m: Map, groups: Mapping[str, Sequence[Trajectory]], path: str | Path,
                      titles: Mapping[str, str] | None = None) -> Path:
    """One panel per group: every trajectory of the group drawn over the top-down map."""
    from proxybench.domain.topdown import map_image

    plt = pyplot()
    n = len(groups)
    w, h = m.size_m
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 4.4), squeeze=False)
    img = map_image(m, 64)
    for ax, (name, trajs) in zip(axes[0], groups.items(), strict=True):
        ax.imshow(img, extent=(0, w, 0, h), origin="upper")
        for tr in trajs:
            ax.plot(tr["x"], tr["y"], lw=0.8, alpha=0.8)
        ax.set_title((titles or {}).get(name, name), fontsize=9)
        ax.set_xlim(0, w)
        ax.set_ylim(0, h)
        ax.set_xlabel("x [m]")
    axes[0][0].set_ylabel("y [m]")
    fig.tight_layout()
    return save_figure(fig, Path(path))


def plot_deviation_curves(curves: Mapping[str, object], path: str | Path,
                          titles: Mapping[str, str] | None = None) -> Path:
    """Thesis figs. 5.8–5.10: MPD(s) and MOD(s), mean over runs ± one standard deviation, along the lane.

    ``curves``: design name → :class:`proxybench.tasks.metrics.DeviationCurves`.
    """
    import numpy as np

    plt = pyplot()
    n = len(curves)
    fig, axes = plt.subplots(2, n, figsize=(4.2 * n, 5.2), squeeze=False, sharey="row")
    for k, (name, c) in enumerate(curves.items()):
        ok = c.runs_at >= 2
        for row, (values, what, unit) in enumerate(((c.lateral_cm, "MPD: lateral offset", "cm"),
                                                    (c.heading_deg, "MOD: heading error", "deg"))):
            ax = axes[row][k]
            v = values[:, ok]
            m, sd = np.nanmean(v, axis=0), np.nanstd(v, axis=0, ddof=1)
            for run in v:
                ax.plot(c.s[ok], run, color="grey", lw=0.5, alpha=0.5)
            ax.fill_between(c.s[ok], m - sd, m + sd, color="tab:blue", alpha=0.25, lw=0, label="mean ± 1 std over runs")
            ax.plot(c.s[ok], m, color="tab:blue", lw=1.5, label="mean over runs")
            ax.axhline(0.0, color="black", lw=0.6)
            ax.set_ylabel(f"{what} [{unit}]" if k == 0 else "")
            if row == 0:
                ax.set_title((titles or {}).get(name, name), fontsize=9)
            else:
                ax.set_xlabel("distance along the lane [m]")
    axes[0][0].plot([], [], color="grey", lw=0.5, label="one run")
    axes[0][0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    return save_figure(fig, Path(path))
