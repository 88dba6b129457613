"""Figure 3.6 (learning curves on the target, with their fitted curves) and the PLV interval figure of a PLV run."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from proxybench.experiments.plv.measures import CurvePoint
from proxybench.experiments.reporting import pyplot, save_figure

if TYPE_CHECKING:
    from proxybench.experiments.plv.measures import Summary
    from proxybench.experiments.plv.run import PLVResult

__all__ = ["figure_3_6", "figure_plv", "score_range"]


def score_range(res: PLVResult) -> tuple[float, float]:
    """The lane score's possible range [s]: −T (both wheels out all the time) to T (the episode length)."""
    t = float(res.config.eval.seconds)
    return -t, t


def figure_3_6(res: PLVResult, s: Summary, path: Path) -> Path:
    """Lane score on the target against target samples: target-only and each proxy (x = 0: zero-shot).

    Dots are the seeds, markers and bands the mean over seeds with its 95 % bootstrap band (inside the seeds'
    range, so inside the score's possible range); the lines are the fitted curves, and a short vertical tick
    marks where each reaches P.
    """
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9.5, 4.8))
    palette = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    color = {"target-only": "black", **{name: palette[k % len(palette)] for k, name in enumerate(res.proxies)}}
    lo_possible, hi_possible = score_range(res)
    shown: list[float] = [s.reference]
    fits = s.fitted.fits if s.fitted is not None else {}
    for arm in ["target-only", *res.proxies]:
        curve = list(s.curves.get(arm, []))
        if arm in res.proxies:
            row = next(r for r in s.rows if r.proxy == arm)
            curve.insert(0, CurvePoint(0.0, 0.0, 0.0, 0.0, row.zero_shot, row.zero_shot_low, row.zero_shot_high,
                                       row.zero_shot_seeds, row.zero_shot_scores))
        if not curve:
            continue
        x = [p.cost for p in curve]
        ax.plot(x, [p.mean for p in curve], "o", color=color[arm], ms=4, label=arm, zorder=3)
        ax.fill_between(x, [p.low for p in curve], [p.high for p in curve], color=color[arm], alpha=0.12,
                        lw=0)
        for p in curve:
            ax.plot([p.cost] * len(p.scores), p.scores, ".", color=color[arm], ms=3, alpha=0.4, zorder=2)
            shown += [p.low, *p.scores]
        if arm in fits:
            grid = np.concatenate([[min(x)], np.geomspace(max(1.0, min(c for c in x if c > 0)), max(x), 200)])
            ax.plot(grid, fits[arm](grid), "-", color=color[arm], lw=2 if arm == "target-only" else 1.3, zorder=3)
            need = s.target_cost if arm == "target-only" else next(r for r in s.rows if r.proxy == arm).needed
            if need is not None:
                ax.plot([need], [s.reference], "|", color=color[arm], ms=14, mew=2, zorder=4)
    if s.fitted is not None and s.fitted.reference.low is not None:
        ax.axhspan(s.fitted.reference.low, s.fitted.reference.high, color="tab:red", alpha=0.08, lw=0)
    ax.axhline(s.reference, color="tab:red", ls="--", lw=1, label=f"reference P = {s.reference:.1f} s")
    ax.axhline(res.expert_score, color="grey", ls=":", lw=1, label=f"expert {res.expert_score:.1f} s")
    ax.axhline(hi_possible, color="grey", ls="-", lw=0.6, alpha=0.6,
               label=f"maximum possible {hi_possible:g} s (episode length)")
    ax.plot([], [], "-", color="grey", label="fitted a − b(1 + n/n₀)^(−c); | where it reaches P")
    ax.plot([], [], ".", color="grey", label="one seed")
    ax.fill_between([], [], [], color="grey", alpha=0.15, label="95 % bootstrap band over seeds")
    lin = max(1.0, min(res.config.ladder) / 2)
    ax.set_xscale("symlog", linthresh=lin)
    ax.set_xlim(-0.3 * lin, 1.5 * max(res.config.ladder))
    rungs = sorted({p.cost for c in s.curves.values() for p in c} | {0.0})
    ax.set_xticks(rungs, [f"{x:,.0f}" for x in rungs], fontsize=7)
    ax.minorticks_off()
    bottom = max(lo_possible, min(shown) - 0.05 * (hi_possible - lo_possible))
    ax.set_ylim(bottom, hi_possible + 0.02 * (hi_possible - lo_possible))
    ax.set_xlabel("target samples [frames]" + (" (weighted cost η_on·n_on + η_off·n_off)" if res.config.use_dagger
                                               else "") + "; x = 0: zero-shot (pre-trained, no target samples)")
    ax.set_ylabel(f"lane score on the target [s] ({res.config.eval.seconds:g} s episodes)")
    ax.set_title(f"Learning curves on the target ({s.target_label}): from scratch vs pre-trained on a proxy",
                 fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.tight_layout()
    return save_figure(fig, path)


def figure_plv(res: PLVResult, s: Summary, path: Path) -> Path:
    """PLV of each proxy with its 95 % interval (fitted curves; the ladder rule's in grey below it); "not reached"
    ends drawn as arrows to the left edge."""
    plt = pyplot()
    names = [r.proxy for r in s.rows]
    fig, ax = plt.subplots(figsize=(8.5, 0.7 * len(names) + 1.8))
    dt = s.target_cost
    finite = [v for r in s.rows for v in (*r.band(), *r.band(ladder=True)[:2]) if v is not None]
    scale = dt or max([abs(v) for v in finite] + [1.0])
    left = min([0.0, *finite]) - 0.2 * scale  # "not reached" ends point here
    for k, r in enumerate(s.rows):
        y = len(names) - 1 - k
        for dy, key, col in ((0.0, "", "tab:blue"), (-0.25, "ladder_", "0.55")):
            lo, hi, est = r.band(ladder=bool(key))
            if hi is not None:
                ax.plot([left if lo is None else lo, hi], [y + dy, y + dy], color=col, lw=2 if not key else 1.2,
                        solid_capstyle="butt")
            if lo is None and hi is not None:
                ax.annotate("", xy=(left, y + dy), xytext=(left + 0.1 * scale, y + dy),
                            arrowprops={"arrowstyle": "->", "color": col})
            if est is not None:
                ax.plot([est], [y + dy], "o" if not key else "s", color=col, ms=6 if not key else 4)
            elif not key:
                ax.plot([left], [y], "x", color="tab:red")
                ax.text(left, y + 0.18, "not reached" if hi is not None else "not reached (in ≥ 97.5 % of "
                        "replicates)", fontsize=7, color="tab:red")
    ax.axvline(0, color="grey", lw=0.8)
    if dt:
        ax.axvline(dt, color="grey", ls="--", lw=0.8)
        ax.text(dt, len(names) - 0.45, f"|D_target| = {dt:,.0f}\n(100 % saved)", fontsize=7, ha="right",
                va="bottom", color="grey")
        ax.set_xlim(left - 0.05 * scale, max(dt, *finite) + 0.08 * scale)
    ax.set_ylim(-0.8, len(names) + 0.2)
    lo_lim, hi_lim = ax.get_xlim()
    ticks = [t for t in ax.get_xticks() if left + 0.1 * scale <= t <= hi_lim]
    ax.set_xticks([left, *ticks], ["not\nreached", *(f"{t:,.0f}" for t in ticks)])
    ax.set_xlim(lo_lim, hi_lim)
    ax.set_yticks(range(len(names)), list(reversed(names)))
    ax.set_xlabel("PLV [target samples saved]\nblue: fitted curves (dot: estimate, ×: not reached); grey: the ladder "
                  "rule; bars: 95 % bootstrap intervals over seeds; arrow: down to \"not reached\"", fontsize=8)
    ax.set_title(f"Proxy learning value with its interval (target: {s.target_label})", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path)
