"""Tables, figures and a self-contained HTML page for the held-out experiment.

The page opens with what the targets were (all simulated) and with the pass criteria *as written before
the run* (``criteria.json``, its time and hash), then the hit rates with their Wilson intervals and the rate
a random pick would reach, and only then the cases, their revealed truths and the agent-set analyses.
"""

from __future__ import annotations

import hashlib
import html
import json
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from proxybench import __version__
from proxybench.experiments.heldout.analysis import HeldOutResult
from proxybench.experiments.predictivity.report import THESIS
from proxybench.experiments.reporting import html_img, html_table, pyplot, save_figure, source_commit

__all__ = ["findings", "write_heldout_report"]


def _pct(x: float) -> str:
    return "n/a" if not np.isfinite(x) else f"{100 * x:.0f}%"


def _rate_text(r) -> str:
    return f"{r.hits}/{r.n} = {_pct(r.rate)} [{_pct(r.low)}, {_pct(r.high)}]"


def _episodes(res: HeldOutResult) -> dict[str, int]:
    s = res.settings
    k, n = len(res.run.agents), s.episodes + s.reference_episodes
    cases = len(res.run.cases)
    return {"agents": k, "per_agent": n, "eval": s.episodes, "ref": s.reference_episodes,
            "target": cases * k * n, "proxy": len(res.run.grid) * k * n, "cases": cases,
            "held_out": sum(cr.case.kind == "held-out" for cr in res.run.cases)}


def findings(res: HeldOutResult) -> list[str]:
    """Plain statements of what the hit rates say, as strongly as their intervals allow."""
    task, ref, tol = res.primary()
    e = _episodes(res)
    out = [f"Primary criterion (fixed before the run): on task '{task}', a pick within {tol} grid step(s) of a "
           f"{'best available θ' if ref == 'order' else 'grid θ nearest the hidden truth'}; {e['held_out']} held-out "
           f"targets, {e['agents']} agents × {e['eval']} evaluation episodes (+ {e['ref']} reference episodes) each."]
    rates = [r for r in res.rates if (r.task, r.reference, r.tolerance) == (task, ref, tol)]
    for r in rates:
        verdict = ("above chance (the interval's lower end exceeds it)" if r.low > r.chance else
                   "not distinguishable from a random pick" if r.high >= r.chance else "below chance")
        out.append(f"{r.metric}: {_rate_text(r)} (random pick: {_pct(r.chance)}): {verdict}.")
    for c in res.comparisons:
        if (c.task, c.reference, c.tolerance) == (task, ref, tol) and c.p < 0.05:
            better = "PRPV" if c.prpv_only > c.metric_only else c.metric
            out.append(f"PRPV vs {c.metric}: {better} hits more often (PRPV alone {c.prpv_only}, "
                       f"{c.metric} alone {c.metric_only}, exact McNemar p = {c.p:.3f}).")
    held = [sc for sc in res.scores if sc.kind == "held-out" and sc.task == task and sc.reference["truth"]]
    if held:
        near = sum(any(res.run.grid.within(b, sc.reference["truth"], tol) for b in sc.reference["order"])
                   for sc in held)
        out.append(f"Where the structure moved the optimum: the best available θ lies within {tol} grid step(s) of "
                   f"the grid θ nearest the hidden truth in {near}/{len(held)} held-out targets; in the others no "
                   "proxy near the truth orders the agents best, so a metric that finds the truth misses the best "
                   "available θ and vice versa.")
    neg = [sc for sc in res.scores if sc.kind == "negative" and sc.task == task]
    for sc in neg:
        moved = not res.run.grid.within(sc.reference["order"][0], sc.reference["truth"], tol) if \
            sc.reference["truth"] else None
        hit = sc.hits[("PRPV", ref, tol)]
        out.append(f"Negative case ({sc.case}): PRPV picks {res.run.grid.label(sc.picks['PRPV'])} — "
                   f"{'a hit' if hit else 'a miss'}; the best available θ is "
                   f"{'; '.join(res.run.grid.label(i) for i in sc.reference['order'])}"
                   + ("" if moved is None else (", away from the truth (the optimum moved)" if moved else
                                                ", within tolerance of the truth (the optimum did not move)")) + ".")
    ab = res.agent_boot
    if np.isfinite(ab.interval[0]):
        out.append(f"Over the agent population ({ab.n_boot} bootstrap agent sets, the same set in every case): "
                   f"PRPV's hit rate lies in [{_pct(ab.interval[0])}, {_pct(ab.interval[1])}] (95%); its pick "
                   f"stays within {ab.tolerance} step(s) of the full set's in {_pct(ab.pick_stays)} of "
                   "the draws.")
    loo = [h for sc in res.scores if sc.task == task and sc.kind == "held-out" for h in sc.loo_hits]
    if loo:
        out.append(f"Leaving one agent out: PRPV hits in {sum(loo)}/{len(loo)} = {_pct(np.mean(loo))} of "
                   "(target, left-out agent) combinations (reference recomputed without the agent).")
    return out


def fig_hit_rates(res: HeldOutResult, path: Path) -> Path:
    """Hit rate per metric with Wilson intervals and the random-pick rate, per reference and tolerance."""
    plt = pyplot()
    task = res.primary()[0]
    combos = [(ref, tol) for ref in ("order", "truth") for tol in res.settings.criteria.tolerances]
    fig, axes = plt.subplots(1, len(combos), figsize=(3.6 * len(combos), 3.4), squeeze=False, layout="constrained")
    for ax, (ref, tol) in zip(axes[0], combos, strict=True):
        rs = [r for r in res.rates if (r.task, r.reference, r.tolerance) == (task, ref, tol)]
        x = np.arange(len(rs))
        ax.bar(x, [r.rate for r in rs], color="tab:blue", alpha=0.7)
        ax.errorbar(x, [r.rate for r in rs], yerr=[[r.rate - r.low for r in rs], [r.high - r.rate for r in rs]],
                    fmt="none", color="k", capsize=3, label="95% Wilson")
        ax.plot(x, [r.chance for r in rs], "_", color="tab:red", ms=18, mew=2, label="random pick")
        ax.set_xticks(x, [r.metric.split(" (")[0] for r in rs], rotation=45, ha="right", fontsize=8)
        ax.set_ylim(0, 1.05)
        ax.set_title(f"{'best available θ' if ref == 'order' else 'nearest truth'}, ≤ {tol} step", fontsize=9)
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel("hit rate over held-out targets")
    fig.suptitle(f"How often each metric picks the right proxy θ (task: {task}; simulated targets)", fontsize=10)
    return save_figure(fig, path)


def fig_prpv_maps(res: HeldOutResult, path: Path) -> Path:
    """PRPV over the grid for every case: truth (×), best available θ (□), each metric's pick (markers)."""
    plt = pyplot()
    task = res.primary()[0]
    grid = res.run.grid
    scs = [sc for sc in res.scores if sc.task == task]
    cols = min(4, len(scs))
    rows = -(-len(scs) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.3 * cols, 2.9 * rows), squeeze=False, layout="constrained")
    markers = dict(zip([lb for lb in scs[0].picks], "o^sDvP", strict=False))
    two = len(grid.names) == 2
    shape = grid.shape if two else (grid.shape[0], 1)
    for ax, sc in zip(axes.flat, scs, strict=False):
        img = sc.values["PRPV"].reshape(shape)
        ax.imshow(img.T, origin="lower", cmap="viridis", aspect="auto")
        def xy(i: int) -> tuple[int, int]:
            idx = grid.indices[i]
            return (idx[0], idx[1] if two else 0)
        for i in sc.reference["order"]:
            ax.add_patch(plt.Rectangle(np.subtract(xy(i), 0.5), 1, 1, fill=False, ec="w", lw=2))
        for lb, pk in sorted(sc.picks.items(), key=lambda kv: kv[0] == "PRPV"):  # PRPV drawn last, on top
            ax.plot(*xy(pk), markers[lb], mfc="none", mec="tab:red" if lb == "PRPV" else "orange",
                    ms=11 if lb == "PRPV" else 8, mew=2 if lb == "PRPV" else 1, label=lb.split(" (")[0])
        if all(n in sc.truth for n in grid.names):
            tx = np.interp(sc.truth[grid.names[0]], grid.values[0], range(shape[0]))
            ty = np.interp(sc.truth[grid.names[1]], grid.values[1], range(shape[1])) if two else 0
            ax.plot(tx, ty, "x", color="w", ms=9, mew=2)
        ax.set_title(f"{sc.case} ({sc.kind})", fontsize=8)
        ax.set_xticks(range(shape[0]), [f"{v:g}" for v in grid.values[0]], fontsize=7)
        ax.set_xlabel(grid.names[0], fontsize=7)
        if two:
            ax.set_yticks(range(shape[1]), [f"{v:g}" for v in grid.values[1]], fontsize=7)
            ax.set_ylabel(grid.names[1], fontsize=7)
    for ax in list(axes.flat)[len(scs):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=6, loc="upper left")
    fig.suptitle("PRPV over the grid (dark = low); × hidden truth, □ best available θ, markers: picks", fontsize=10)
    return save_figure(fig, path)


def tables(res: HeldOutResult) -> dict[str, Any]:
    """(rates, cases, values, comparisons: PRPV against each metric, McNemar) as pandas frames."""
    import pandas as pd

    grid = res.run.grid
    rates = pd.DataFrame([{**r.__dict__, "rate": r.rate} for r in res.rates])
    cases, values = [], []
    for sc in res.scores:
        row = {"case": sc.case, "kind": sc.kind, "task": sc.task,
               **{f"truth_{n}": sc.truth.get(n, np.nan) for n in grid.names},
               "nearest_truth": "; ".join(grid.label(i) for i in sc.reference["truth"]),
               "best_available": "; ".join(grid.label(i) for i in sc.reference["order"]),
               "disagreement_min": float(np.min(sc.disagreement)), "resolved_entries": sc.resolved,
               "reference_stability": sc.stability, "noise_floor": sc.noise.value,
               "noise_floor_low": sc.noise.low, "noise_floor_high": sc.noise.high,
               "prpv_pick_separated": sc.prpv_separated, "loo_hit_rate": float(np.mean(sc.loo_hits)) if sc.loo_hits
               else np.nan, **{f"order_{k}": v for k, v in sc.structure.items()}}
        for lb, pk in sc.picks.items():
            row[f"pick {lb}"] = grid.label(pk)
            row[f"ties {lb}"] = sc.ties[lb]
            for (m, ref, tol), h in sc.hits.items():
                if m == lb:
                    row[f"hit {lb} {ref}≤{tol}"] = h
        cases.append(row)
        for g in range(len(grid)):
            values.append({"case": sc.case, "task": sc.task, **grid.points[g], "disagreement": sc.disagreement[g],
                           "prpv_low": sc.prpv_interval[0][g], "prpv_high": sc.prpv_interval[1][g],
                           **{lb: v[g] for lb, v in sc.values.items()}})
    return {"rates": rates, "cases": pd.DataFrame(cases), "values": pd.DataFrame(values),
            "comparisons": pd.DataFrame([asdict(c) for c in res.comparisons])}


def _rates_html(res: HeldOutResult, task: str) -> str:
    neg = {sc.case: sc for sc in res.scores if sc.kind == "negative" and sc.task == task}
    rows = []
    for r in [x for x in res.rates if x.task == task]:
        cmp = next((c for c in res.comparisons if c.key() == (task, r.reference, r.tolerance, r.metric)), None)
        rows.append([r.metric, "best available θ" if r.reference == "order" else "nearest truth", r.tolerance,
                     _rate_text(r), _pct(r.chance),
                     ", ".join(f"{'hit' if sc.hits[(r.metric, r.reference, r.tolerance)] else 'miss'}"
                               for sc in neg.values()) or "—",
                     "—" if cmp is None else f"{cmp.prpv_only} / {cmp.metric_only}, p = {cmp.p:.2f}"])
    return html_table(["metric", "reference", "≤ steps", "hits over held-out targets [95% Wilson]", "random pick",
                   "negative case", "PRPV only / metric only (McNemar)"], rows)


def _cases_html(res: HeldOutResult, task: str) -> str:
    grid = res.run.grid
    rows = []
    for sc in [x for x in res.scores if x.task == task]:
        truth = ", ".join(f"{n}={sc.truth[n]:.3g}" for n in grid.names if n in sc.truth)
        pk = sc.picks["PRPV"]
        others = "; ".join(f"{lb.split(' (')[0]}: {grid.label(p)}" for lb, p in sc.picks.items() if lb != "PRPV")
        rows.append([sc.case, sc.kind, truth, "; ".join(grid.label(i) for i in sc.reference["truth"]),
                     "; ".join(grid.label(i) for i in sc.reference["order"]),
                     f"{np.min(sc.disagreement):g} / {sc.resolved}", _pct(sc.stability),
                     f"{grid.label(pk)} ({sc.values['PRPV'][pk]:.1f} [{sc.prpv_interval[0][pk]:.1f}, "
                     f"{sc.prpv_interval[1][pk]:.1f}]; {sc.ties['PRPV']} tied; "
                     f"{'separated' if sc.prpv_separated else 'not separated'} from its neighbours)",
                     f"{sc.noise.value:.1f} [{sc.noise.low:.1f}, {sc.noise.high:.1f}]", others,
                     f"{sum(p != pk for p in sc.loo_picks)}/{len(sc.loo_picks)}"])
    return html_table(["case", "kind", "revealed truth", "nearest grid θ", "best available θ", "D min / resolved",
                   "reference stable", "PRPV pick (value [order range])", "noise floor", "other metrics' picks",
                   "agents whose removal moves PRPV's pick"], rows)


def _structure_html(res: HeldOutResult) -> str:
    rows = []
    for task, ms in res.settings.tasks.items():
        st = [sc.structure for sc in res.scores if sc.task == task]
        mean = {k: float(np.mean([x.get(k, np.nan) for x in st])) for k in st[0]}
        caps = "; ".join(f"{ms[int(k.rsplit('_', 1)[1])]}: {mean[k]:.1f} of {len(res.run.agents)} agents always at "
                         f"the cap ({_pct(mean[k.replace('agents_at_cap', 'at_cap')])} of agent-episodes)"
                         for k in mean if k.startswith("agents_at_cap"))
        rows.append([task, f"{mean['pairs']:.0f}", f"{mean['both_agree']:.1f}", f"{mean['decided_by_one_metric']:.1f}",
                     f"{mean['incomparable']:.1f}", f"{mean['equal']:.1f}", caps or "—"])
    return html_table(["task", "agent pairs", "both metrics agree", "one metric ties, the other decides",
                   "incomparable (metrics disagree)", "equal", "saturation"], rows)


def write_heldout_report(res: HeldOutResult, out: str | Path) -> dict[str, Path]:
    """``report.html``, figures (PNG + SVG) and tables (CSV + Parquet) in ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = {"fig_hits": fig_hit_rates(res, out / "fig_hit_rates.png"),
             "fig_maps": fig_prpv_maps(res, out / "fig_prpv_maps.png"), "html": out / "report.html"}
    for name, df in tables(res).items():
        df.to_csv(out / f"{name}.csv", index=False)
        df.astype({c: str for c in df.columns if df[c].dtype == object}).to_parquet(out / f"{name}.parquet",
                                                                                    index=False)
        files[name] = out / f"{name}.csv"
    s = res.settings
    e = _episodes(res)
    crit = res.run.criteria_file
    crit_doc = json.loads(crit.read_text()) if crit and crit.exists() else {}
    crit_hash = hashlib.sha256(crit.read_bytes()).hexdigest()[:16] if crit and crit.exists() else "—"
    task, ref, tol = res.primary()
    cases = "".join(f"<li><b>{html.escape(cr.case.name)}</b>: {html.escape(cr.case.description)} — "
                    f"{html.escape(cr.target.info.statement)}</li>" for cr in res.run.cases)
    secondary = "".join(f"<h3>Task {html.escape(t)}</h3>{_rates_html(res, t)}" for t in s.tasks if t != task)
    revealed = html_table(["case", "revealed θ and effects"], [
        [cr.case.name, ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in
                                 sorted(cr.case.reveal().items()) if not isinstance(v, tuple))]
        for cr in res.run.cases])
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>proxybench held-out targets</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto;line-height:1.4;padding:0 1em}}
table{{border-collapse:collapse;font-size:12px;margin:.5em 0}}td,th{{border:1px solid #ccc;padding:2px 6px}}
.box{{border:1px solid #ccc;padding:.6em 1em;margin:.6em 0}}.prov{{color:#555;font-size:13px}}</style></head><body>
<h1>Held-out targets: how often does each metric pick the best available proxy θ?</h1>
<div class="box" style="background:#fff4e5"><b>SIMULATED TARGETS.</b> Every case is a simulated stand-in for a
Duckiebot (held-out targets drawn from a hidden seed, and the shipped reality model); no real robot was involved.
</div>
<div class="box" style="background:#eef6ff"><b>Pass criteria, fixed before the run</b> (criteria.json, written
{html.escape(str(crit_doc.get("written", "?")))}, sha256 {crit_hash}): on task <b>{html.escape(task)}</b>
({", ".join(map(html.escape, s.tasks[task]))}), a metric's pick is a hit when it lies within <b>{tol}</b> grid
step(s) of {"a <b>best available θ</b>" if ref == "order" else "the grid θ <b>nearest the hidden truth</b>"}.
<br><b>Best available θ</b>: {html.escape(crit_doc.get("best_available_definition", ""))}</div>
<p class="prov">proxybench {__version__}, commit {html.escape(source_commit())}; {time.strftime("%Y-%m-%d %H:%M")};
method: {html.escape(THESIS)}. {e['cases']} cases ({e['held_out']} held-out); {e['agents']} agents; per case the
target ran {e['agents']} × {e['per_agent']} episodes ({e['eval']} evaluation + {e['ref']} reference) of
{s.seconds:g} s on {html.escape(Path(s.map).name)}, and each of {len(res.run.grid)} grid proxies
({html.escape(", ".join(f"{k} ∈ {{{', '.join(f'{v:g}' for v in vs)}}}" for k, vs in s.grid.items()))})
replayed them; {res.run.simulated_episodes} episodes simulated in this run; wall time {res.run.wall_s:.0f} s.</p>
<h2>Findings</h2><ul>{"".join(f"<li>{html.escape(f)}</li>" for f in findings(res))}</ul>
<h2>Hit rates (task {html.escape(task)})</h2>{_rates_html(res, task)}{html_img(files["fig_hits"], "hit rates")}
<h2>Cases</h2>{_cases_html(res, task)}{html_img(files["fig_maps"], "PRPV maps")}
<h2>Does the task's order use both metrics?</h2><p>Agent pairs on the target's episodes (mean over cases):</p>
{_structure_html(res)}
<h2>Other tasks</h2>{secondary or "<p>none</p>"}
<h2>The cases</h2><ul>{cases}</ul>
<details><summary>revealed θ and effects of every case (read only after every episode ran)</summary>{revealed}
</details>
<details><summary>settings</summary><pre>{html.escape(json.dumps(s, indent=1, default=str))}</pre></details>
</body></html>"""
    files["html"].write_text(page)
    return files
