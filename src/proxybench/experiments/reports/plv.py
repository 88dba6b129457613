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

from proxybench.experiments.plv import PLVResult
from proxybench.usefulness.plv import DataCost, PLVValue, first_reaching, plv, reference_score, settled_rung
from proxybench.usefulness.plv_intervals import Interval, PLVIntervals, curves_from_runs, mean_band, plv_bootstrap

__all__ = ["Summary", "findings", "needed_column", "summarize", "table_rows", "write_report", "zero_shot_by_seed"]

THESIS_REDUCTION = (0.88, 0.97)


@dataclass
class Summary:
    """The numbers behind Table 3.1: curves per arm, the reference score, samples needed and PLV per proxy.

    ``curves[arm]``: per rung the mean over seeds, its 95 % bootstrap band (``low``, ``high``) and the
    per-seed scores; ``intervals``: the bootstrap over seeds of P, |D_target| and each proxy's PLV.
    """

    curves: dict[str, list[dict[str, Any]]]
    converged: float
    converged_ok: bool
    reference: float
    target_needed: DataCost | None
    rows: list[dict[str, Any]]
    intervals: PLVIntervals | None = None
    target_first: DataCost | None = None


def _curves(res: PLVResult) -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}
    for arm in dict.fromkeys(r["arm"] for r in res.runs):
        rows = [r for r in res.runs if r["arm"] == arm]
        curve = []
        for n in sorted({r["n"] for r in rows}):
            at = sorted((r for r in rows if r["n"] == n), key=lambda r: r["seed"])
            m, lo, hi = mean_band(np.array([r["score"] for r in at]), replicates=res.config.replicates)
            curve.append({"n": n, "cost": at[0]["cost"], "off_policy": at[0]["off_policy"],
                          "on_policy": at[0]["on_policy"], "mean": m, "low": lo, "high": hi, "seeds": len(at),
                          "scores": [r["score"] for r in at]})
        out[arm] = curve
    return out


def _split_at(curve: list[dict[str, Any]], cost: float | None) -> DataCost | None:
    if cost is None:
        return None
    if cost == 0:
        return DataCost(0)
    c = next(c for c in curve if c["cost"] == cost)
    return DataCost(c["off_policy"], c["on_policy"])


def zero_shot_by_seed(rec: dict[str, Any]) -> dict[int, float]:
    """Seed → zero-shot score of a proxy's pre-trained networks (one network, seed 0, in old records)."""
    by = rec.get("zero_shot_by_seed")
    return {int(k): float(v) for k, v in by.items()} if by else {0: float(rec["zero_shot"])}


def summarize(res: PLVResult) -> Summary:
    """Reference score, |D_target|, and per proxy: zero-shot score, |D_proxy→target|, PLV, reduction, intervals.

    Samples needed follow the "reach and stay above P" rule (:func:`settled_rung`); the first rung that
    reached P (the old rule) is kept beside it. Intervals: percentile bootstrap over seeds.
    """
    cfg = res.config
    curves = _curves(res)
    target = curves.get("target-only", [])
    converged = target[-1]["mean"] if target else float("nan")
    reference = reference_score(converged, cfg.tolerance)
    ok = len(target) >= 2 and abs(target[-1]["mean"] - target[-2]["mean"]) <= cfg.tolerance * abs(converged)
    t_costs, t_means = [c["cost"] for c in target], [c["mean"] for c in target]
    d_target = _split_at(target, settled_rung(t_costs, t_means, reference, cfg.confirm, through_end=True))
    t_first = _split_at(target, first_reaching(t_costs, t_means, reference))
    ivs = None
    if target:
        t_curve = curves_from_runs(res.runs, "target-only", cfg.ladder)
        p_curves = {name: curves_from_runs(res.runs, name, cfg.ladder, zero_shot_by_seed(rec))
                    for name, rec in res.proxies.items()}
        ivs = plv_bootstrap(t_curve, p_curves, cfg.tolerance, cfg.confirm, cfg.replicates)
    rows = []
    for name, rec in res.proxies.items():
        curve = curves.get(name, [])
        zs = zero_shot_by_seed(rec)
        ns = [0.0, *(c["cost"] for c in curve)]
        means = [float(np.mean(list(zs.values()))), *(c["mean"] for c in curve)]
        tried_end = any(c["n"] == cfg.ladder[-1] for c in curve)
        need = _split_at(curve, settled_rung(ns, means, reference, cfg.confirm, through_end=tried_end))
        first = _split_at(curve, first_reaching(ns, means, reference))
        value: PLVValue = plv(d_target, need, cfg.eta_on, cfg.eta_off)
        cost = None if need is None else need.weighted(cfg.eta_on, cfg.eta_off)
        first_cost = None if first is None else first.weighted(cfg.eta_on, cfg.eta_off)
        zm, zlo, zhi = mean_band(np.array(list(zs.values())), replicates=cfg.replicates)
        row = {"proxy": name, "spec": rec["spec"], "zero_shot": zm, "zero_shot_low": zlo, "zero_shot_high": zhi,
               "zero_shot_seeds": len(zs), "in_proxy": rec["in_proxy"],
               "needed": cost, "needed_label": "not reached" if cost is None else f"{cost:,.0f}",
               "first_reached": first_cost,
               "first_reached_label": "not reached" if first_cost is None else f"{first_cost:,.0f}",
               "tried_up_to": max((c["cost"] for c in curve), default=0),
               "plv": value.value, "plv_label": value.label, "reduction": value.reduction,
               "reduction_label": value.reduction_label, "status": value.status}
        if ivs is not None:
            row |= {"needed_ci": ivs.needed[name].label(), "plv_ci": ivs.plv[name].label(),
                    "reduction_ci": ivs.reduction[name].label("{:.0f} %", scale=100.0),
                    "reached_share": ivs.reached[name], "plv_low": ivs.plv[name].low, "plv_high": ivs.plv[name].high}
        rows.append(row)
    return Summary(curves, converged, ok, reference, d_target, rows, ivs, t_first)


def _spearman(xs: list[float], ys: list[float]) -> float | None:
    from scipy import stats

    if len(xs) < 3 or len(set(xs)) < 2 or len(set(ys)) < 2:
        return None
    return float(stats.spearmanr(xs, ys).statistic)


def _fmt_band(m: float, lo: float, hi: float) -> str:
    return f"{m:.2f} [{lo:.2f}, {hi:.2f}]"


def findings(res: PLVResult, s: Summary | None = None) -> list[str]:
    """Plain statements: convergence, each proxy's PLV with its interval, the comparison with the thesis."""
    s = s or summarize(res)
    cfg, out = res.config, []
    t = s.curves.get("target-only", [])
    prev = f"{t[-2]['mean']:.2f} → " if len(t) >= 2 else ""
    top = f"{t[-1]['mean']:.2f} [{t[-1]['low']:.2f}, {t[-1]['high']:.2f}]" if t else "nan"
    out.append(f"Target-only training scores {top} with {t[-1]['n'] if t else 0:,} samples "
               f"(mean over {len(cfg.seeds)} seeds [95 % bootstrap band]; the expert itself: {res.expert_score:.2f}); "
               "the curve "
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
    iv = s.intervals
    ref = f"{s.reference:.2f}" + (f" [{iv.reference.low:.2f}, {iv.reference.high:.2f}]" if iv else "")
    tneed = iv.target_needed.label() if iv else need
    out.append(f"Reference score P = {ref} ({100 * cfg.tolerance:.0f} % below converged); target-only needs "
               f"|D_target| = {tneed} target samples to reach P and stay at or above it on every larger rung.")
    if s.target_first is not None and s.target_needed is not None and s.target_first != s.target_needed:
        out.append(f"Target-only first reached P with {s.target_first.weighted(cfg.eta_on, cfg.eta_off):,.0f} "
                   "samples but fell below it again on a larger rung: that rung does not count.")
    for r in s.rows:
        zs = _fmt_band(r["zero_shot"], r["zero_shot_low"], r["zero_shot_high"])
        ci = f" — 95 % interval {r['plv_ci']}, P settled in {100 * r['reached_share']:.0f} % of bootstrap " \
             "replicates" if "plv_ci" in r else ""
        if r["status"] == "ok":
            out.append(f"{r['proxy']}: zero-shot {zs} ({r['zero_shot_seeds']} pre-trained networks); after "
                       f"pre-training {r['needed_label']} target samples reach P and stay above it: "
                       f"PLV {r['plv_label']} ({r['reduction_label']}){ci}.")
        else:
            out.append(f"{r['proxy']}: zero-shot {zs}; P {r['status']} (or not for good) with up to "
                       f"{r['tried_up_to']:,.0f} target samples after pre-training (no PLV on this ladder){ci}.")
        if r["first_reached"] is not None and r["first_reached"] != r["needed"]:
            out.append(f"{r['proxy']} first reached P with {r['first_reached_label']} target samples but did not "
                       "stay above it: once is not enough.")
    lo, hi = THESIS_REDUCTION
    red = [r["reduction"] for r in s.rows if r["reduction"] is not None]
    if red:
        agree = sum(lo - 0.005 <= x <= 1.0 for x in red)
        overlap = sum(1 for r in s.rows if iv and _overlaps(iv.reduction[r["proxy"]], lo))
        out.append(f"Reductions here: {100 * min(red):.0f}–{100 * max(red):.0f} % (thesis: {100 * lo:.0f}–"
                   f"{100 * hi:.0f} % fewer target samples); {agree} of {len(s.rows)} proxies are at or above the "
                   "thesis' range" + (f", {overlap} of {len(s.rows)} have an interval reaching it." if iv else "."))
    else:
        out.append("No proxy settled above the reference score: no reduction to compare with the thesis' 88–97 %.")
    plvs = [r["plv"] if r["plv"] is not None else -np.inf for r in s.rows]
    rho = _spearman([r["zero_shot"] for r in s.rows], plvs)
    rho = None if rho is None else round(rho, 2)  # classify the value the text shows
    if rho is not None:
        verdict = ("a good guide" if rho >= 0.8 else "a partial guide" if rho >= 0.4 else "a poor guide")
        thesis = "as the thesis found" if verdict != "a good guide" else "unlike the thesis' finding"
        out.append(f"Zero-shot score vs PLV across proxies: Spearman ρ = {rho:.2f} — zero-shot score is {verdict} "
                   f"to PLV here, {thesis}. (Rungs quantise PLV, so ties are common with few proxies; with "
                   f"{len(s.rows)} proxies this is weak evidence either way.)")
    return out


def _overlaps(iv: Interval, lo: float) -> bool:
    """Whether a reduction interval reaches the thesis' range (its upper end at or above its lower bound)."""
    return iv.high is not None and iv.high >= lo - 0.005


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def score_range(res: PLVResult) -> tuple[float, float]:
    """The lane score's possible range [s]: −T (both wheels out all the time) to T (the episode length)."""
    t = float(res.config.eval.seconds)
    return -t, t


def figure_3_6(res: PLVResult, s: Summary, path: Path) -> Path:
    """Lane score on the target against target samples: target-only and each proxy (x = 0: zero-shot).

    Lines are means over seeds, bands their 95 % bootstrap intervals (inside the seeds' range, so inside
    the score's possible range), dots the seeds themselves.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9.5, 4.8))
    palette = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    color = {"target-only": "black", **{name: palette[k % len(palette)] for k, name in enumerate(res.proxies)}}
    lo_possible, hi_possible = score_range(res)
    shown: list[float] = [s.reference]
    for arm in ["target-only", *res.proxies]:
        curve = list(s.curves.get(arm, []))
        if arm in res.proxies:
            row = next(r for r in s.rows if r["proxy"] == arm)
            zs = list(zero_shot_by_seed(res.proxies[arm]).values())
            curve.insert(0, {"cost": 0.0, "mean": row["zero_shot"], "low": row["zero_shot_low"],
                             "high": row["zero_shot_high"], "scores": zs})
        if not curve:
            continue
        x = [p["cost"] for p in curve]
        ax.plot(x, [p["mean"] for p in curve], "o-", color=color[arm], lw=2 if arm == "target-only" else 1.4,
                ms=4, label=arm, zorder=3)
        ax.fill_between(x, [p["low"] for p in curve], [p["high"] for p in curve], color=color[arm], alpha=0.15,
                        lw=0)
        for p in curve:
            ax.plot([p["cost"]] * len(p["scores"]), p["scores"], ".", color=color[arm], ms=3, alpha=0.5, zorder=2)
            shown += [p["low"], *p["scores"]]
    iv = s.intervals
    if iv is not None and iv.reference.low is not None:
        ax.axhspan(iv.reference.low, iv.reference.high, color="tab:red", alpha=0.08, lw=0)
    ax.axhline(s.reference, color="tab:red", ls="--", lw=1, label=f"reference P = {s.reference:.1f} s")
    ax.axhline(res.expert_score, color="grey", ls=":", lw=1, label=f"expert {res.expert_score:.1f} s")
    ax.axhline(hi_possible, color="grey", ls="-", lw=0.6, alpha=0.6,
               label=f"maximum possible {hi_possible:g} s (episode length)")
    ax.plot([], [], ".", color="grey", label="one seed")
    ax.fill_between([], [], [], color="grey", alpha=0.15, label="95 % bootstrap band over seeds")
    lin = max(1.0, min(res.config.ladder) / 2)
    ax.set_xscale("symlog", linthresh=lin)
    ax.set_xlim(-0.3 * lin, 1.5 * max(res.config.ladder))
    rungs = sorted({p["cost"] for c in s.curves.values() for p in c} | {0.0})
    ax.set_xticks(rungs, [f"{x:,.0f}" for x in rungs], fontsize=7)
    ax.minorticks_off()
    bottom = max(lo_possible, min(shown) - 0.05 * (hi_possible - lo_possible))
    ax.set_ylim(bottom, hi_possible + 0.02 * (hi_possible - lo_possible))
    ax.set_xlabel("target samples [frames]" + (" (weighted cost η_on·n_on + η_off·n_off)" if res.config.use_dagger
                                               else "") + "; x = 0: zero-shot (pre-trained, no target samples)")
    ax.set_ylabel(f"lane score on the target [s] ({res.config.eval.seconds:g} s episodes)")
    ax.set_title("Learning curves on the target (reality model, simulated): from scratch vs pre-trained on a proxy",
                 fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    fig.savefig(path.with_suffix(".svg"))
    plt.close(fig)
    return path


def figure_plv(res: PLVResult, s: Summary, path: Path) -> Path:
    """PLV of each proxy with its 95 % bootstrap interval; "not reached" ends drawn as arrows to the left edge."""
    plt = _pyplot()
    names = [r["proxy"] for r in s.rows]
    fig, ax = plt.subplots(figsize=(8.5, 0.6 * len(names) + 1.8))
    dt = None if s.target_needed is None else s.target_needed.weighted(res.config.eta_on, res.config.eta_off)
    finite = [v for r in s.rows for v in (r["plv"], r.get("plv_low"), r.get("plv_high")) if v is not None]
    scale = dt or max([abs(v) for v in finite] + [1.0])
    left = min([0.0, *finite]) - 0.2 * scale  # "not reached" ends point here
    for k, r in enumerate(s.rows):
        y = len(names) - 1 - k
        lo, hi = r.get("plv_low"), r.get("plv_high")
        if hi is not None:
            ax.plot([left if lo is None else lo, hi], [y, y], color="tab:blue", lw=2, solid_capstyle="butt")
        if lo is None and hi is not None:
            ax.annotate("", xy=(left, y), xytext=(left + 0.1 * scale, y),
                        arrowprops={"arrowstyle": "->", "color": "tab:blue"})
        if r["plv"] is not None:
            ax.plot([r["plv"]], [y], "o", color="tab:blue")
        else:
            ax.plot([left], [y], "x", color="tab:red")
            what = "not reached" if hi is not None else "not reached (in ≥ 97.5 % of replicates)"
            ax.text(left, y + 0.18, what, fontsize=7, color="tab:red")
    ax.axvline(0, color="grey", lw=0.8)
    if dt:
        ax.axvline(dt, color="grey", ls="--", lw=0.8)
        ax.text(dt, len(names) - 0.45, f"|D_target| = {dt:,.0f}\n(100 % saved)", fontsize=7, ha="right",
                va="bottom", color="grey")
        ax.set_xlim(left - 0.05 * scale, dt + 0.08 * scale)
    ax.set_ylim(-0.6, len(names) + 0.2)
    lo_lim, hi_lim = ax.get_xlim()
    ticks = [t for t in ax.get_xticks() if left + 0.1 * scale <= t <= hi_lim]
    ax.set_xticks([left, *ticks], ["not\nreached", *(f"{t:,.0f}" for t in ticks)])
    ax.set_xlim(lo_lim, hi_lim)
    ax.set_yticks(range(len(names)), list(reversed(names)))
    ax.set_xlabel("PLV [target samples saved]\ndot: estimate, ×: not reached; bar: 95 % bootstrap interval over "
                  "seeds; arrow: down to \"not reached\"", fontsize=8)
    ax.set_title("Proxy learning value with its interval (target: reality model, simulated)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    fig.savefig(path.with_suffix(".svg"))
    plt.close(fig)
    return path


def needed_column(res: PLVResult) -> str:
    """Header of the samples column: plain counts, or the weighted cost when DAgger mixes sample kinds."""
    if res.config.use_dagger:
        return (f"target cost to reach and stay above P (η_on={res.config.eta_on:g}, η_off={res.config.eta_off:g}) "
                "[95 % CI]")
    return "target samples to reach and stay above P [95 % CI]"


def table_rows(res: PLVResult, s: Summary) -> list[dict[str, Any]]:
    """Table 3.1 with intervals: one row for target-only training and one per proxy."""
    column = needed_column(res)
    iv = s.intervals
    target = None if s.target_needed is None else s.target_needed.weighted(res.config.eta_on, res.config.eta_off)
    tcell = iv.target_needed.label() if iv else ("not reached" if target is None else f"{target:,.0f}")
    rows = [{"domain": "target only", "zero-shot score [95 % CI]": "–", "score in own domain": "–", column: tcell,
             "first reached P": "–" if s.target_first is None else
             f"{s.target_first.weighted(res.config.eta_on, res.config.eta_off):,.0f}",
             "PLV [95 % CI]": "–", "reduction [95 % CI]": "–", "settles (share of replicates)": "–"}]
    for r in s.rows:
        rows.append({"domain": r["proxy"],
                     "zero-shot score [95 % CI]": _fmt_band(r["zero_shot"], r["zero_shot_low"], r["zero_shot_high"]),
                     "score in own domain": f"{r['in_proxy']:.2f}", column: r.get("needed_ci", r["needed_label"]),
                     "first reached P": r["first_reached_label"], "PLV [95 % CI]": r.get("plv_ci", r["plv_label"]),
                     "reduction [95 % CI]": r.get("reduction_ci", r["reduction_label"]),
                     "settles (share of replicates)": f"{100 * r['reached_share']:.0f} %" if "reached_share" in r
                     else "–"})
    return rows


METHOD = ("Samples needed = the smallest rung from which the mean score over seeds reaches the reference P and "
          "stays at or above it on every larger rung tried, confirmed by {confirm} larger rung(s) or the ladder's end "
          "(the settling-time rule of control engineering; reaching P once is not enough). Intervals: 95 % "
          "percentile bootstrap over seeds ({replicates:,} replicates), the whole computation (P, |D_target|, "
          "|D_proxy→target|, PLV) redone in each replicate; seeds shared by target-only and a proxy are resampled "
          "together. A seed of a proxy is one pre-training followed by its fine-tuning runs. \"not reached\" as an "
          "interval end: in more than 2.5 % of the replicates the proxy did not settle above P on the rungs tried. "
          "With few seeds these intervals are too narrow: for 3 seeds the band of a mean is about the seeds' range, "
          "which covers the median with probability 75 %.")


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
    blob = {"config": res.config.to_dict(), "summary": {"converged": s.converged, "converged_ok": s.converged_ok,
            "reference": s.reference, "expert": res.expert_score, "rows": s.rows, "curves": s.curves,
            "intervals": None if s.intervals is None else s.intervals.to_dict(), "method": method},
            "findings": facts, "proxies": res.proxies, "runs": res.runs, "wall_s": res.wall_s, "stage_s": res.stage_s,
            "cached": res.cached}
    files["json"].write_text(json.dumps(blob, indent=1, default=str))
    img = {k: base64.b64encode(files[k].read_bytes()).decode() for k in ("fig3_6", "fig_plv")}
    cached = f" (this invocation; {res.cached} units of work came from the cache)" if res.cached else ""
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>proxybench PLV</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}}
table{{border-collapse:collapse;font-size:13px}}td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}</style>
</head><body><h1>Proxy learning value (PLV)</h1>
<p><b>What is simulated:</b> everything. The target is proxybench's <i>reality model</i>, a simulated stand-in for a
real Duckiebot (wheel slip, motor dead-band, latency jitter, a lens unlike its calibration, other light and noise);
the proxies are the plain simulator. The learner is a PilotNet-style CNN ({cfg.width}×{cfg.height} frames → wheel
PWM) cloned from a privileged pure-pursuit expert. No real robot was involved.</p>
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
