"""``proxybench plan``, registered: how many target episodes per agent, and which agents need them."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from proxybench.experiments.config import ExperimentStudy
from proxybench.experiments.study import register

if TYPE_CHECKING:
    from proxybench.experiments.plan.run import PlanResult

__all__ = ["PlanStudy"]


@register
class PlanStudy(ExperimentStudy):
    """Plan target episodes: n per agent to settle every pair of agents, for a PRPV interval of a given width, or
    for a given chance of the right θ.

    Pairs within the task's tolerance ε count as ties, so every pair settles with finitely many episodes; the
    pilot (--episodes per agent) is not taken as the truth: every count is a range over its posterior, and
    experiments with n episodes per agent are simulated in worlds drawn from it (docs/usefulness.md); --sweep
    gives candidate θ to pick among. Episodes are cached in OUT/runs: `predictivity --out OUT` re-uses them.
    """

    name = "plan"
    quick_help = "6 agents × 3 pilot episodes × 8 s; --sequential: budget 4"
    out_help = "folder for plan.json, tables, plan.png and the episode cache"
    exclude = ("search", "plv", "n_boot", "pod_seconds", "truth")
    runs = "proxybench.experiments.plan.run:run_plan"
    reports = "proxybench.experiments.plan.run:write_plan"

    def example(self) -> PlanResult:
        """A canned result: the plan for five agents from a made-up pilot of three episodes (no episode runs)."""
        from proxybench.experiments.examples import canned_experiment, canned_target
        from proxybench.experiments.plan.run import PlanResult, tolerances
        from proxybench.tasks.metrics import METRICS
        from proxybench.usefulness.plan import plan

        exp = canned_experiment()
        tgt = canned_target(exp)
        higher = tuple(METRICS[m].higher_is_better for m in exp.metrics)
        made = plan(tgt.results, higher, exp.metrics, grid=[3, 10, 30], reps=20, seed=0,
                    tolerances=tolerances(exp.metrics, exp.seconds, {}))
        return PlanResult(made, tgt, exp)

    def show(self, result: PlanResult, console: Any, *, wall: float = 0.0) -> None:
        _print_plan(result.plan, result.target, result.sequential, result.wall_s, console)


def _n(x: float) -> str:
    return f"{x:,.0f}" if math.isfinite(x) else "> 100,000"


def _print_plan(p: Any, tgt: Any, seq: Any, wall: float, console: Any) -> None:
    from rich.table import Table

    console.print(f"[bold]target:[/bold] {tgt.info.statement}", highlight=False)
    pilot = ", ".join(f"{a} {n}" for a, n in p.pilot_episodes.items())
    what = "pilot episodes" if seq is None else "target episodes (pilot + sequential)"
    console.print(f"{what} per agent: {pilot}; {len(p.agents)} agents, PRPV in [0, "
                  f"{len(p.agents) * (len(p.agents) - 1)}]; {wall:.0f} s", highlight=False)
    eps = ", ".join(f"{m} {e:g}" for m, e in zip(p.metrics, p.tolerances, strict=True))
    console.print(f"tolerances ε (pairs within them are ties): {eps}", highlight=False)
    if seq is not None:
        rounds = ", ".join(f"{'+'.join(h.agents)}" + (f" → {h.open_pairs}" if h.look else "") for h in seq.history)
        console.print(f"sequential: {sum(len(h.agents) for h in seq.history)} more episodes "
                      f"({'every pair settled' if seq.stopped == 'settled' else 'budget spent'}; the level split "
                      f"over {seq.looks} looks); open pairs: {seq.open_after_pilot} after the pilot"
                      + (f", then {rounds}" if rounds else ""), highlight=False)
    how = "worlds drawn from the pilot's posterior" if p.uncertain else "the pilot taken as the truth"
    table = Table(title=f"what n target episodes per agent give (simulated experiments in {how})")
    cols = ["n per agent", "order range width: mean", f"{p.confidence:.0%} of runs ≤", "open pairs",
            "P(all settled)"]
    if p.width is not None:
        cols.append(f"P(width ≤ {p.width:g})")
    if p.candidates:
        cols.append("P(right θ)")
    for c in cols:
        table.add_column(c, justify="right")
    for r in p.rows:
        cells = [str(r.n), f"{r.width_mean:.1f}", f"{r.width_q:.1f}", f"{r.open_pairs:.1f}", f"{r.p_settled:.2f}"]
        if p.width is not None:
            cells.append(f"{r.p_width:.2f}")
        if p.candidates:
            cells.append(f"{r.p_correct:.2f}")
        table.add_row(*cells)
    console.print(table)
    if p.width is not None:
        console.print(_answer(p.n_for_width, f"an order range at most {p.width:g} wide in {p.confidence:.0%} of runs",
                              p.rows[-1].n), highlight=False)
    if p.candidates:
        best = ", ".join(p.best)
        console.print(f"candidates (PRPV on the pilot): {', '.join(f'{k} {v:g}' for k, v in p.pilot_prpv.items())}; "
                      f"the pilot's best: {best}", highlight=False)
        if p.p_correct_goal is not None:
            console.print(_answer(p.n_for_p_correct, f"picking {best} with probability {p.p_correct_goal:.0%}",
                                  p.rows[-1].n), highlight=False)
    lo, mid, hi = p.settle_all[1], p.settle_all[0], p.settle_all[2]
    console.print(f"→ every pair settled (ordered, or tied within ε) with probability {p.power:.0%} each: {_n(mid)} "
                  f"episodes per agent [{_n(lo)}, {_n(hi)}] ({p.range_level:.0%} of the pilot's posterior)",
                  highlight=False)
    pairs = Table(title=f"pairs on the target still open: episodes per agent to settle each, median "
                        f"[{p.range_level:.0%} range] over the pilot's posterior")
    for c in ("pair", "metric", "difference", "se (pilot)", "ε", "episodes per agent", "pilot as truth"):
        pairs.add_column(c, justify="left" if c in ("pair", "metric") else "right")
    open_ = [q for q in p.pairs if not q.settled]
    for q in open_[:12]:
        pairs.add_row(f"{q.a} – {q.b}", q.metric, f"{q.difference:+.3g}", f"{q.se:.3g}", f"{q.tolerance:g}",
                      f"{_n(q.episodes)} [{_n(q.episodes_low)}, {_n(q.episodes_high)}]", _n(q.plug_in))
    if open_:
        console.print(pairs)
        if len(open_) > 12:
            console.print(f"… and {len(open_) - 12} more (pairs.csv)")
    else:
        console.print("every pair of agents is settled on the target with the pilot's episodes")
    if p.next_agents:
        console.print(f"run next (most pairs settled per episode): {', '.join(p.next_agents)}", highlight=False)


def _answer(n: int | None, what: str, largest: int) -> str:
    if n is None:
        return f"→ {what}: not reached with up to {largest} episodes per agent (near ties: see the pairs)"
    return f"→ {what}: {n} episodes per agent"
