"""The baselines and the per-pair diagnosis of a predictivity report: what a proxy must beat, and where it fails.

Beside the proxies stand the answers that need no tuning or no simulator (:mod:`proxybench.experiments.
baselines`); below them, for the best proxy and the baselines, the agent pairs they order differently from
the target, with the start directions on which they do (:mod:`proxybench.usefulness.diagnosis`). A figure
draws each predictor's disagreements as a K×K matrix.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from proxybench.experiments.baselines import CLASS_RULE
from proxybench.experiments.reporting import pyplot, save_figure

if TYPE_CHECKING:
    from proxybench.experiments.predictivity.run import PredictivityResult

__all__ = ["baseline_findings", "baselines_html", "diagnosis_csv", "diagnosis_findings", "diagnosis_html",
           "figure_pairs"]

_SHOWN = 12  # pairs per predictor in the report's table (all of them in the CSV)


def baseline_findings(res: PredictivityResult) -> list[str]:
    """One line per baseline: its PRPV beside the best proxy's, and whether the best proxy beats it."""
    best = res.best_row()
    k = len(res.target.results)
    out = []
    for name, u in res.baselines.items():
        p = u["prpv"]
        if not (np.isfinite(p.low) and np.isfinite(best.prpv.low)):
            span, beaten = "(no range: one episode per agent in it)", "the data cannot say which is lower"
        else:
            span = f"[{p.low:.1f}, {p.high:.1f}]"
            beaten = ("the best proxy's range lies below it" if best.prpv.high < p.low else
                      "it beats the best proxy: its range lies below" if p.high < best.prpv.low else
                      "the best proxy does not beat it: their ranges overlap")
        out.append(f"baseline {name}: PRPV {p.value:.1f} {span} of {k * (k - 1)} vs the best proxy's "
                   f"{best.prpv.value:.1f} [{best.prpv.low:.1f}, {best.prpv.high:.1f}] ({best.domain}): {beaten}")
    if "no simulator: agent classes" in res.baselines:
        out.append(f"the agent-class rule: {CLASS_RULE}")
    return out


def diagnosis_findings(res: PredictivityResult) -> list[str]:
    """Per predictor, its costliest disagreement with the target in words, and the start direction it lives on."""
    out = []
    for name, pairs in res.diagnosis.items():
        if not pairs:
            out.append(f"{name}: orders every pair of agents as the target does.")
            continue
        p = pairs[0]
        where = p.where()
        on = f", on {' and '.join(where)}s" if where and len(where) < len(p.groups) else ""
        out.append(f"{name}: {len(pairs)} pairs ordered differently (PRPV {sum(q.cost for q in pairs):g}); the "
                   f"costliest: {p.a} is {_alpha(p.alpha_target)} {p.b} on the target, {_alpha(p.alpha_proxy)} it in "
                   f"the predictor{on}.")
    return out


def baselines_html(res: PredictivityResult) -> str:
    """A table of the baselines' figures (same columns as the proxies') and the rule of the class baseline."""
    head = ("baseline", "PRPV [order range]", "PPV (mean per agent) [95% CI]", "Pearson r (SRCC)", "Spearman ρ",
            "Kendall τ")
    best = res.best_row()
    rows = [f'<tr style="background:#eef6ff"><td>best proxy: {html.escape(best.domain)}</td><td>{best.prpv.value:.1f} '
            f'[{best.prpv.low:.1f}, {best.prpv.high:.1f}]</td><td>{best.ppv.value:.2f} [{best.ppv.low:.2f}, '
            f'{best.ppv.high:.2f}]</td><td>{best.pearson:.2f}</td><td>{best.spearman:.2f}</td>'
            f'<td>{best.kendall:.2f}</td></tr>']
    for name, u in res.baselines.items():
        p, v = u["prpv"], u["ppv"]
        rows.append(f"<tr><td>{html.escape(name)}</td><td>{p.value:.1f} [{p.low:.1f}, {p.high:.1f}]</td>"
                    f"<td>{v.value:.2f} [{v.low:.2f}, {v.high:.2f}]</td><td>{u['pearson'].value:.2f}</td>"
                    f"<td>{u['spearman'].value:.2f}</td><td>{u['kendall'].value:.2f}</td></tr>")
    table = "<table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>" + "".join(rows) + "</table>"
    items = "".join(f"<li>{html.escape(line)}</li>" for line in baseline_findings(res))
    return table + f"<ul>{items}</ul>"


def _alpha(a: float) -> str:
    return {1.0: "ahead of", 0.0: "behind", 0.5: "tied with"}[a]


def diagnosis_html(res: PredictivityResult) -> str:
    """Per predictor: its costliest disagreeing pairs, by how much, and on which starts."""
    metrics = res.experiment.metrics
    parts = []
    for name, pairs in res.diagnosis.items():
        cost = sum(p.cost for p in pairs)
        head = ("agent a", "agent b", "a on the target", "a in the predictor", "PRPV cost",
                *(f"target Δ {m}" for m in metrics), *(f"predictor Δ {m}" for m in metrics), "ordered differently on")
        rows = []
        for p in pairs[:_SHOWN]:
            cells = (p.a, p.b, _alpha(p.alpha_target), _alpha(p.alpha_proxy), f"{p.cost:g}",
                     *(f"{p.target_delta[m]:+.2f}" for m in metrics), *(f"{p.proxy_delta[m]:+.2f}" for m in metrics),
                     ", ".join(p.where()) or "no single start direction")
            rows.append("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in cells) + "</tr>")
        more = f" (the {_SHOWN} costliest shown; all in diagnosis.csv)" if len(pairs) > _SHOWN else ""
        parts.append(f"<h3>{html.escape(name)}: {len(pairs)} pairs ordered differently, PRPV {cost:g}{more}</h3>"
                     + ("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"
                        + "".join(rows) + "</table>" if rows else "<p>none</p>"))
    return "".join(parts)


def diagnosis_csv(res: PredictivityResult, path: Path) -> Path:
    """Every disagreeing pair of every predictor, with its order in each start direction."""
    import pandas as pd

    rows = []
    for name, pairs in res.diagnosis.items():
        for p in pairs:
            row = {"predictor": name, "a": p.a, "b": p.b, "alpha_target": p.alpha_target,
                   "alpha_predictor": p.alpha_proxy, "cost": p.cost,
                   **{f"target_delta_{m}": v for m, v in p.target_delta.items()},
                   **{f"predictor_delta_{m}": v for m, v in p.proxy_delta.items()}}
            for g, (ap, at, n) in p.groups.items():
                row[f"{g}: alpha_target"], row[f"{g}: alpha_predictor"], row[f"{g}: episodes"] = at, ap, n
            rows.append(row)
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


def figure_pairs(res: PredictivityResult, path: Path) -> Path:
    """One K×K panel per predictor: the PRPV cost of each pair it orders differently from the target."""
    plt = pyplot()
    agents = list(res.target.results)
    k = len(agents)
    names = list(res.diagnosis)
    fig, axes = plt.subplots(1, len(names), figsize=(3.2 + 0.28 * k) * np.array([len(names), 1]) / [1, 1.1],
                             squeeze=False, layout="constrained")
    image = None
    for ax, name in zip(axes[0], names, strict=True):
        grid = np.zeros((k, k))
        for p in res.diagnosis[name]:
            i, j = agents.index(p.a), agents.index(p.b)
            grid[i, j] = grid[j, i] = p.cost
        image = ax.imshow(grid, vmin=0, vmax=2, cmap="Reds")
        ax.set_xticks(range(k), agents, rotation=90, fontsize=7)
        ax.set_yticks(range(k), agents, fontsize=7)
        ax.set_title(f"{name}\nPRPV {grid.sum() / 2:g}", fontsize=8)
    if image is not None:
        fig.colorbar(image, ax=list(axes[0]), label="PRPV cost of the pair (2: swapped, 1: a tie on one side)",
                     fraction=0.03)
    return save_figure(fig, path)
