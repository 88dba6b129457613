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

from proxybench.experiments.reporting import html_table, pyplot, save_figure
from proxybench.experiments.validate.measures import QUALITIES, Interval, ValidationSummary, regrets
from proxybench.experiments.validate.run import ValidationRun
from proxybench.usefulness.validation import minimum_detectable_effect

__all__ = ["answer", "primary_sentences", "write_validation_report"]

_LABELS = {"prpv_norm": "PRPV/K(K−1) regret", "kendall_gap": "1 − Kendall τ_b regret",
           "top1_regret": "top-1 regret", "topk_regret": "top-k regret"}


def _where(test, interim: bool) -> str:
    if interim:
        return f"over the {test.n + test.not_applicable} targets finished (every stratum together)"
    return f"in the {test.stratum} stratum"


def primary_sentences(summary: ValidationSummary) -> list[str]:
    """The primary comparison, one sentence per stratum and calibration, in the words the criteria fixed: "PRPV is
    non-inferior to X within m" or "superior to X" only when the test says so; otherwise "not shown", with the
    interval and n."""
    s = summary.settings
    out = []
    for test in summary.primary_tests:
        b, where = test.b, _where(test, summary.interim)
        level = f"one-sided {100 * (1 - test.alpha):.4g}% upper bound"
        if s.primary.multiplicity == "holm":
            level += f" (Holm's level for this test among {len(summary.primary_tests)})"
        skipped = (f"; {test.not_applicable} target(s) where {b} was not applicable left out"
                   if test.not_applicable else "")
        if test.n < 2:
            out.append(f"PRPV against {b} {where}: not tested ({test.n} target(s) with both picks{skipped}).")
            continue
        numbers = (f"PRPV − {b} {test.mean:+.4f} in PRPV/K(K−1) on held-out agents, {level} {test.upper:+.4f}, "
                   f"n = {test.n}{skipped}")
        assumed = minimum_detectable_effect(test.n, test.alpha, test.power) * s.assumed_sd
        mde = (f"; with {test.n} targets a margin of {test.mde:.3f} (observed SD {test.sd:.3f}) could be shown with "
               f"{test.power:.0%} power, {assumed:.3f} at the assumed SD {s.assumed_sd:g}")
        if test.superior:
            out.append(f"PRPV is superior to {b} {where}: {numbers} < 0.")
        elif test.noninferior:
            out.append(f"PRPV is non-inferior to {b} within {test.margin:g} {where}: {numbers} < {test.margin:g}.")
        else:
            out.append(f"PRPV non-inferior to {b} within {test.margin:g} {where}: not shown ({numbers} ≥ "
                       f"{test.margin:g}{mde}).")
    return out


def answer(summary: ValidationSummary) -> str:
    """The result as criteria.json decided it would be read: the primary comparison (PRPV against the
    calibrations, per stratum), then the secondary one against the nominal θ."""
    p = summary.primary
    problems = summary.criteria.problems
    failed = (f"PRE-REGISTRATION CHECK FAILED ({len(problems)} problem{'s' if len(problems) > 1 else ''}: "
              f"{problems[0]}{'; …' if len(problems) > 1 else ''}); read nothing below as the registered "
              "study's result. ") if problems else ""
    n, fam = summary.targets, summary.family
    head = (f"INTERIM LOOK, {n} of {summary.targets_planned} pre-registered targets (the decision waits for all of "
            "them; the strata are shown with the targets' θ in the final report only). ") if summary.interim else ""
    if summary.settings.quick:
        p_mde = p.minimum_detectable_difference if p is not None else float("nan")
        head = (f"QUICK MODE ({n} targets, {len(summary.settings.agents)} agents, {summary.settings.seconds:g}-s "
                "episodes): a smoke test of the study that CANNOT ANSWER THE QUESTION — with so few targets the "
                f"smallest difference it could detect is about {p_mde:.2f} PRPV/K(K−1), larger than any plausible "
                f"effect; run the full study (without --quick) for an answer. {head}")
    primary = (" ".join(primary_sentences(summary))
               or "The primary comparison (PRPV against the calibrations) was not run.")
    if p is None:
        return f"{failed}{head}{primary} The secondary comparison (PRPV against the nominal θ) was not run."
    verdict = ("Tuning with PRPV helped on held-out agents" if p.rejected else
               "This study does not show that tuning with PRPV helps on held-out agents")
    if summary.interim:
        verdict = ("so far PRPV's pick beats the nominal θ's" if p.rejected else
                   "so far the data do not show that tuning with PRPV helps on held-out agents")
    return (f"{failed}{head}{primary} Secondary, PRPV against the nominal θ: {verdict}: over {n} {fam} targets, "
            f"PRPV's pick had a mean regret {p.mean:+.4f} "
            f"[{p.low:+.4f}, {p.high:+.4f}] (PRPV/K(K−1), 95 % bootstrap over targets) relative to the nominal "
            f"θ's; it was better on {p.wins}, worse on {p.losses}, equal on {p.ties} targets; one-sided "
            f"Wilcoxon p = {p.p_wilcoxon:.3g} (α {p.alpha}; paired t p = {p.p_t:.3g}). The smallest mean "
            f"difference this study could detect with 80 % power is about {p.minimum_detectable_difference:.4f} "
            f"(d_z {p.d_z:.2f}, {n} targets).")


def _frame(run: ValidationRun, summary: ValidationSummary):
    """targets.csv: every target × method. At an interim look a continuous pick's θ (an estimate of the hidden θ)
    and the strata are left out."""
    import pandas as pd

    rows = []
    for i, r in enumerate(run.records):
        stratum = {"stratum": summary.strata[i]} if summary.strata else {}
        for method, pk in r.picks.items():
            theta = r.candidates[pk.index]
            hide = summary.interim and pk.index >= (r.grid_size or len(r.candidates))
            rows.append({"target": r.target, "map": r.map, **stratum, "method": method, "ties": pk.ties,
                         **({} if hide else {f"pick_{k}": v for k, v in theta.items()}),
                         **r.quality[pk.index].model_dump(),
                         **{f"regret_{m}": regrets(r, method, m) for m in QUALITIES}})
        for method, why in r.not_applicable.items():
            rows.append({"target": r.target, "map": r.map, **stratum, "method": method, "not_applicable": why})
    return pd.DataFrame(rows)


def _primary_table(summary: ValidationSummary) -> str:
    """The primary tests, and the sizes the criteria planned for each stratum."""
    plan = summary.settings.primary.strata
    planned = summary.planned
    head = ("stratum", "PRPV − …", "n", "not applicable", "mean", "upper bound", "level α", "margin", "non-inferior",
            "superior", "MDE (observed SD)", "planned / needed (criteria)")
    rows = []
    for t in summary.primary_tests:
        st = plan.get(t.stratum)
        cells = (t.stratum, t.b, t.n, t.not_applicable, f"{t.mean:+.4f}", f"{t.upper:+.4f}", f"{t.alpha:.4g}",
                 f"{t.margin:g}",
                 "yes" if t.noninferior else "not shown", "yes" if t.superior else "not shown", f"{t.mde:.3f}",
                 f"{planned[t.stratum]['targets']:g} / {st.needed}" if st and t.stratum in planned else "—")
        rows.append("<tr>" + "".join(f"<td>{html.escape(str(x))}</td>" for x in cells) + "</tr>")
    return "<table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>" + "".join(rows) + "</table>"


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


def _iv(i: Interval) -> str:
    return f"{i.value:+.4f} [{i.low:+.4f}, {i.high:+.4f}]"


def _agent_level_html(summary: ValidationSummary) -> str:
    """Each comparison's gain with targets alone and with targets and agent families resampled, and the agents
    that carry it (the five largest leave-one-out contributions)."""
    if not summary.agent_level:
        return "<p>Too few targets with both picks for the agent-level resampling.</p>"
    rows = [(name, _iv(a.targets_only), _iv(a.targets_and_families), a.targets_only.n_agents,
             "; ".join(f"{c.agent} ({c.family}) {c.loo:+.4f} [{c.low:+.4f}, {c.high:+.4f}]"
                       for c in a.contributions[:5]))
            for name, a in summary.agent_level.items()]
    return html_table(("comparison (negative: PRPV's pick better)", "targets resampled [95 %]",
                       "targets and agent families resampled [95 %]", "held-out agents",
                       "largest leave-one-agent-out contributions [95 %]"), rows)


def _savings_html(summary: ValidationSummary) -> str:
    if not summary.savings:
        return ("<p>Not computed: it needs at least 3 evaluation episodes per held-out agent (episodes_eval) on "
                "2 targets or more.</p>")
    rows = [(m, _iv(v.saved_share), f"{v.episodes_alone:.1f}", f"{v.episodes_with:.1f}",
             _iv(v.vs_nominal) if v.vs_nominal else "—", v.targets) for m, v in summary.savings.items()]
    return html_table(("method's pick as the predictor", "share of target episodes saved, median [95 %]",
                       "episodes per agent to decide a pair, alone (median)", "… with the proxy",
                       "Δ saved share vs nominal θ's proxy (mean [95 %])", "targets"), rows)


def secondary_lines(summary: ValidationSummary) -> list[str]:
    """The agent-level resampling and the episodes saved, one line each, for the terminal."""
    out = [f"{name}, agents as a sample: {_iv(a.targets_and_families)} with targets and agent families resampled "
           f"({_iv(a.targets_only)} with targets alone; {a.targets_only.n_agents} held-out agents)"
           for name, a in summary.agent_level.items()]
    if summary.savings:
        out.append("target episodes saved as the predictor for the held-out pairs (median over targets): " + ", ".join(
            f"{m} {v.saved_share.value:.0%} [{v.saved_share.low:.0%}, {v.saved_share.high:.0%}]"
            for m, v in summary.savings.items()))
    return out


def write_validation_report(run: ValidationRun, summary: ValidationSummary, out: str | Path) -> dict[str, Path]:
    """summary.json, targets.csv, two figures (PNG + SVG) and report.html in ``out``."""
    out = Path(out)
    files = {"summary": out / "summary.json", "csv": out / "targets.csv", "html": out / "report.html"}
    data = {**summary.model_dump(), "verdict": answer(summary)}  # the answer in words, beside the numbers
    files["summary"].write_text(json.dumps(data, indent=1, default=float))
    _frame(run, summary).to_csv(files["csv"], index=False)
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
    if summary.interim:
        strata_words = "The strata are assigned from the hidden θ and shown in the final report only."
    else:
        counts = {name: summary.strata.count(name) for name in s.primary.strata}
        strata_words = "Targets per stratum: " + ", ".join(
            f"{name} {c} ({html.escape(s.primary.strata[name].definition)}; planned "
            f"{summary.planned[name]['targets']:g})" for name, c in counts.items()) + "."
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
<h2>The primary comparison: PRPV against the calibrations, per stratum</h2>
<p><b>{html.escape(answer(summary))}</b></p>{_primary_table(summary)}
<p>Differences of quality on the held-out agents (PRPV/K(K−1), B on E2): the oracle cancels. A continuous pick
(trajectory_fit, calibration) is not a grid candidate, so its regret against the grid's oracle can be below 0.
{strata_words}</p>
<p>Criteria written {html.escape(crit.written)} at commit {html.escape(crit.commit)} (now
{html.escape(crit.commit_now)}); {check}. Per target: {len(s.agents) + bc} agents ({len(s.agents)} named,
{bc} behaviour-cloned checkpoints) split into tuning (A) and
held-out (B) sets; {s.episodes_tune} tuning and {s.episodes_eval} fresh evaluation episodes of
{s.seconds:g} s; candidates: the grid {html.escape(json.dumps({k: list(v) for k, v in s.grid.items()}))} (the
nominal θ at its centre) and the continuous methods' picks.</p>
<h2>Every method against the nominal θ (secondary)</h2>{_table(summary)}{_img(files['forest'])}
<h2>Regret per target</h2>{_img(files['strip'])}
<h2>Agents as a sample too</h2>
<p>The gain built from each held-out agent's share of PRPV/K(K−1), resampled over targets alone (the pool held
fixed) and over targets and agent families (another pool like this one); split: {html.escape(s.split)}. An interval
that widens a lot when families are resampled rests on a few families; the contributions name them.</p>
{_agent_level_html(summary)}
<h2>What each proxy is worth in target episodes (secondary)</h2>
<p>Each method's pick as PPI++'s predictor for deciding the held-out agents' pairs on E2 (the target's own paired
episodes, many proxy-only episodes assumed): the share of target episodes it saves for the same interval width, and
a plug-in count of the episodes per agent a decidable pair needs (<code>usefulness/episodes_saved.py</code>). With
{s.episodes_eval} episodes per agent these are rough; the proxy replays the target's starts and seeds but not its
noise, so a saving needs episode-level correlation between proxy and target.</p>
{_savings_html(summary)}
{reveal}
<details><summary>settings</summary><pre>{html.escape(json.dumps(s.model_dump(mode='json'), indent=1))}</pre></details>
</body></html>"""
    files["html"].write_text(page)
    return files
