"""The validation study's report: the answer to "does tuning help, on agents it was not tuned on?", its numbers.

``summary.json`` (machine-readable), ``targets.csv`` (every target × method: the pick, its qualities and
regrets), a figure of each method's paired difference from the nominal θ with its interval, a figure of the
regrets per target, and a self-contained ``report.html`` that states the primary result the way
``criteria.json`` fixed it before the first episode, and checks the code it was scored with.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import numpy as np

from proxybench.experiments.reporting import pyplot, save_figure
from proxybench.experiments.validate.measures import QUALITIES, ValidationSummary, regrets
from proxybench.experiments.validate.run import ValidationRun

__all__ = ["answer", "write_validation_report"]

_LABELS = {"prpv_norm": "PRPV/K(K−1) regret", "kendall_gap": "1 − Kendall τ_b regret",
           "top1_regret": "top-1 regret", "topk_regret": "top-k regret"}


def answer(summary: ValidationSummary) -> str:
    """The primary result in one sentence, as criteria.json decided it would be read."""
    p = summary.primary
    problems = summary.criteria.problems
    failed = (f"PRE-REGISTRATION CHECK FAILED ({len(problems)} problem{'s' if len(problems) > 1 else ''}: "
              f"{problems[0]}{'; …' if len(problems) > 1 else ''}); read nothing below as the registered "
              "study's result. ") if problems else ""
    if p is None:
        return failed + "The primary comparison (PRPV against the nominal θ) was not run."
    n, fam = summary.targets, summary.family
    verdict = ("Tuning with PRPV helped on held-out agents" if p.rejected else
               "This study does not show that tuning with PRPV helps on held-out agents")
    if summary.interim:
        verdict = (f"INTERIM LOOK, {n} of {summary.targets_planned} pre-registered targets (the decision waits for "
                   f"all of them): " + ("so far PRPV's pick beats the nominal θ's" if p.rejected else
                                       "so far the data do not show that tuning with PRPV helps on held-out agents"))
    return (f"{failed}{verdict}: over {n} {fam} targets, PRPV's pick had a mean regret {p.mean:+.4f} "
            f"[{p.low:+.4f}, {p.high:+.4f}] (PRPV/K(K−1), 95 % bootstrap over targets) relative to the nominal "
            f"θ's; it was better on {p.wins}, worse on {p.losses}, equal on {p.ties} targets; one-sided "
            f"Wilcoxon p = {p.p_wilcoxon:.3g} (α {p.alpha}; paired t p = {p.p_t:.3g}). The smallest mean "
            f"difference this study could detect with 80 % power is about {p.minimum_detectable_difference:.4f} "
            f"(d_z {p.d_z:.2f}, {n} targets).")


def _frame(run: ValidationRun):
    import pandas as pd

    rows = []
    for r in run.records:
        for method, pk in r.picks.items():
            theta = r.candidates[pk.index]
            rows.append({"target": r.target, "map": r.map, "method": method, "ties": pk.ties,
                         **{f"pick_{k}": v for k, v in theta.items()}, **r.quality[pk.index].model_dump(),
                         **{f"regret_{m}": regrets(r, method, m) for m in QUALITIES}})
    return pd.DataFrame(rows)


def _forest(summary: ValidationSummary, path: Path) -> Path:
    plt = pyplot()
    methods = [m for m in summary.methods if m != "nominal"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 0.45 * len(methods) + 1.6), layout="constrained")
    for ax, measure in zip(axes, ("prpv_norm", "top1_regret"), strict=True):
        for y, m in enumerate(methods):
            c = getattr(summary.methods[m], measure).vs_nominal
            colour = "tab:green" if c.high < 0 else "tab:red" if c.low > 0 else "0.3"
            ax.errorbar(c.mean, y, xerr=[[c.mean - c.low], [c.high - c.mean]], fmt="o", color=colour,
                        capsize=3)
        ax.axvline(0, color="k", lw=0.8)
        ax.set_yticks(range(len(methods)), methods)
        ax.set_xlabel(f"{_LABELS[measure]}: method − nominal θ (95 %; < 0: better)")
    fig.suptitle(f"paired over {summary.targets} {summary.family} targets (held-out agents, fresh episodes)",
                 fontsize=10)
    return save_figure(fig, path)


def _strip(run: ValidationRun, summary: ValidationSummary, path: Path) -> Path:
    plt = pyplot()
    methods = list(summary.methods)
    fig, ax = plt.subplots(figsize=(1.0 + 0.6 * len(methods), 3.6), layout="constrained")
    rng = np.random.default_rng(0)
    for x, m in enumerate(methods):
        v = np.array([regrets(r, m) for r in run.records], float)
        ax.plot(x + rng.uniform(-0.18, 0.18, len(v)), v, ".", alpha=0.6)
        ax.plot([x - 0.3, x + 0.3], [np.nanmean(v)] * 2, "k-")
    ax.set_xticks(range(len(methods)), methods, rotation=45, ha="right")
    ax.set_ylabel("PRPV/K(K−1) regret per target (0: the oracle θ)")
    return save_figure(fig, path)


def _img(path: Path) -> str:
    return f'<img src="data:image/png;base64,{base64.b64encode(path.read_bytes()).decode()}" style="max-width:100%">'


def _table(summary: ValidationSummary) -> str:
    head = ("method", "mean PRPV regret", "Δ vs nominal [95 %]", "better / worse / equal", "one-sided p (Wilcoxon)",
            "mean top-1 regret", "Δ top-1 vs nominal", "hit rate (within one grid step of the oracle)", "ties")
    rows = []
    for m, e in summary.methods.items():
        c, t1, h = e.prpv_norm.vs_nominal, e.top1_regret, e.hit_rate
        cells = (m, f"{e.prpv_norm.mean_regret:.4f}", f"{c.mean:+.4f} [{c.low:+.4f}, {c.high:+.4f}]",
                 f"{c.wins} / {c.losses} / {c.ties}", f"{c.p_wilcoxon:.3g}", f"{t1.mean_regret:.3f}",
                 f"{t1.vs_nominal.mean:+.3f} [{t1.vs_nominal.low:+.3f}, {t1.vs_nominal.high:+.3f}]",
                 f"{h.hits}/{h.targets} [{h.low:.2f}, {h.high:.2f}]", f"{e.ties:.2f}")
        rows.append("<tr>" + "".join(f"<td>{html.escape(str(x))}</td>" for x in cells) + "</tr>")
    return "<table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>" + "".join(rows) + "</table>"


def write_validation_report(run: ValidationRun, summary: ValidationSummary, out: str | Path) -> dict[str, Path]:
    """summary.json, targets.csv, two figures (PNG + SVG) and report.html in ``out``."""
    out = Path(out)
    files = {"summary": out / "summary.json", "csv": out / "targets.csv", "html": out / "report.html"}
    files["summary"].write_text(json.dumps(summary.model_dump(), indent=1, default=float))
    _frame(run).to_csv(files["csv"], index=False)
    files["forest"] = _forest(summary, out / "vs_nominal.png")
    files["strip"] = _strip(run, summary, out / "regrets.png")
    crit = summary.criteria
    check = ("the scoring code is the one criteria.json hashed" if crit.scoring_unchanged else
             "WARNING: the scoring code differs from the one criteria.json hashed")
    if crit.problems:
        items = "".join(f"<li>{html.escape(p)}</li>" for p in crit.problems)
        banner = ('<div style="background:#fdd;border:3px solid #c00;padding:.6em 1em"><b>PRE-REGISTRATION CHECK '
                  f"FAILED.</b> Read nothing below as the registered study's result:<ul>{items}</ul></div>")
    else:
        banner = ('<p>Pre-registration checked: criteria.json as registered, looks.jsonl\'s chain intact, every '
                  "target record as logged, the scoring code as hashed, no cached episode older than the "
                  "criteria.</p>")
    if summary.interim:
        reveal = ("<h2>The targets' θ</h2><p>Hidden until the final report: an interim look shows no target's "
                  "θ.</p>")
    else:
        reveal = ("<h2>The targets' θ (revealed after scoring)</h2>"
                  f"<pre>{html.escape(json.dumps(summary.truths, indent=1))}</pre>")
    s = run.settings
    bc = s.bc_agents  # checkpoints the study trains: agents too, though not named in the settings
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>proxybench validate</title>
<style>body{{font-family:sans-serif;max-width:1150px;margin:2em auto;line-height:1.4;padding:0 1em}}
table{{border-collapse:collapse;font-size:13px}}td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}
td:first-child{{text-align:left}}</style></head><body>
<h1>Does tuning help, on agents it was not tuned on?</h1>
{banner}
<div style="background:#fff4e5;border:1px solid #ccc;padding:.6em 1em"><b>SIMULATED TARGETS.</b> Family
{html.escape(s.family)}: {summary.targets} targets drawn from a hidden seed (revealed below, after scoring, in the final
report only);
no real robot was involved.</div>
<p><b>{html.escape(answer(summary))}</b></p>
<p>Criteria written {html.escape(crit.written)} at commit {html.escape(crit.commit)} (now
{html.escape(crit.commit_now)}); {check}. Per target: {len(s.agents) + bc} agents ({len(s.agents)} named,
{bc} behaviour-cloned checkpoints) split into tuning (A) and
held-out (B) sets; {s.episodes_tune} tuning and {s.episodes_eval} fresh evaluation episodes of
{s.seconds:g} s; candidates: the grid {html.escape(json.dumps({k: list(v) for k, v in s.grid.items()}))} and the
nominal θ.</p>
<h2>Every method against the nominal θ</h2>{_table(summary)}{_img(files['forest'])}
<h2>Regret per target</h2>{_img(files['strip'])}
{reveal}
<details><summary>settings</summary><pre>{html.escape(json.dumps(s.model_dump(mode='json'), indent=1))}</pre></details>
</body></html>"""
    files["html"].write_text(page)
    return files
