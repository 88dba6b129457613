"""Table 3.1, Figure 3.6 and a self-contained HTML page for a PLV run, with plain statements of the findings.

PLV comes from fitted learning curves (:mod:`proxybench.usefulness.plv_curve`: a continuous crossing of P, with a
bootstrap interval that refits every curve); the ladder rule (:mod:`proxybench.usefulness.plv_intervals`: the
first rung that reaches P and stays) is kept beside it. The statements compare with the thesis (88–97 % fewer
target samples after pre-training on a proxy; zero-shot score a poor guide to PLV) and say so when this run
disagrees.
"""

from __future__ import annotations

import base64
import html
import json
import os
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.experiments.plv.figures import figure_3_6, figure_plv, score_range
from proxybench.experiments.plv.measures import Summary, summarize, zero_shot_by_seed
from proxybench.experiments.plv.run import PLVResult
from proxybench.usefulness.plv_intervals import Interval

__all__ = ["Summary", "figure_3_6", "figure_plv", "findings", "needed_column", "score_range", "summarize",
           "summary_record", "table_rows", "write_report", "zero_shot_by_seed"]

THESIS_REDUCTION = (0.88, 0.97)


def _spearman(xs: list[float], ys: list[float]) -> float | None:
    from scipy import stats

    if len(xs) < 3 or len(set(xs)) < 2 or len(set(ys)) < 2:
        return None
    return float(stats.spearmanr(xs, ys).statistic)


def _fmt_band(m: float, lo: float, hi: float) -> str:
    return f"{m:.2f} [{lo:.2f}, {hi:.2f}]"


def findings(res: PLVResult, s: Summary | None = None) -> list[str]:
    """Plain statements: convergence, the fits, each proxy's PLV with its interval, the comparison with the thesis."""
    s = s or summarize(res)
    cfg, out = res.config, []
    t = s.curves.get("target-only", [])
    prev = f"{t[-2].mean:.2f} → " if len(t) >= 2 else ""
    top = f"{t[-1].mean:.2f} [{t[-1].low:.2f}, {t[-1].high:.2f}]" if t else "nan"
    out.append(f"Target-only training scores {top} with {t[-1].n if t else 0:,} samples "
               f"(mean over {len(cfg.seeds)} seeds [95 % bootstrap band]; the expert itself: {res.expert_score:.2f}); "
               "the curve "
               + ("has converged (last two rungs within the tolerance)." if s.converged_ok else
                  f"has NOT converged on this ladder (last two rungs {prev}{s.converged:.2f} differ by more than the "
                  "tolerance): the reference P, and with it |D_target| and every PLV, would move with a longer "
                  "ladder."))
    if t:
        peak = max(t, key=lambda c: c.mean)
        if peak.mean - s.converged > cfg.tolerance * abs(s.converged):
            out.append(f"The target-only curve is not monotone: it peaks at {peak.mean:.2f} with {peak.n:,} "
                       f"samples and falls to {s.converged:.2f} with {t[-1].n:,}. With more data the clone copies "
                       f"the expert more faithfully, and the expert itself scores {res.expert_score:.2f} on the target;"
                       " 'converged' here means the score more data settles toward, not the best score seen. The "
                       "fitted curve (saturating) cannot follow the peak.")
    f = s.fitted
    if f is None:
        return out
    ft = f.fits["target-only"]
    misfit = [arm for arm, pv in f.lack_of_fit.items() if pv is not None and np.isfinite(pv) and pv < 0.01]
    out.append(f"Fitted target-only curve {ft.a:.2f} − {ft.b:.2f}·(1 + n/{ft.n0:g})^(−{ft.c:.2f}); P = "
               f"{f.reference.label('{:.2f}')} ({100 * cfg.tolerance:.0f} % below the fit at the largest rung); "
               f"target-only reaches P with |D_target| = {f.target_needed.label()} samples (continuous crossing; "
               f"95 % bootstrap interval over seeds, refitting). The ladder rule: "
               f"{s.intervals.target_needed.label() if s.intervals else '–'} (P = {s.ladder_reference:.2f}).")
    if misfit:
        out.append(f"Lack of fit (p < 0.01: the fitted curve misses the rung means by more than their seeds' spread) "
                   f"for {', '.join(misfit)}: read those crossing points as approximate.")
    for r in s.rows:
        zs = _fmt_band(r.zero_shot, r.zero_shot_low, r.zero_shot_high)
        ladder = f"; the ladder rule: {r.ladder_plv_ci or r.ladder_plv_label}"
        if r.status == "ok":
            out.append(f"{r.proxy}: zero-shot {zs} ({r.zero_shot_seeds} pre-trained networks); after "
                       f"pre-training the fitted curve reaches P with {r.needed_ci} target samples: PLV "
                       f"{r.plv_ci} ({r.reduction_label}), reaching P in {100 * r.reached_share:.0f} % "
                       f"of bootstrap replicates{ladder}.")
        else:
            out.append(f"{r.proxy}: zero-shot {zs}; P {r.status} by the fitted curve with up to "
                       f"{r.tried_up_to:,.0f} target samples after pre-training (no PLV; interval {r.plv_ci})"
                       f"{ladder}.")
    lo, hi = THESIS_REDUCTION
    red = [r.reduction for r in s.rows if r.reduction is not None]
    if red:
        agree = sum(lo - 0.005 <= x <= 1.0 for x in red)
        overlap = sum(1 for r in s.rows if _overlaps(f.reduction[r.proxy], lo))
        out.append(f"Reductions here: {100 * min(red):.0f}–{100 * max(red):.0f} % (thesis: {100 * lo:.0f}–"
                   f"{100 * hi:.0f} % fewer target samples); {agree} of {len(s.rows)} proxies are at or above the "
                   f"thesis' range, {overlap} of {len(s.rows)} have an interval reaching it.")
    else:
        out.append("No proxy reached the reference score: no reduction to compare with the thesis' 88–97 %.")
    plvs = [r.plv if r.plv is not None else -np.inf for r in s.rows]
    rho = _spearman([r.zero_shot for r in s.rows], plvs)
    rho = None if rho is None else round(rho, 2)  # classify the value the text shows
    if rho is not None:
        verdict = ("a good guide" if rho >= 0.8 else "a partial guide" if rho >= 0.4 else "a poor guide")
        thesis = "as the thesis found" if verdict != "a good guide" else "unlike the thesis' finding"
        out.append(f"Zero-shot score vs PLV across proxies: Spearman ρ = {rho:.2f} — zero-shot score is {verdict} "
                   f"to PLV here, {thesis}. (With {len(s.rows)} proxies this is weak evidence either way.)")
    return out


def _overlaps(iv: Interval, lo: float) -> bool:
    """Whether a reduction interval reaches the thesis' range (its upper end at or above its lower bound)."""
    return iv.high is not None and iv.high >= lo - 0.005


def needed_column(res: PLVResult) -> str:
    """Header of the samples column: plain counts, or the weighted cost when DAgger mixes sample kinds."""
    if res.config.use_dagger:
        return f"target cost to reach P (η_on={res.config.eta_on:g}, η_off={res.config.eta_off:g}) [95 % CI]"
    return "target samples to reach P, fitted [95 % CI]"


def table_rows(res: PLVResult, s: Summary) -> list[dict[str, Any]]:
    """Table 3.1 with intervals: one row for target-only training and one per proxy; fitted curves first, the
    ladder rule after."""
    column = needed_column(res)
    f, iv = s.fitted, s.intervals
    rows = [{"domain": "target only", "zero-shot score [95 % CI]": "–", "score in own domain": "–",
             column: f.target_needed.label() if f else "–", "PLV [95 % CI]": "–", "reduction [95 % CI]": "–",
             "reaches P (share of replicates)": "–",
             "ladder: samples (reach and stay)": iv.target_needed.label() if iv else "–", "ladder: PLV": "–"}]
    for r in s.rows:
        rows.append({"domain": r.proxy,
                     "zero-shot score [95 % CI]": _fmt_band(r.zero_shot, r.zero_shot_low, r.zero_shot_high),
                     "score in own domain": f"{r.in_proxy:.2f}", column: r.needed_ci or r.needed_label,
                     "PLV [95 % CI]": r.plv_ci or r.plv_label,
                     "reduction [95 % CI]": r.reduction_ci or r.reduction_label,
                     "reaches P (share of replicates)": f"{100 * r.reached_share:.0f} %" if r.reached_share is not None
                     else "–",
                     "ladder: samples (reach and stay)": r.ladder_needed_ci or r.ladder_needed_label,
                     "ladder: PLV": r.ladder_plv_ci or r.ladder_plv_label})
    return rows


METHOD = ("Each arm's mean score over seeds is fitted with a saturating learning curve a − b·(1 + n/n₀)^(−c) "
          "(n₀ = the first rung; n = 0 is the zero-shot score), weighted by the precision of each rung's mean. "
          "P = the fitted target-only score at the largest rung less the tolerance; samples needed = where an arm's "
          "fitted curve reaches P and stays above it to its last rung (a continuous number); PLV = |D_target| − "
          "|D_proxy→target|. Intervals: percentile bootstrap over seeds ({replicates:,} replicates), every curve "
          "refitted and the whole computation redone in each replicate, seeds shared by target-only and a proxy "
          "resampled together, expanded for the seed count (Hesterberg's expanded percentile interval); its "
          "coverage is checked on simulated curves (docs/learning.md). A seed of a proxy is one pre-training "
          "followed by its fine-tuning runs. \"not reached\" as an interval end: in more than 2.5 % of the "
          "replicates the curve did not reach P. Beside it, the ladder rule: the smallest rung from which the "
          "mean reaches P and stays above it, confirmed by {confirm} larger rung(s) or the ladder's end — "
          "quantised by the rungs.")


def _what_is_simulated(cfg) -> str:
    if cfg.target == "reality":
        return ("everything. The target is proxybench's reality model, a simulated stand-in for a real Duckiebot "
                "(wheel slip, motor dead-band, latency jitter, a lens unlike its calibration, other light and noise); "
                "the proxies are the plain simulator. No real robot was involved.")
    return (f"the proxies are the plain simulator. The target is the robot node `{cfg.target.removeprefix('robot:')}`: "
            "target samples were collected on it (the expert reading the true lane pose it serves) and every network "
            "was scored on it. proxybench cannot tell a real robot from a simulator behind the robot protocol: treat "
            "the result as real only if you know the node drives a physical robot.")


def summary_record(res: PLVResult, s: Summary | None = None) -> dict[str, Any]:
    """What plv.json says of a run besides its training runs: the config, the summary (reference, Table 3.1's rows,
    curves, intervals, fitted curves), the findings, the proxies' pre-training records. A pure function of the
    runs, so that a shipped run (results/, :mod:`proxybench.experiments.evidence`) is recomputed by this very code."""
    s = s if s is not None else summarize(res)
    cfg = res.config
    method = METHOD.format(confirm=cfg.confirm, replicates=cfg.replicates)
    return {"config": cfg.to_dict(), "summary": {"converged": s.converged, "converged_ok": s.converged_ok,
            "reference": s.reference, "expert": res.expert_score, "rows": [asdict(r) for r in s.rows],
            "curves": {arm: [asdict(p) for p in c] for arm, c in s.curves.items()},
            "intervals": None if s.intervals is None else s.intervals.to_dict(),
            "fitted": None if s.fitted is None else s.fitted.to_dict(), "target_needed": s.target_cost,
            "ladder_reference": s.ladder_reference, "target": s.target_label, "method": method},
            "findings": findings(res, s), "proxies": res.proxies}


def write_report(res: PLVResult, out: str | Path) -> dict[str, Path]:
    """PNG + SVG figures, CSV/JSON tables and one self-contained ``report.html`` in ``out``."""
    import pandas as pd

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    s = summarize(res)
    files = {"fig3_6": figure_3_6(res, s, out / "fig3_6_learning_curves.png"),
             "fig_plv": figure_plv(res, s, out / "fig_plv_intervals.png"), "runs": out / "plv_runs.csv",
             "table": out / "table3_1.csv", "json": out / "plv.json", "html": out / "report.html"}
    res.frame().drop(columns=["scores", "terminations"], errors="ignore").to_csv(files["runs"], index=False)
    table = pd.DataFrame(table_rows(res, s))
    table.to_csv(files["table"], index=False)
    facts = findings(res, s)
    cfg = res.config
    method = METHOD.format(confirm=cfg.confirm, replicates=cfg.replicates)
    blob = {**summary_record(res, s), "runs": res.runs, "wall_s": res.wall_s, "stage_s": res.stage_s,
            "cached": res.cached}
    files["json"].write_text(json.dumps(blob, indent=1, default=str))
    img = {k: base64.b64encode(files[k].read_bytes()).decode() for k in ("fig3_6", "fig_plv")}
    cached = f" (this invocation; {res.cached} units of work came from the cache)" if res.cached else ""
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>proxybench PLV</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}}
table{{border-collapse:collapse;font-size:13px}}td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}</style>
</head><body><h1>Proxy learning value (PLV)</h1>
<p><b>What is simulated:</b> {html.escape(_what_is_simulated(cfg))} The learner is a PilotNet-style CNN
({cfg.width}×{cfg.height} frames → wheel PWM) cloned from a privileged pure-pursuit expert.</p>
<p><b>PLV</b> (thesis Def. 4, eq. 3.5.1) = |D_target| − |D_proxy→target|: the target samples a behaviour-cloning agent
needs to reach the reference score P (the converged target-only score less {100 * cfg.tolerance:.0f} %) when trained
on the target alone, less those it needs after pre-training on the proxy. Lane score (thesis §3.7.2): seconds
driven, −1 per second with one wheel out of the lane, −2 with both out; range [−T, T] for T-second episodes.</p>
<p>Ladder {", ".join(f"{n:,}" for n in cfg.ladder)} target samples × {len(cfg.seeds)} seeds;
{cfg.eval.episodes} evaluation episodes × {cfg.eval.seconds:g} s on {html.escape(cfg.eval.map)};
{cfg.proxy_samples:,} proxy samples per proxy{"; DAgger on" if cfg.use_dagger else ""};
wall time {res.wall_s:.0f} s on {os.cpu_count()} cores{cached}.</p>
<p><b>Method.</b> {html.escape(method)}</p>
<h2>Findings</h2><ul>{"".join(f"<li>{html.escape(f)}</li>" for f in facts)}</ul>
<h2>Table 3.1: target samples saved by pre-training on each proxy</h2>{table.to_html(index=False)}
<h2>PLV with its interval</h2><img src="data:image/png;base64,{img["fig_plv"]}" style="max-width:100%">
<h2>Figure 3.6: learning curves on the target</h2><img src="data:image/png;base64,{img["fig3_6"]}"
style="max-width:100%">
<h2>Every training run</h2>{res.frame().drop(columns=["scores", "terminations", "checkpoint"], errors="ignore")
                             .round(3).to_html(index=False)}
<h2>Configuration</h2><pre>{html.escape(json.dumps(cfg.to_dict(), indent=1, default=str))}</pre>
</body></html>"""
    files["html"].write_text(page)
    return files
