"""The argmin-PRPV vs argmax-PLV comparison as a table, a figure and JSON."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from proxybench.experiments.plv_prpv.run import ChoiceResult
from proxybench.experiments.reporting import pyplot, save_figure

__all__ = ["plot_choice", "table_rows", "write_choice"]


def table_rows(res: ChoiceResult) -> list[dict[str, Any]]:
    """One row per candidate θ: PRPV with its order range and paired Δ, PLV with its interval, which picks it."""
    out = []
    for c in res.candidates:
        picks = [w for w, pick in (("argmin PRPV", res.prpv_pick), ("argmax PLV", res.plv_pick)) if c.label == pick]
        tied = [w for w, t in (("PRPV", res.prpv_tied), ("PLV", res.plv_tied)) if c.label in t]
        d = c.delta
        out.append({"candidate θ": c.label, "PRPV [order range]": f"{c.prpv:g} [{c.prpv_low:g}, {c.prpv_high:g}]",
                    "Δ vs lowest [paired 95 %]": f"{d[0]:+g} [{d[1]:+g}, {d[2]:+g}]",
                    "PLV [95 % CI]": c.plv_label, "reaches P": f"{100 * c.reached:.0f} %",
                    "zero-shot": f"{c.zero_shot:.2f}", "picked by": ", ".join(picks) or "–",
                    "in the tied set of": ", ".join(tied) or "–"})
    return out


def plot_choice(res: ChoiceResult, path: Path) -> Path:
    """PRPV (lower is better) and PLV (higher is better) of every candidate, with intervals, picks starred."""
    plt = pyplot()
    labels = [c.label for c in res.candidates]
    x = list(range(len(labels)))
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), layout="constrained")
    ax = axes[0]
    for i, c in enumerate(res.candidates):
        ax.errorbar([i], [c.prpv], yerr=[[c.prpv - c.prpv_low], [c.prpv_high - c.prpv]], fmt="o", capsize=3,
                    color="tab:green" if c.label in res.prpv_tied else "0.5")
    ax.plot([labels.index(res.prpv_pick)], [res.candidates[labels.index(res.prpv_pick)].prpv], "*", ms=14,
            color="gold", mec="k", label="argmin PRPV (green: not separated from it)")
    ax.set_ylabel("PRPV [order range] (↓ predicts the target's ranking)")
    ax2 = axes[1]
    floor = min([0.0] + [c.plv_low for c in res.candidates if c.plv_low is not None]) - 0.1 * (res.target_samples or 1)
    for i, c in enumerate(res.candidates):
        if c.plv is None:
            ax2.plot([i], [floor], "x", color="tab:red", ms=8)
            continue
        lo = floor if c.plv_low is None else c.plv_low
        hi = c.plv if c.plv_high is None else c.plv_high
        ax2.errorbar([i], [c.plv], yerr=[[c.plv - lo], [hi - c.plv]], fmt="o", capsize=3,
                     color="tab:blue" if c.label in res.plv_tied else "0.5")
    if res.plv_pick is not None:
        ax2.plot([labels.index(res.plv_pick)], [res.candidates[labels.index(res.plv_pick)].plv], "*", ms=14,
                 color="gold", mec="k", label="argmax PLV (blue: intervals reach it)")
    ax2.axhline(floor, color="tab:red", lw=0.6, ls=":")
    ax2.set_ylabel("PLV [target samples saved] (↑ teaches; ×: not reached)")
    for a in axes:
        a.set_xticks(x, labels, rotation=20, fontsize=8)
        a.legend(fontsize=7)
    fig.suptitle(f"predict vs teach on one target — {res.verdict()}", fontsize=9)
    return save_figure(fig, path)


def write_choice(res: ChoiceResult, out: str | Path, wall: float) -> dict[str, Path]:
    """``choice.json``, ``choice.csv`` and ``choice.png`` / ``.svg`` in ``out``."""
    import pandas as pd

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = {"json": out / "choice.json", "csv": out / "choice.csv", "png": out / "choice.png"}
    files["json"].write_text(json.dumps({**res.to_dict(), "wall_s": round(wall, 1)}, indent=1, default=str))
    pd.DataFrame(table_rows(res)).to_csv(files["csv"], index=False)
    plot_choice(res, files["png"])
    return files
