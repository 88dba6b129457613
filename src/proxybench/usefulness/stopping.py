"""A sequential stopping rule for target episodes: run more where pairs are open, stop when every pair is settled.

After a pilot, each round runs ``batch`` episodes of the agents whose next episode most raises the expected
number of settled pairs (:func:`~proxybench.usefulness.plan.next_agents`), and the loop stops when every pair
of agents is *settled* — ordered, or tied within the task's tolerance ε
(:mod:`~proxybench.usefulness.indifference`) — or the budget is spent. The same loop serves a live target
(:mod:`proxybench.experiments.plan.sequential` runs the episodes through the runner) and the simulation that checks
its error rate (:mod:`proxybench.usefulness.stopping_check`): only ``fetch`` differs.

Looking at the data again and again and stopping when a test passes inflates its error rate. So the loop
decides only at a few *looks* — after the pilot, then whenever the episodes run have grown by half
(:func:`look_schedule`) — and by default the level is split over them (Bonferroni, ``correct=True``); episodes
are still allocated batch by batch in between. The simulated error rate of both versions is in
docs/usefulness.md.

>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> truth = {"a": 0.0, "b": 2.0, "c": 2.1}
>>> fetch = lambda picks: [rng.normal(truth[a], 1.0, 1) for a in picks]
>>> pilot = {a: rng.normal(mu, 1.0, (3, 1)) for a, mu in truth.items()}
>>> res = run_until_settled(pilot, fetch, (True,), tolerances=(0.5,), budget=600, batch=3)
>>> res.stopped, res.decisions[("a", "b")], res.decisions[("b", "c")]   # b and c, 0.1 apart with ε = 0.5: a tie
('settled', 'b', 'tie')
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from proxybench.usefulness.indifference import TIE, Rule, pair_stats, ranges_of, settle_state
from proxybench.usefulness.intervals import _alpha_options

__all__ = ["Fetch", "StopResult", "decide", "look_schedule", "run_until_settled"]

#: run one more episode of each named agent (in this order); one (m,) row of metric values per name
Fetch = Callable[[list[str]], Sequence[np.ndarray]]


def look_schedule(pilot: int, budget: int, growth: float = 1.5) -> list[int]:
    """Total episodes (all agents) at which the loop looks at the data: the pilot's, then every time the total
    has grown by ``growth``, and at the budget's end. Few looks keep the per-look level high (it is split over
    them); allocation goes on between looks."""
    if growth <= 1.0:
        raise ValueError(f"growth must be > 1, got {growth}")
    end, out = pilot + budget, [pilot]
    while out[-1] < end:
        out.append(min(end, max(out[-1] + 1, math.ceil(out[-1] * growth))))
    return out


def decide(results: Mapping[str, np.ndarray], higher: Sequence[bool], rule: Rule) -> dict[tuple[str, str], str]:
    """Every pair (a, b) of agents: the better agent's name, "tie" (within ε on every metric), "incomparable"
    (metrics disagree, for sure) or "open" — as the dominance matrix α reads the settled signs."""
    st = pair_stats(results, higher)
    state = settle_state(st.diff, st.se, st.df, rule)
    lo, hi = ranges_of(state, st.signs)
    options = _alpha_options(lo, hi)  # can α be 0, 0.5, 1
    out = {}
    for q in range(len(st.i)):
        a, b = st.agents[st.i[q]], st.agents[st.j[q]]
        if options[q].sum() > 1:
            out[(a, b)] = "open"
        elif options[q, 2]:
            out[(a, b)] = a
        elif options[q, 0]:
            out[(a, b)] = b
        else:
            out[(a, b)] = "tie" if np.all(lo[q] == TIE) and np.all(hi[q] == TIE) else "incomparable"
    return out


@dataclass(frozen=True)
class Batch:
    """One batch of the sequential rule: the agents run, the episodes spent so far (pilot included), whether it
    ended in a look at the data, and the pairs still open as of the last look."""

    agents: list[str]
    episodes: int
    look: bool
    open_pairs: int


@dataclass
class StopResult:
    """The episodes after the loop, what each batch did, why it stopped and what it decided per pair."""

    results: dict[str, np.ndarray]
    rule: Rule
    history: list[Batch] = field(default_factory=list)
    stopped: str = "budget"  # "settled" (no open pair left) | "budget"
    spent: int = 0  # episodes run after the pilot
    open_after_pilot: int = 0
    decisions: dict[tuple[str, str], str] = field(default_factory=dict)

    @property
    def episodes(self) -> dict[str, int]:
        return {a: len(v) for a, v in self.results.items()}

    def open_pairs(self) -> list[tuple[str, str]]:
        return [p for p, d in self.decisions.items() if d == "open"]


def run_until_settled(results: Mapping[str, np.ndarray], fetch: Fetch, higher: Sequence[bool], *,
                      tolerances: Sequence[float], budget: int, batch: int = 2, level: float = 0.95,
                      correct: bool = True, growth: float = 1.5,
                      progress: Callable[[int, int], None] | None = None) -> StopResult:
    """Spend up to ``budget`` more episodes, ``batch`` at a time, until every pair is settled.

    ``results``: the pilot (agent → (episodes, m)); ``fetch`` runs the chosen agents' next episodes. The loop
    decides only at the looks of :func:`look_schedule` (``growth``); ``correct``: split the level over them, so
    that the error rate over the whole loop stays near 1 − ``level`` per pair and metric (else every look tests
    at the full level).
    """
    from proxybench.usefulness.plan import next_agents

    if budget < 0 or batch < 1:
        raise ValueError(f"budget must be >= 0 and batch >= 1, got {budget}, {batch}")
    res = {a: np.asarray(v, float).reshape(len(v), -1) for a, v in results.items()}
    pilot = sum(len(v) for v in res.values())
    looks = look_schedule(pilot, budget, growth)
    rule = Rule(tuple(tolerances), level, len(looks) if correct else 1)
    out = StopResult(res, rule)
    out.decisions = decide(res, higher, rule)
    out.open_after_pilot = len(out.open_pairs())
    nxt = 1
    while out.spent < budget and out.open_pairs():
        picks = next_agents(res, higher, k=min(batch, budget - out.spent), level=level, tolerances=rule.tolerances,
                            looks=rule.looks)
        if not picks:  # settled between looks: look now (one of the scheduled looks, counted above)
            out.decisions = decide(res, higher, rule)
            break
        rows = fetch(picks)
        for a, row in zip(picks, rows, strict=True):
            res[a] = np.vstack([res[a], np.asarray(row, float).reshape(1, -1)])
        out.spent += len(picks)
        look = pilot + out.spent >= looks[min(nxt, len(looks) - 1)] or out.spent >= budget
        if look:
            nxt += 1
            out.decisions = decide(res, higher, rule)
        out.history.append(Batch(list(picks), pilot + out.spent, look, len(out.open_pairs())))
        if progress:
            progress(out.spent, budget)
    out.stopped = "budget" if out.open_pairs() else "settled"
    return out
