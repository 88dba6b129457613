"""Plots people would rather look at than read: trajectories on the map, metric comparisons."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from proxybench.domain.maps import Map
from proxybench.domain.topdown import map_image
from proxybench.tasks.trajectory import Trajectory

__all__ = ["plot_trajectories"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_trajectories(m: Map, groups: Mapping[str, Sequence[Trajectory]], path: str | Path,
                      titles: Mapping[str, str] | None = None) -> Path:
    """One panel per group: every trajectory of the group drawn over the top-down map."""
    plt = _pyplot()
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
    path = Path(path)
    fig.savefig(path, dpi=110)
    if path.suffix == ".png":
        fig.savefig(path.with_suffix(".svg"))
    plt.close(fig)
    return path
