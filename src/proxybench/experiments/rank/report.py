"""rank's report: rank.json (every pair, with and without the proxy), pairs.csv, the rank-sets drawn (rank.png)
and rank.html; the terminal view; a canned result for the study contract."""

from __future__ import annotations

import html
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.experiments.rank.run import RankResult
from proxybench.experiments.reporting import html_img, html_table, pyplot, save_figure, source_commit

__all__ = ["canned_rank", "plot_rank_sets", "show_rank", "write_rank"]

_WORDS = {"a>b": "a better", "b>a": "b better", "tie": "tie (within ε)", "undecided": "undecided"}


def write_rank(res: RankResult, out: str | Path) -> list[Path]:
    """rank.json, pairs.csv, rank.png (+ .svg) and rank.html in ``out``."""
    import pandas as pd

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "rank.json").write_text(json.dumps(res.to_dict(), indent=1, default=float))
    alone = {(p.a, p.b, p.metric): p for p in res.ranking.target_only}
    rows = [{**p.to_dict(), "interval_low": p.interval[0], "interval_high": p.interval[1],
             "target_only_decision": alone[(p.a, p.b, p.metric)].decision,
             "target_only_low": alone[(p.a, p.b, p.metric)].interval[0],
             "target_only_high": alone[(p.a, p.b, p.metric)].interval[1]} for p in res.ranking.pairs]
    frame = pd.DataFrame(rows).drop(columns=["interval"])
    frame.to_csv(out / "pairs.csv", index=False)
    png = plot_rank_sets(res, out / "rank.png")
    (out / "rank.html").write_text(_page(res, png))
    return [out / "rank.json", out / "pairs.csv", png, out / "rank.html"]


def plot_rank_sets(res: RankResult, path: Path) -> Path:
    """One panel per metric: each agent's rank-set as a bar from its best to its worst possible rank."""
    r = res.ranking
    fig, axes = pyplot().subplots(1, len(r.metrics), figsize=(4.2 * len(r.metrics), 0.45 * len(r.agents) + 1.4),
                                  squeeze=False)
    for ax, metric in zip(axes[0], r.metrics, strict=True):
        sets = r.rank_sets[metric]
        order = sorted(r.agents, key=lambda a: (sum(sets[a]), a))
        for y, a in enumerate(order):
            lo, hi = sets[a]
            ax.plot([lo, hi], [y, y], "-o", lw=6, ms=9, solid_capstyle="round",
                    color="tab:blue" if lo == hi else "tab:gray")  # blue: its rank is settled
        ax.set_yticks(range(len(order)), order)
        ax.invert_yaxis()
        ax.set_xlim(0.5, len(r.agents) + 0.5)
        ax.set_xticks(range(1, len(r.agents) + 1))
        ax.set_xlabel("rank (1 = best)")
        ax.set_title(metric, fontsize=9)
    fig.suptitle(f"rank-sets at α = {r.alpha:g} ({'anytime-valid' if r.sequential else 'fixed sample'}): "
                 f"{res.target.label}", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def _page(res: RankResult, png: Path) -> str:
    from proxybench import __version__

    r, d = res.ranking, res.to_dict()
    alone = {(p.a, p.b, p.metric): p for p in r.target_only}
    rows = [[f"{p.a} – {p.b}", p.metric, _WORDS[p.decision], f"{p.estimate:+.3g}", _iv(p.interval), p.n,
             f"{p.weight:.2f}", _WORDS[alone[(p.a, p.b, p.metric)].decision], _iv(alone[(p.a, p.b, p.metric)].interval)]
            for p in r.pairs]
    sets = [[a, *(f"{r.rank_sets[m][a][0]}–{r.rank_sets[m][a][1]}" for m in r.metrics)] for a in r.agents]
    eps = d["episodes"]
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in res.notes)
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>proxybench rank</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto}}td,th{{padding:2px 8px;text-align:left}}
table{{border-collapse:collapse}}tr:nth-child(even){{background:#f4f4f4}}.box{{background:#eef;padding:8px}}</style>
</head><body><h1>Ranking {len(r.agents)} agents on the target</h1>
<p class="box"><b>Target:</b> {html.escape(res.target.statement)}<br><b>Guarantee:</b> {html.escape(r.error_control)}
(α = {r.alpha:g}; {"anytime-valid: it holds whenever the run stopped" if r.sequential else "fixed sample"}).
<br><b>Proxy:</b> {html.escape(_theta(res))}, as the predictor (PPI++).</p>
<p>{r.decided()} of {len(r.pairs)} pair decisions made with the proxy, {r.decided(False)} with the target alone;
{eps["target"]} target episodes, {eps["proxy_paired"]} paired proxy episodes and {eps["proxy_only"]} proxy-only
episodes; tolerances ε: {html.escape(", ".join(f"{m} {e:g}" for m, e in zip(r.metrics, res.tolerances,
                                                                             strict=True)))}.
{html.escape(_stopped(res))}</p>
<h2>Rank-sets</h2>{html_img(png, "rank-sets")}{html_table(["agent", *r.metrics], sets)}
{_bt_html(res)}
<h2>Pairs</h2>{html_table(["pair (a – b)", "metric", "decision", "a − b", "interval", "target episodes",
                           "proxy weight λ", "target alone", "interval (target alone)"], rows)}
<ul>{notes}</ul>
<p style="color:#666">proxybench {__version__}, commit {html.escape(source_commit())};
{time.strftime("%Y-%m-%d %H:%M")}; {res.wall_s:.0f} s.</p></body></html>"""


def _bt_html(res: RankResult) -> str:
    """One table per metric: Bradley–Terry scores (log-odds of beating the first agent in an episode) with the
    proxy as predictor and from the target alone."""
    parts = []
    for metric, (with_, lam, alone) in res.bradley_terry.items():
        rows = [[w.agent, f"{w.score:+.2f} [{w.lo:+.2f}, {w.hi:+.2f}]", f"{a.score:+.2f} [{a.lo:+.2f}, {a.hi:+.2f}]"]
                for w, a in zip(with_, alone, strict=True)]
        ref = html.escape(str(with_[0].agent))
        parts.append(f"<h3>{html.escape(metric)}: Bradley–Terry score, log-odds of beating {ref} in an episode "
                     f"(95 %, per agent; proxy weight λ = {lam:.2f})</h3>"
                     + html_table(["agent", "with the proxy (PPI++)", "target alone"], rows))
    return "<h2>Scores</h2>" + "".join(parts) if parts else ""


def _iv(iv: tuple[float, float]) -> str:
    return "[" + ", ".join("−∞" if v == -np.inf else "∞" if v == np.inf else f"{v:+.3g}" for v in iv) + "]"


def _theta(res: RankResult) -> str:
    """θ and where it came from (``--param``, an optimize run), or the nominal calibration."""
    theta = ", ".join(f"{k}={v}" for k, v in res.theta.items())
    return f"{theta} ({res.theta_source})" if theta else "the nominal calibration"


def _stopped(res: RankResult) -> str:
    if res.stopped == "fixed":
        return ""
    return (f"Sequential: {len(res.steps)} target episodes after the pilot; "
            + ("every pair decided." if res.stopped == "settled" else "the budget was spent with pairs undecided."))


def show_rank(res: RankResult, console: Any) -> None:
    """The terminal view: what the target is, the guarantee, the rank-sets and the pairs still undecided."""
    from rich.markup import escape
    from rich.table import Table

    r = res.ranking
    console.print(f"[bold]target:[/bold] {escape(res.target.statement)}", highlight=False)
    console.print(f"proxy: {escape(_theta(res))}; α = {r.alpha:g}, "
                  f"{escape(r.error_control)}", highlight=False)
    table = Table(title=f"rank-sets ({'anytime-valid' if r.sequential else 'fixed sample'})")
    table.add_column("agent")
    for m in r.metrics:
        table.add_column(m, justify="right")
    for a in sorted(r.agents, key=lambda a: sum(r.rank_sets[r.metrics[0]][a])):
        table.add_row(escape(a), *(f"{r.rank_sets[m][a][0]}–{r.rank_sets[m][a][1]}" for m in r.metrics))
    console.print(table)
    eps = res.to_dict()["episodes"]
    console.print(f"decided: {r.decided()} of {len(r.pairs)} with the proxy, {r.decided(False)} with the target "
                  f"alone; {eps['target']} target, {eps['proxy_paired']} paired and {eps['proxy_only']} proxy-only "
                  f"episodes. {_stopped(res)}", highlight=False)
    for n in res.notes:
        console.print(f"note: {escape(n)}", highlight=False)


def canned_rank() -> RankResult:
    """Five agents' made-up target scores (12 episodes) and a proxy that tracks them, ranked (no episode runs)."""
    from proxybench.experiments.examples import canned_experiment, canned_target
    from proxybench.experiments.rank.run import PROXY_ONLY_FROM, bradley_terry_of, measure_rank, scores_of_target

    exp = canned_experiment(12)
    tgt = canned_target(exp)
    target = scores_of_target(tgt)
    rng = np.random.default_rng(3)
    proxy = {a: {e: v + rng.normal(0.0, 0.3, v.shape) for e, v in eps.items()} for a, eps in target.items()}
    for a, means in zip(target, (np.mean(list(v.values()), 0) for v in target.values()), strict=True):
        proxy[a] |= {PROXY_ONLY_FROM + i: means + rng.normal(0.0, 0.8, means.shape) for i in range(60)}
    tol = (0.2, 0.66)
    ranking = measure_rank(exp, target, proxy, tol, 0.05)
    return RankResult(ranking, exp, tgt.info, {}, "the nominal calibration", tol, {a: 12 for a in target},
                      12 * len(target), 60 * len(target), target_table=target, proxy_table=proxy,
                      bradley_terry=bradley_terry_of(exp, target, proxy, tol))
