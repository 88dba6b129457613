"""Table 3.1, Figure 3.6 and a self-contained HTML page for a PLV run, with plain statements of the findings.

The statements compare with the thesis (88–97 % fewer target samples after pre-training on a proxy;
zero-shot score a poor guide to PLV) and say so when this run disagrees.
"""

from __future__ import annotations

import base64
import html
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.learning.experiment import PLVResult
from proxybench.learning.value import DataCost, PLVValue, first_reaching, mean_ci, plv, reference_score

__all__ = ["Summary", "findings", "needed_column", "summarize", "write_report"]

THESIS_REDUCTION = (0.88, 0.97)


@dataclass
class Summary:
    """The numbers behind Table 3.1: curves per arm, the reference score, samples needed and PLV per proxy."""

    curves: dict[str, list[dict[str, Any]]]
    converged: float
    converged_ok: bool
    reference: float
    target_needed: DataCost | None
    rows: list[dict[str, Any]]


def _curves(res: PLVResult) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}
    for arm in dict.fromkeys(r["arm"] for r in res.runs):
        rows = [r for r in res.runs if r["arm"] == arm]
        curve = []
        for n in sorted({r["n"] for r in rows}):
            at = [r for r in rows if r["n"] == n]
            m, lo, hi = mean_ci([r["score"] for r in at])
            curve.append({"n": n, "cost": at[0]["cost"], "off_policy": at[0]["off_policy"],
                          "on_policy": at[0]["on_policy"], "mean": m, "low": lo, "high": hi, "seeds": len(at)})
        out[arm] = curve
    return out


def _needed(curve: list[dict[str, Any]], reference: float) -> DataCost | None:
    hit = first_reaching([c["cost"] for c in curve], [c["mean"] for c in curve], reference)
    if hit is None:
        return None
    c = next(c for c in curve if c["cost"] == hit)
    return DataCost(c["off_policy"], c["on_policy"])


def summarize(res: PLVResult) -> Summary:
    """Reference score, |D_target|, and per proxy: zero-shot score, |D_proxy→target|, PLV and reduction."""
    cfg = res.config
    curves = _curves(res)
    target = curves.get("target-only", [])
    converged = target[-1]["mean"] if target else float("nan")
    reference = reference_score(converged, cfg.tolerance)
    ok = len(target) >= 2 and abs(target[-1]["mean"] - target[-2]["mean"]) <= cfg.tolerance * abs(converged)
    d_target = _needed(target, reference)
    rows = []
    for name, rec in res.proxies.items():
        need = DataCost(0) if rec["zero_shot"] >= reference else _needed(curves.get(name, []), reference)
        value: PLVValue = plv(d_target, need, cfg.eta_on, cfg.eta_off)
        cost = None if need is None else need.weighted(cfg.eta_on, cfg.eta_off)
        rows.append({"proxy": name, "spec": rec["spec"], "zero_shot": rec["zero_shot"], "in_proxy": rec["in_proxy"],
                     "needed": cost, "needed_label": "not reached" if cost is None else f"{cost:,.0f}",
                     "tried_up_to": max((c["cost"] for c in curves.get(name, [])), default=0),
                     "plv": value.value, "plv_label": value.label, "reduction": value.reduction,
                     "reduction_label": value.reduction_label, "status": value.status})
    return Summary(curves, converged, ok, reference, d_target, rows)


def _spearman(xs: list[float], ys: list[float]) -> float | None:
    from scipy import stats

    if len(xs) < 3 or len(set(xs)) < 2 or len(set(ys)) < 2:
        return None
    return float(stats.spearmanr(xs, ys).statistic)


def findings(res: PLVResult, s: Summary | None = None) -> list[str]:
    """Plain statements: convergence, each proxy's PLV, the comparison with the thesis."""
    s = s or summarize(res)
    cfg, out = res.config, []
    t = s.curves.get("target-only", [])
    prev = f"{t[-2]['mean']:.2f} → " if len(t) >= 2 else ""
    out.append(f"Target-only training scores {s.converged:.2f} with {t[-1]['n'] if t else 0:,} samples "
               f"(the expert itself: {res.expert_score:.2f}); the curve "
               + ("has converged (last two rungs within the tolerance)." if s.converged_ok else
                  f"has NOT converged on this ladder (last two rungs {prev}{s.converged:.2f} differ by more than the "
                  "tolerance): the reference P, and with it |D_target| and every PLV, would move with a longer "
                  "ladder."))
    if t:
        peak = max(t, key=lambda c: c["mean"])
        if peak["mean"] - s.converged > cfg.tolerance * abs(s.converged):
            out.append(f"The target-only curve is not monotone: it peaks at {peak['mean']:.2f} with {peak['n']:,} "
                       f"samples and falls to {s.converged:.2f} with {t[-1]['n']:,}. With more data the clone copies "
                       f"the expert more faithfully, and the expert itself scores {res.expert_score:.2f} on the target;"
                       " 'converged' here means the score more data settles toward, not the best score seen.")
    need = "not reached" if s.target_needed is None else f"{s.target_needed.weighted(cfg.eta_on, cfg.eta_off):,.0f}"
    out.append(f"Reference score P = {s.reference:.2f} ({100 * cfg.tolerance:.0f} % below converged); "
               f"target-only needs |D_target| = {need} target samples to reach it.")
    for r in s.rows:
        if r["status"] == "ok":
            out.append(f"{r['proxy']}: zero-shot {r['zero_shot']:.2f}; after pre-training "
                       f"{r['needed_label']} target samples reach P: PLV {r['plv_label']} ({r['reduction_label']}).")
        else:
            out.append(f"{r['proxy']}: zero-shot {r['zero_shot']:.2f}; P {r['status']} with up to "
                       f"{r['tried_up_to']:,.0f} target samples after pre-training (no PLV on this ladder).")
    red = [r["reduction"] for r in s.rows if r["reduction"] is not None]
    lo, hi = THESIS_REDUCTION
    if red:
        agree = sum(lo - 0.005 <= x <= 1.0 for x in red)
        out.append(f"Reductions here: {100 * min(red):.0f}–{100 * max(red):.0f} % (thesis: {100 * lo:.0f}–"
                   f"{100 * hi:.0f} % fewer target samples); {agree} of {len(s.rows)} proxies are at or above the "
                   "thesis' range.")
    else:
        out.append("No proxy reached the reference score: no reduction to compare with the thesis' 88–97 %.")
    plvs = [r["plv"] if r["plv"] is not None else -np.inf for r in s.rows]
    rho = _spearman([r["zero_shot"] for r in s.rows], plvs)
    rho = None if rho is None else round(rho, 2)  # classify the value the text shows
    if rho is not None:
        verdict = ("a good guide" if rho >= 0.8 else "a partial guide" if rho >= 0.4 else "a poor guide")
        thesis = "as the thesis found" if verdict != "a good guide" else "unlike the thesis' finding"
        out.append(f"Zero-shot score vs PLV across proxies: Spearman ρ = {rho:.2f} — zero-shot score is {verdict} "
                   f"to PLV here, {thesis}. (Rungs quantise PLV, so ties are common with few proxies.)")
    return out


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_3_6(res: PLVResult, s: Summary, path: Path) -> Path:
    """Lane score on the target against target samples: target-only and each proxy (x = 0: zero-shot)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.6))
    palette = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    color = {"target-only": "black", **{name: palette[k % len(palette)] for k, name in enumerate(res.proxies)}}
    for arm in ["target-only", *res.proxies]:
        curve = s.curves.get(arm, [])
        x, y = [p["cost"] for p in curve], [p["mean"] for p in curve]
        if arm in res.proxies:
            x, y = [0.0, *x], [res.proxies[arm]["zero_shot"], *y]
        ax.plot(x, y, "o-", color=color[arm], label=arm, lw=2 if arm == "target-only" else 1.4)
        if curve:
            ax.fill_between([p["cost"] for p in curve], [p["low"] for p in curve], [p["high"] for p in curve],
                            color=color[arm], alpha=0.15, lw=0)
    ax.axhline(s.reference, color="tab:red", ls="--", lw=1, label=f"reference P = {s.reference:.1f}")
    ax.axhline(res.expert_score, color="grey", ls=":", lw=1, label=f"expert {res.expert_score:.1f}")
    lin = max(1.0, res.config.ladder[0] / 2)
    ax.set_xscale("symlog", linthresh=lin)
    ax.set_xlim(-0.3 * lin, 1.5 * max(res.config.ladder))
    lows = [p["mean"] for c in s.curves.values() for p in c] + [r["zero_shot"] for r in res.proxies.values()]
    ax.set_ylim(min([*lows, s.reference]) - 3.0, res.config.eval.seconds + 2.0)  # t-bands of 2-3 seeds are wide
    ax.set_xlabel("target samples" + (" (weighted cost η_on·n_on + η_off·n_off)" if res.config.use_dagger else "")
                  + "; x = 0: zero-shot")
    ax.set_ylabel(f"lane score [s] ({res.config.eval.seconds:g} s episodes)")
    ax.set_title("Learning curves on the target (reality model, simulated): from scratch vs pre-trained on a proxy",
                 fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    fig.savefig(path.with_suffix(".svg"))
    plt.close(fig)
    return path


def needed_column(res: PLVResult) -> str:
    """Header of the samples column: plain counts, or the weighted cost when DAgger mixes sample kinds."""
    if res.config.use_dagger:
        return f"target cost to reach P (η_on={res.config.eta_on:g}, η_off={res.config.eta_off:g})"
    return "target samples to reach P"


def _table_rows(res: PLVResult, s: Summary) -> list[dict[str, Any]]:
    column = needed_column(res)
    target = None if s.target_needed is None else s.target_needed.weighted(res.config.eta_on, res.config.eta_off)
    rows = [{"domain": "target only", "zero-shot score": "–", "score in own domain": "–",
             column: "not reached" if target is None else f"{target:,.0f}", "PLV": "–", "reduction": "–"}]
    for r in s.rows:
        rows.append({"domain": r["proxy"], "zero-shot score": f"{r['zero_shot']:.2f}",
                     "score in own domain": f"{r['in_proxy']:.2f}", column: r["needed_label"],
                     "PLV": r["plv_label"], "reduction": r["reduction_label"]})
    return rows


def write_report(res: PLVResult, out: str | Path) -> dict[str, Path]:
    """PNG + SVG figure, CSV/JSON tables and one self-contained ``report.html`` in ``out``."""
    import pandas as pd

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    s = summarize(res)
    files = {"fig3_6": figure_3_6(res, s, out / "fig3_6_learning_curves.png"), "runs": out / "plv_runs.csv",
             "table": out / "table3_1.csv", "json": out / "plv.json", "html": out / "report.html"}
    res.frame().drop(columns=["scores", "terminations"], errors="ignore").to_csv(files["runs"], index=False)
    table = pd.DataFrame(_table_rows(res, s))
    table.to_csv(files["table"], index=False)
    facts = findings(res, s)
    blob = {"config": res.config.to_dict(), "summary": {"converged": s.converged, "converged_ok": s.converged_ok,
            "reference": s.reference, "expert": res.expert_score, "rows": s.rows, "curves": s.curves},
            "findings": facts, "proxies": res.proxies, "runs": res.runs, "wall_s": res.wall_s, "stage_s": res.stage_s,
            "cached": res.cached}
    files["json"].write_text(json.dumps(blob, indent=1, default=str))
    img = base64.b64encode(files["fig3_6"].read_bytes()).decode()
    cfg = res.config
    cached = f" (this invocation; {res.cached} units of work came from the cache)" if res.cached else ""
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>proxybench PLV</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}}
table{{border-collapse:collapse;font-size:13px}}td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}</style>
</head><body><h1>Proxy learning value (PLV)</h1>
<p><b>What is simulated:</b> everything. The target is proxybench's <i>reality model</i>, a simulated stand-in for a
real Duckiebot (wheel slip, motor dead-band, latency jitter, a lens unlike its calibration, other light and noise);
the proxies are the plain simulator. The learner is a PilotNet-style CNN ({cfg.width}×{cfg.height} frames → wheel
PWM) cloned from a privileged pure-pursuit expert. No real robot was involved.</p>
<p>Ladder {", ".join(f"{n:,}" for n in cfg.ladder)} target samples × {len(cfg.seeds)} training seeds (bands: 95 %
t-intervals over seeds); {cfg.eval.episodes} evaluation episodes × {cfg.eval.seconds:g} s on
{html.escape(cfg.eval.map)}; {cfg.proxy_samples:,} proxy samples per proxy{"; DAgger on" if cfg.use_dagger else ""};
wall time {res.wall_s:.0f} s on {os.cpu_count()} cores{cached}.</p>
<h2>Findings</h2><ul>{"".join(f"<li>{html.escape(f)}</li>" for f in facts)}</ul>
<h2>Table 3.1: target samples saved by pre-training on each proxy</h2>{table.to_html(index=False)}
<h2>Figure 3.6: learning curves on the target</h2><img src="data:image/png;base64,{img}" style="max-width:100%">
<h2>Every training run</h2>{res.frame().drop(columns=["scores", "terminations", "checkpoint"], errors="ignore")
                             .round(3).to_html(index=False)}
<h2>Configuration</h2><pre>{html.escape(json.dumps(cfg.to_dict(), indent=1, default=str))}</pre>
</body></html>"""
    files["html"].write_text(page)
    return files
