"""Figures 3.3 / 3.4, tables and a self-contained HTML page for a predictivity run.

The page says first what the target was (simulated, real, or unknown: never a simulated result presented
as a real one), defines every metric with its range, puts the target's noise floor beside every PRPV, and
claims "lowest at X" only where paired intervals separate X from its neighbours.
"""

from __future__ import annotations

import html
import json
import time
from pathlib import Path

import numpy as np

from proxybench import __version__
from proxybench.experiments.predictivity.diagnosis import (
    baseline_findings,
    baselines_html,
    diagnosis_csv,
    diagnosis_findings,
    diagnosis_html,
    figure_pairs,
)
from proxybench.experiments.predictivity.run import PredictivityResult
from proxybench.experiments.proxies import param_label
from proxybench.experiments.reporting import html_img, pyplot, save_figure, source_commit

__all__ = ["DEFINITIONS", "THESIS", "agent_set_findings", "episodes_statement", "findings", "noise_statement",
           "plot_plan", "ppv_agent_frame", "pyplot", "save_figure", "source_commit", "write_report"]

THESIS = ("A. Courchesne, “On quantifying the value of simulation for training and evaluating robotic agents”, "
          "M.Sc. thesis, Université de Montréal (chapter 3: A. Courchesne, A. Censi, L. Paull, “On Assessing the "
          "Usefulness of Proxy Domains for Developing and Evaluating Embodied Agents”, IROS 2021)")

#: (name, range and direction, definition) of every figure in the report
DEFINITIONS = (
    ("PRPV", "[0, K(K−1)], lower is better",
     "Proxy Relative Predictive Value (thesis eq. 3.4.4): Σ_ij |α^proxy_ij − α^target_ij| over the dominance "
     "matrices of the K agents' mean performance (α_ij = 1 if agent i is at least as good as j on every task "
     "metric and better on one, 0 if the reverse, 0.5 if incomparable or equal). 0: the proxy orders every pair "
     "as the target does; one swapped pair costs 2."),
    ("PPV", "[0, ∞), lower is better",
     "Proxy Predictivity Value (thesis eq. 3.4.1), per agent: Σ_m β_m |mean in proxy − mean in target|, with "
     "β_m = 1 / (spread of metric m across the agents' target means), fixed from the target. The table shows "
     "the mean over agents; the sum over agents (ppv_sum) and each agent's PPV are in the details and "
     "usefulness.csv / ppv_agents.csv. Noise alone makes it positive: compare proxies with each other."),
    ("Pearson r (SRCC)", "[−1, 1], higher is better",
     "Habitat's sim-vs-real correlation coefficient: Pearson's r between proxy and target mean performance of "
     "the agents, per metric (pearson_<metric>) and averaged over the metrics that vary across agents; a "
     "metric with the same value for every agent has no correlation (the notes name it). Spearman's ρ and "
     "Kendall's τ_b (same range) are the rank versions."),
    ("MMRV", "[0, ∞) in the metric's unit, lower is better",
     "SIMPLER's mean maximum rank violation, per metric (mmrv_<metric>): for each agent, the largest target-"
     "performance gap to an agent the proxy orders the other way; averaged over agents. mmrv_scaled averages "
     "MMRV_m·β_m over the metrics (dimensionless)."),
    ("POD", "[0, 1], lower is better",
     "Naive pixel distance: the same open-loop commands (the PID agent's on the target) from the same start in "
     "proxy and target; mean |Δpixel| / 255 between the camera streams. Needs the target's camera, so it is "
     "only computed against the live reality model."),
    ("noise floor", "[0, K(K−1)] for PRPV",
     "PRPV (and PPV) of the target against a replicate of itself: two independent resamples of its own episodes "
     "(same count per agent). A proxy whose PRPV lies within it cannot be told from a perfect proxy with these "
     "data; PPV, a sum of |differences|, is positive from noise alone: its floor is the reference, not 0."),
    ("PRPV interval (order range)", "",
     "The plug-in PRPV with the smallest and largest PRPV of any orders the data cannot rule out: on each metric, "
     "two agents whose mean difference does not keep its sign in 95% of the paired resamples may be ordered "
     "either way (or tied) in that domain. It contains the point value, and is wide where pairs are near ties "
     "(more episodes settle them: proxybench plan)."),
    ("other intervals", "",
     "95% BCa intervals (scipy.stats.bootstrap) over paired resamples: the same episode indices, per agent, in "
     "the proxy and on the target (each proxy episode replays a target episode). Where BCa is undefined "
     "(e.g. every resample gives the same value) the percentile interval is shown."),
    ("Missing values", "",
     "An episode without a value for a metric (a refused agent, a failed robot episode) is left out of that "
     "metric's mean; an agent without any value is worst on it in PRPV, as on the benchmark's leaderboard, and "
     "left out of PPV, correlations and MMRV (the notes name it)."),
    ("Δ vs best", "PRPV units",
     "PRPV of this θ minus PRPV of the best θ of the same parameter, over paired resamples (the same target "
     "episodes, replayed from the same starts in both proxies). An interval above 0 separates the two."),
)






def _main_parameter(res: PredictivityResult) -> str:
    """The parameter figure 3.3 shows: trim when swept (as in the thesis), else the one with most values."""
    sweep = res.experiment.sweep
    return "trim" if "trim" in sweep else max(sweep, key=lambda k: len(sweep[k]))


_PANELS = (("prpv", "PRPV (↓)", "PRPV  [0, {kk}]"), ("ppv", "PPV, mean per agent (↓)", "PPV  [dimensionless]"),
           ("pearson", "SRCC: Pearson's r (↑)", "r  [−1, 1]"), ("pod", "POD (↓)", "POD  [0, 1]"))


def _band(ax, df, key, label):
    ax.plot(df.value, df[key], "o-", color="tab:blue", label=label)
    if f"{key}_low" in df:
        ax.fill_between(df.value, df[f"{key}_low"], df[f"{key}_high"], color="tab:blue", alpha=0.2, lw=0,
                        label="order range (95%)" if key == "prpv" else "95% BCa interval")


def _marks(ax, res: PredictivityResult, d, floor: bool) -> None:
    if floor:
        nf = res.noise
        ax.axhspan(nf.low, nf.high, color="0.55", alpha=0.25, lw=0, label="target noise floor (95%)")
    truth = d.truth.iloc[0]
    if np.isfinite(truth):
        ax.axvline(truth, color="tab:red", ls="--", lw=1, label="target's known θ")


def figure_3_3(res: PredictivityResult, path: Path) -> Path:
    """PRPV, PPV, SRCC (and POD where known) against the main swept parameter, side by side."""
    plt = pyplot()
    name = _main_parameter(res)
    df = res.frame()
    d = df[df.parameter == name].sort_values("value")
    panels = [p for p in _PANELS if p[0] != "pod" or d.pod.notna().any()]
    k = len(res.experiment.agents)
    fig, axes = plt.subplots(1, len(panels), figsize=(3.9 * len(panels), 3.6), layout="constrained")
    for ax, (key, title, ylabel) in zip(np.atleast_1d(axes), panels, strict=True):
        _band(ax, d, key, "proxy")
        _marks(ax, res, d, key == "prpv")
        ax.set_xlabel(f"proxy {param_label(name)}")
        ax.set_ylabel(ylabel.format(kk=k * (k - 1)))
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=7)
    fig.suptitle(_short(f"Usefulness of proxies with different {name} for predicting the ranking of {k} agents "
                        f"(target: {res.target.info.label})", 40 * len(panels)), fontsize=10)
    return save_figure(fig, path)


def figure_3_4(res: PredictivityResult, path: Path) -> Path:
    """PRPV against every swept parameter, with the target's noise floor."""
    plt = pyplot()
    df = res.frame()
    params = list(res.experiment.sweep)
    k = len(res.experiment.agents)
    fig, axes = plt.subplots(1, len(params), figsize=(3.9 * len(params), 3.6), squeeze=False, layout="constrained")
    for ax, name in zip(axes[0], params, strict=True):
        d = df[df.parameter == name].sort_values("value")
        _band(ax, d, "prpv", "proxy")
        _marks(ax, res, d, True)
        claim = res.claims.get(name)
        if claim is not None and claim.separated:
            ax.plot([claim.best], [float(d.prpv[d.value == claim.best].iloc[0])], "*", color="k", ms=11,
                    label="lowest (separated)")
        ax.set_xlabel(f"proxy {param_label(name)}")
        ax.set_ylabel(f"PRPV  [0, {k * (k - 1)}]")
        ax.set_title("PRPV (↓)", fontsize=10)
        ax.legend(fontsize=7)
    fig.suptitle(_short(f"PRPV for each swept parameter (target: {res.target.info.label})", 40 * len(params)),
                 fontsize=10)
    return save_figure(fig, path)


def _short(text: str, width: int) -> str:
    """A figure title that fits its figure (the full target statement is on the page)."""
    import textwrap

    return textwrap.shorten(text, max(width, 60), placeholder=" …")




def _fmt(v: float) -> str:
    return f"{v:g}"


def noise_statement(res: PredictivityResult) -> str:
    """How much of the best proxy's PRPV is what two replicates of the target differ by."""
    best, nf = res.best_row(), res.noise
    where = f"{best.parameter} = {_fmt(best.value)}"
    df = res.frame()
    equal = [f"{r.parameter} = {_fmt(r.value)}" for r in df[df.prpv == best.prpv.value].itertuples()
             if (r.parameter, r.value) != (best.parameter, best.value)]
    if equal:  # the best value is not one proxy's alone: say so
        where += f" (equally at {', '.join(equal)})"
    if best.prpv.value <= 0:
        return (f"The best proxy ({where}) orders the agents exactly as the target (PRPV 0); the target's noise "
                f"floor is {nf.value:.1f} [{nf.low:.1f}, {nf.high:.1f}].")
    share = min(1.0, nf.value / best.prpv.value)
    within = best.prpv.value <= nf.high
    return (f"Best PRPV {best.prpv.value:.1f} [{best.prpv.low:.1f}, {best.prpv.high:.1f}] at {where}; the "
            f"target's own noise floor (PRPV of the target against a replicate of itself, "
            f"{res.experiment.episode_count} episodes per agent) is {nf.value:.1f} [{nf.low:.1f}, {nf.high:.1f}]: "
            "about "
            f"{100 * share:.0f}% of the residual gap is sampling noise"
            + (", and the best proxy is within the noise floor (the data cannot tell it from a perfect proxy)."
               if within else "; the rest is a gap no swept θ closed."))


def episodes_statement(res: PredictivityResult) -> str:
    """How many of the target's pairs of agents are near ties, and what settling them would take."""
    import math

    from proxybench.tasks.metrics import METRICS
    from proxybench.usefulness.plan import pair_needs

    metrics = res.experiment.metrics
    needs = pair_needs(res.target.results, tuple(METRICS[m].higher_is_better for m in metrics), metrics)
    open_ = [p for p in needs if not p.settled]
    if not open_:
        return (f"Every pair of the {len(res.target.results)} agents is ordered on the target with "
                f"{res.experiment.episode_count} episodes per agent.")
    finite = sorted(p.episodes for p in open_ if math.isfinite(p.episodes))
    ties = len(open_) - len(finite)
    cheapest = ", ".join(f"{p.a} – {p.b}" for p in open_[:3])
    return (f"{len(open_)} of {len(needs)} pairs of agents are near ties on the target with "
            f"{res.experiment.episode_count} episodes per agent (their order is open, which widens every PRPV range)"
            + (f"; the cheapest to settle ({cheapest}) need about {_span(finite[0], finite[min(2, len(finite) - 1)])}"
               " episodes per agent" if finite else "")
            + (f"; {ties} look like ties within the noise" if ties else "")
            + ". `proxybench plan` works out the episodes and spends them where they settle most.")


def _code(escaped: str) -> str:
    """`commands` in (escaped) findings as <code>, as the terminal shows them in backticks.

    >>> _code("run `proxybench plan` first")
    'run <code>proxybench plan</code> first'
    """
    import re

    return re.sub(r"`([^`]+)`", r"<code>\1</code>", escaped)


def _span(lo: float, hi: float) -> str:
    """``7`` or ``7–9``: a range only when its ends differ (the report used to say "about 7–7 episodes").

    >>> _span(7, 7), _span(7, 9)
    ('7', '7–9')
    """
    return f"{lo:g}" if lo == hi else f"{lo:g}–{hi:g}"


def findings(res: PredictivityResult) -> list[str]:
    """Plain statements: where PRPV is lowest per parameter, and only as strongly as the paired intervals allow."""
    out = [noise_statement(res), episodes_statement(res)]
    if res.localisation is not None:  # a target measured through (simulated) watchtowers: what that adds
        out.append(res.localisation.statement)
    df = res.frame()
    for name, claim in res.claims.items():
        d = df[df.parameter == name].sort_values("value")
        truth = float(d.truth.iloc[0])
        known = f" (the target's known {name}: {_fmt(truth)})" if np.isfinite(truth) else ""
        if len(d) == 1:
            continue
        if claim.separated:
            parts = ", ".join(f"Δ vs {_fmt(v)}: {e.value:+.1f} [{e.low:+.1f}, {e.high:+.1f}]"
                              for v, e in claim.neighbours)
            out.append(f"{name}: PRPV is lowest at {_fmt(claim.best)}, separated from its neighbours ({parts})"
                       f"{known}.")
        else:
            plausible = ", ".join(_fmt(v) for v in claim.plausible)
            low = float(d.prpv.min())
            ties = [float(v) for v in d.value[np.isclose(d.prpv, low)]]
            where = (f"is equally small ({low:.1f}) at {', '.join(_fmt(v) for v in ties)}" if len(ties) > 1
                     else f"is smallest at {_fmt(claim.best)} ({low:.1f})")
            out.append(f"{name}: PRPV {where}, but the paired intervals do not separate the minimum from its "
                       f"neighbours; values the data cannot tell apart from it: {plausible}{known}.")
    out.extend(baseline_findings(res))
    out.extend(diagnosis_findings(res))
    out.extend(agent_set_findings(res))
    main = _main_parameter(res)
    d = df[df.parameter == main].sort_values("value")
    if len(d) >= 3:
        v = d.prpv.to_numpy()
        k = int(np.argmin(v))
        mono = bool(np.all(np.diff(v[: k + 1]) <= 0) and np.all(np.diff(v[k:]) >= 0))
        out.append(f"{main}: PRPV {'falls then rises monotonically' if mono else 'is not monotone'} around its "
                   f"smallest value (point values {', '.join(f'{x:.0f}' for x in v)}; see the intervals).")
    out += [f"Note: {n}." for n in res.notes()]
    return out


def agent_set_findings(res: PredictivityResult) -> list[str]:
    """How much PRPV's argmin depends on which agents were ranked, and whether the task's order uses both
    metrics (agents at a metric's cap tie on it, so only the other metric orders them)."""
    out = []
    for name, sens in res.agent_sensitivity.items():
        values = sorted(res.experiment.sweep[name])
        if len(values) < 2:
            continue
        k = len(sens.agents)
        stay = sum(a == sens.full_argmin for a in sens.loo_argmin)
        movers = [sens.agents[i] for i, a in enumerate(sens.loo_argmin) if a != sens.full_argmin]
        lo, hi = sens.interval()
        share = float(np.mean(sens.boot_argmin == sens.full_argmin))
        out.append(f"{name}, agent set: PRPV's smallest value is at {_fmt(values[sens.full_argmin])} with all {k} "
                   f"agents and stays there with any one agent left out in {stay}/{k} cases"
                   + (f" (moves without {', '.join(movers)})" if movers else "")
                   + f"; over {len(sens.boot_argmin)} bootstrap agent sets it stays in {100 * share:.0f}%, and "
                   f"PRPV/K(K−1) there spans [{lo[sens.full_argmin]:.2f}, {hi[sens.full_argmin]:.2f}].")
    o = res.order
    if o:
        caps = "; ".join(f"{int(o[key])} of {len(res.experiment.agents)} agents at the "
                         f"{res.experiment.metrics[int(key.rsplit('_', 1)[1])]} cap in every episode"
                         for key in o if key.startswith("agents_at_cap"))
        out.append(f"Task order on the target: of {int(o['pairs'])} agent pairs, {int(o['both_agree'])} are ordered "
                   f"alike by every metric, {int(o['decided_by_one_metric'])} by one metric while another ties, "
                   f"{int(o['incomparable'])} are incomparable, {int(o['equal'])} equal"
                   + (f" ({caps})" if caps else "") + ".")
    return out


def ppv_agent_frame(res: PredictivityResult):
    """One row per (proxy domain, agent): the agent's PPV (thesis eq. 3.4.1) with its BCa interval."""
    import pandas as pd

    rows = [{"domain": dom, "agent": a, "ppv": e.value, "ppv_low": e.low, "ppv_high": e.high, "method": e.method}
            for dom, u in res.details.items() for a, e in u.ppv_agents.items()]
    return pd.DataFrame(rows, columns=["domain", "agent", "ppv", "ppv_low", "ppv_high", "method"])


def _target_box(res: PredictivityResult) -> str:
    info = res.target.info
    colour, tag = {True: ("#fff4e5", "SIMULATED TARGET"), False: ("#e8f5e9", "REAL ROBOTS (declared by the recording)"),
                   None: ("#fffde7", "TARGET OF UNKNOWN NATURE")}[info.simulated]
    return (f'<div style="background:{colour};border:1px solid #ccc;padding:.6em 1em"><b>{tag}.</b> '
            f"{html.escape(info.statement)}</div>")


def _compact_table(res: PredictivityResult) -> str:
    df = res.frame()
    head = ("parameter", "value", "PRPV [order range]", "Δ vs best [95% paired CI]", "PPV (mean per agent) [95% CI]",
            "Pearson r (SRCC)", "Spearman ρ", "POD")
    rows = []
    for name in res.experiment.sweep:
        d = df[df.parameter == name].sort_values("value")
        for _, r in d.iterrows():
            mark = []
            if np.isfinite(r.truth) and abs(r.value - r.truth) < 1e-9:
                mark.append("known θ")
            if res.claims.get(name) and res.claims[name].best == r.value:
                mark.append("lowest" + ("" if res.claims[name].separated else ", not separated"))
            delta = ("—" if res.claims.get(name) and res.claims[name].best == r.value
                     else f"{r.delta_best:+.1f} [{r.delta_best_low:+.1f}, {r.delta_best_high:+.1f}]")
            pod = "n/a" if not np.isfinite(r.pod) else f"{r.pod:.3f}"
            cells = (name, f"{_fmt(r.value)}" + (f" <small>({', '.join(mark)})</small>" if mark else ""),
                     f"{r.prpv:.1f} [{r.prpv_low:.1f}, {r.prpv_high:.1f}]", delta,
                     f"{r.ppv:.2f} [{r.ppv_low:.2f}, {r.ppv_high:.2f}]", f"{r.pearson:.2f}", f"{r.spearman:.2f}", pod)
            style = ' style="background:#eef6ff"' if "lowest" in " ".join(mark) else ""
            rows.append(f"<tr{style}>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    nf = res.noise
    pf = res.ppv_noise
    ppv_cell = f"{pf.value:.2f} [{pf.low:.2f}, {pf.high:.2f}]" if pf is not None else ""
    rows.append(f'<tr style="background:#f2f2f2"><td>target noise floor</td><td>—</td><td>{nf.value:.1f} '
                f"[{nf.low:.1f}, {nf.high:.1f}]</td><td></td><td>{ppv_cell}</td><td></td><td></td><td></td></tr>")
    return ("<table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>" + "".join(rows) + "</table>")


def _diagnosis_section(res: PredictivityResult, files: dict[str, Path]) -> str:
    if not res.diagnosis:
        return ""
    return (f"<h2>Which pairs of agents each predictor orders differently from the target</h2>"
            f"<p>Start directions: whether an episode's start faces clockwise or counter-clockwise around the map's "
            f"centre; a pair listed under one of them is ordered differently there.</p>{diagnosis_html(res)}"
            f"{html_img(files['pairs'], 'per-pair disagreements')}")


def usefulness_table(res: PredictivityResult):
    """usefulness.csv / .parquet: a row per swept proxy, then the nominal θ's (parameter ``nominal``), the
    baseline the report shows beside them, with the same columns (its figures are the baselines' resamples)."""
    import pandas as pd

    from proxybench.experiments.baselines import NOMINAL

    df = res.frame()
    base = res.baselines.get(NOMINAL)
    if base is None:
        return df
    row: dict[str, object] = {"parameter": "nominal", "value": float("nan"), "domain": NOMINAL, "truth": float("nan")}
    for name, e in base.items():
        row[name], row[f"{name}_low"], row[f"{name}_high"] = e.value, e.low, e.high
    row["notes"] = "; ".join(base.notes)
    row["pod"] = float("nan")
    return pd.concat([df, pd.DataFrame([row])], ignore_index=True)


def write_report(res: PredictivityResult, out: str | Path, wall_s: float | None = None) -> dict[str, Path]:
    """PNG + SVG figures, CSV + Parquet tables and one self-contained ``report.html`` in ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = {
        "fig3_3": figure_3_3(res, out / "fig3_3_trim.png"),
        "fig3_4": figure_3_4(res, out / "fig3_4_parameters.png"),
        "csv": out / "usefulness.csv",
        "parquet": out / "usefulness.parquet",
        "ppv_agents": out / "ppv_agents.csv",
        "html": out / "report.html",
    }
    if res.diagnosis:
        files["pairs"] = figure_pairs(res, out / "pairs.png")
        files["diagnosis"] = diagnosis_csv(res, out / "diagnosis.csv")
    table = usefulness_table(res)
    table.to_csv(files["csv"], index=False)
    table.to_parquet(files["parquet"], index=False)
    per_agent = ppv_agent_frame(res)
    per_agent.to_csv(files["ppv_agents"], index=False)
    exp = res.experiment
    k = len(exp.agents)
    defs = "".join(f"<dt><b>{html.escape(n)}</b> <small>{html.escape(r)}</small></dt><dd>{html.escape(d)}</dd>"
                   for n, r, d in DEFINITIONS)
    metrics = ", ".join(html.escape(m) for m in exp.metrics)
    target_rows = "".join(
        f"<tr><td>{html.escape(a)}</td>" + "".join(f"<td>{v:.2f}</td>" for v in s.values()) + "</tr>"
        for a, s in sorted(res.target_scores.items(), key=lambda kv: -next(iter(kv[1].values())))
    )
    details = table.round(4).to_html(index=False, border=0)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>proxybench predictivity</title>
<style>body{{font-family:sans-serif;max-width:1150px;margin:2em auto;line-height:1.4;padding:0 1em}}
table{{border-collapse:collapse;font-size:13px;margin:.5em 0}}td,th{{border:1px solid #ccc;padding:2px 6px;
text-align:right}}td:first-child{{text-align:left}}dt{{margin-top:.4em}}details{{margin:.8em 0}}
.prov{{color:#555;font-size:13px}}</style></head><body>
<h1>Predictivity of simulator instances</h1>
{_target_box(res)}
<p class="prov">proxybench {__version__}, commit {html.escape(source_commit())}; {time.strftime("%Y-%m-%d %H:%M")};
method: {html.escape(THESIS)}.</p>
<p>{k} agents × {exp.episode_count} episodes × {exp.seconds:g} s on {html.escape(Path(exp.map).name)}; task metrics
{metrics}; each proxy replays every target episode from the same start pose and seed; {exp.n_boot} bootstrap
resamples (95% intervals){f"; wall time {wall_s:.0f} s" if wall_s else ""}.</p>
<h2>Findings</h2><p><small>PRPV, PPV, SRCC, POD, noise floor: <a href="#definitions">definitions and
ranges below</a>.</small></p><ul>{"".join(f"<li>{_code(html.escape(f))}</li>" for f in findings(res))}</ul>
<h2>Results</h2>{_compact_table(res)}
{"<h2>Baselines: no tuning, no simulator</h2>" + baselines_html(res) if res.baselines else ""}
<details><summary>every figure with its interval (per-metric correlations and MMRV, PPV sum, normalised PRPV,
notes, …)</summary>
{details}</details>
<details><summary>PPV of each agent (thesis eq. 3.4.1) in each proxy, with 95% BCa intervals</summary>
{per_agent.round(4).to_html(index=False, border=0)}</details>
<h2>Figure 3.3: usefulness metrics against proxy {html.escape(_main_parameter(res))}</h2>
{html_img(files["fig3_3"], "figure 3.3")}
<h2>Figure 3.4: PRPV for each swept parameter</h2>{html_img(files["fig3_4"], "figure 3.4")}
{_diagnosis_section(res, files)}
<h2 id="definitions">What the figures mean</h2><dl>{defs}</dl>
<h2>Agents on the target (mean over episodes)</h2><table><tr><th>agent</th>
{"".join(f"<th>{html.escape(m)}</th>" for m in exp.metrics)}</tr>{target_rows}</table>
<details><summary>configuration</summary><pre>{html.escape(json.dumps(
        {"experiment": exp.to_dict(), "target": res.target.info.details}, indent=1, default=str))}</pre></details>
</body></html>"""
    files["html"].write_text(page)
    return files


def plot_plan(plan, path: Path, target_label: str) -> Path:
    """The planner's curves against n episodes per agent: order-range width, and P(right θ) or open pairs."""
    plt = pyplot()
    n = [r.n for r in plan.rows]
    fig, axes = plt.subplots(1, 2, figsize=(9.5, 3.6), layout="constrained")
    axes[0].plot(n, [r.width_mean for r in plan.rows], "o-", label="mean")
    axes[0].plot(n, [r.width_q for r in plan.rows], "s--", label=f"{plan.confidence:.0%} of experiments below")
    if plan.width is not None:
        axes[0].axhline(plan.width, color="tab:red", lw=1, label=f"goal {plan.width:g}")
    axes[0].set_ylabel("PRPV order-range width")
    if plan.candidates:
        axes[1].plot(n, [r.p_correct for r in plan.rows], "o-", color="tab:green")
        if plan.p_correct_goal is not None:
            axes[1].axhline(plan.p_correct_goal, color="tab:red", lw=1)
        axes[1].set_ylabel(f"P(argmin PRPV = {', '.join(plan.best)})")
        axes[1].set_ylim(0, 1.02)
    else:
        axes[1].plot(n, [r.open_pairs for r in plan.rows], "o-", color="tab:orange")
        axes[1].set_ylabel("pairs of agents still open on the target")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xlabel("target episodes per agent")
    axes[0].legend(fontsize=7)
    fig.suptitle(_short(f"Sample-size plan from a pilot (target: {target_label})", 110), fontsize=10)
    return save_figure(fig, Path(path))
