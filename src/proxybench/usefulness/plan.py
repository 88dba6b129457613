"""Sample-size planning for PRPV: how many target episodes per agent, and which agents need them most.

Target episodes are what costs (robot time, lab time); proxies replay them for free. From a **pilot** —
a few episodes per agent on the target, of any kind (:mod:`proxybench.targets`), and optionally their
replays in candidate proxies θ — the planner answers:

- how many episodes per agent until every pair of agents is *settled* (ordered, or tied within the task's
  tolerance ε: :mod:`proxybench.usefulness.indifference`), per pair and for all of them, as a **range**;
- how many for PRPV's order range (:mod:`proxybench.usefulness.intervals`) to be at most W wide, and for a
  given probability of picking the right θ among the candidates;
- which agents to run next (:func:`next_agents`; :mod:`proxybench.usefulness.stopping` runs it in a loop
  until every pair is settled, and checks that loop's error rate by simulation).

**The pilot is not the truth.** A pilot of 2–3 episodes says little about the agents' true means and spreads,
so every answer is computed over *worlds* drawn from the posterior given the pilot (normal episodes, flat
prior; :func:`~proxybench.usefulness.indifference.posterior_draws`): a world shifts and scales each agent's
pilot episodes to its drawn mean and spread (so pairing, exact ties, capped metrics and skew carry over), a
proxy's world keeps its paired difference to the target's up to that difference's own uncertainty, and an
experiment with n episodes per agent is simulated by drawing n of those episodes with replacement — the same
draws on the target and in every candidate proxy, since proxies replay the target's episodes. The "right θ"
is the world's argmin of PRPV. ``uncertain=False`` takes the pilot as the truth (the former model).

>>> import numpy as np
>>> pilot = {"a": np.array([[3.0], [3.2], [2.9]]), "b": np.array([[1.0], [1.3], [0.8]]),
...          "c": np.array([[1.1], [0.7], [1.2]])}
>>> p = plan(pilot, (True,), ("distance",), width=0.0, reps=200)
>>> [(q.a, q.b) for q in p.pairs if not q.settled]      # b and c are a near tie: they need the episodes
[('b', 'c')]
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from proxybench.usefulness.indifference import (
    OPEN,
    TIE,
    Rule,
    _var,
    _welch,
    needs,
    pair_stats,
    ranges_of,
    settle_probability,
    settle_state,
)
from proxybench.usefulness.intervals import _alpha_options
from proxybench.usefulness.metrics import _signed, agent_means, pair_signs, prpv_from_means

__all__ = ["PairNeed", "Plan", "PlanRow", "next_agents", "pair_needs", "plan", "settle_probability"]

Results = Mapping[str, np.ndarray]
DEFAULT_GRID = (5, 10, 20, 40, 80, 160, 320)
_STATE = {1: "ordered", -1: "ordered", TIE: "tie", OPEN: "open"}


def _rule(tolerances: Sequence[float] | None, m: int, level: float, looks: int = 1) -> Rule:
    return Rule(tuple(tolerances) if tolerances is not None else (0.0,) * m, level, looks)


@dataclass(frozen=True)
class PairNeed:
    """A pair of agents on the target: its difference on the metric that decides least clearly, its state, and
    the episodes per agent that would settle it with the planned power — a range over the pilot's posterior
    (``episodes`` its median; inf only beyond the cap, i.e. a tie within the noise and no tolerance)."""

    a: str
    b: str
    metric: str
    difference: float  # mean(a) − mean(b), in the metric's unit, signed so that > 0 means a is better
    se: float  # its standard error with the pilot's episodes
    settled: bool  # its order (or tie within the tolerance) is decided with the pilot already
    episodes: float  # per agent, median over the posterior
    episodes_low: float = math.nan
    episodes_high: float = math.nan
    state: str = "open"  # ordered | tie | open (on this metric)
    tolerance: float = 0.0  # ε of this metric
    plug_in: float = math.nan  # what the pilot's point values alone would say (for comparison only)


def _open(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(…,) whether a pair's α can still take more than one value, from (…, m) plausible sign ranges."""
    return _alpha_options(lo, hi).sum(-1) > 1


def _sign_ranges(means: np.ndarray, sd: np.ndarray, n: np.ndarray, higher, rule: Rule):
    """(…, P, m) plausible sign ranges of every pair (i < j) under ``rule`` when the agents' episodes have
    means ``means``, spreads ``sd`` and counts ``n`` (…, K, m); with the differences and standard errors."""
    k = means.shape[-2]
    i, j = np.triu_indices(k, 1)
    signs = pair_signs(means, higher)[..., i, j, :]
    var = np.asarray(sd, float) ** 2
    se, df = _welch(var[..., i, :], n[..., i, :], var[..., j, :], n[..., j, :])
    signed = _signed(means, higher)
    diff = signed[..., i, :] - signed[..., j, :]
    lo, hi = ranges_of(settle_state(diff, se, df, rule), signs)
    return lo, hi, diff, se


def pair_needs(results: Results, higher: Sequence[bool], names: Sequence[str], *, level: float = 0.95,
               power: float = 0.8, tolerances: Sequence[float] | None = None, range_level: float = 0.8,
               draws: int = 1000, seed: int = 0) -> list[PairNeed]:
    """Every pair of agents on the target: settled or not, and the episodes per agent to settle it (a range).

    Settled: on every metric ordered or tied within ε (``tolerances``, default 0: strict) by the rule of
    :mod:`~proxybench.usefulness.indifference`, or incomparable for sure.
    """
    rule = _rule(tolerances, len(names), level)
    st = pair_stats(results, higher)
    state = settle_state(st.diff, st.se, st.df, rule)
    lo, hi = ranges_of(state, st.signs)
    is_open = _open(lo, hi)
    nd = needs(results, higher, rule, power=power, range_level=range_level, draws=draws, seed=seed)
    out = []
    for q in range(len(st.i)):
        i, j = st.i[q], st.j[q]
        cand = np.flatnonzero(state[q] == OPEN) if is_open[q] else np.arange(len(names))
        # the open metric with the smallest |difference| / se decides least clearly
        clarity = np.abs(st.diff[q, cand]) / np.where(st.se[q, cand] > 0, st.se[q, cand], np.inf)
        m = int(cand[int(np.nanargmin(np.nan_to_num(clarity, nan=np.inf)))]) if cand.size else 0
        out.append(PairNeed(st.agents[i], st.agents[j], names[m], float(st.diff[q, m]), float(st.se[q, m]),
                            not bool(is_open[q]), _ceil(nd.median[q]), _ceil(nd.low[q]), _ceil(nd.high[q]),
                            _STATE.get(int(state[q, m]), "ordered"), rule.tolerances[m], _ceil(nd.plug_in[q])))
    return sorted(out, key=lambda p: (p.settled, p.episodes))  # open pairs first, the cheapest to settle first


def _ceil(x: float) -> float:
    return math.ceil(x) if math.isfinite(x) else math.inf


def next_agents(results: Results, higher: Sequence[bool], *, k: int = 1, level: float = 0.95,
                tolerances: Sequence[float] | None = None, looks: int = 1) -> list[str]:
    """The next ``k`` target episodes to run: greedily, the agent whose one more episode most raises the
    expected number of settled pairs (:func:`settle_probability` on the open pairs, with the current means,
    spreads and tolerances); agents with fewer than 2 episodes first (no spread yet). Empty when every pair
    is settled.
    """
    agents = list(results)
    m = np.asarray(results[agents[0]]).shape[1]
    rule = _rule(tolerances, m, level, looks)
    eps = np.asarray(rule.tolerances, float)
    means = agent_means(results, agents)
    sd = np.sqrt(np.nan_to_num(np.stack([_var(np.asarray(results[a], float)) for a in agents])))
    n = np.stack([np.isfinite(np.asarray(results[a], float)).sum(0) for a in agents]).astype(float)
    rows = np.array([len(results[a]) for a in agents])
    iu = np.triu_indices(len(agents), 1)
    picks: list[str] = []
    for _ in range(k):
        few = [i for i in range(len(agents)) if rows[i] < 2]  # no spread yet (an agent never scored is worst)
        if few:
            i = min(few, key=lambda i: (rows[i], i))
        else:
            lo, hi, diff, _ = _sign_ranges(means, sd, n, higher, rule)
            is_open = _open(lo, hi)
            if not is_open.any():
                break
            gains = _gains(diff, sd, n, iu, is_open[:, None] & (lo != hi), rule, eps)
            i = int(np.argmax(gains - 1e-12 * n.min(1)))  # equal gains: the agent with fewer episodes
        picks.append(agents[i])
        n[i] += 1
        rows[i] += 1
    return picks


def _gains(diff, sd, n, iu, open_, rule: Rule, eps) -> np.ndarray:
    """(K,) expected pairs (metrics) settled by one more episode of each agent, over the open pair-metrics."""
    var = sd ** 2
    a, b = iu

    def p(na, nb) -> np.ndarray:
        se, df = _welch(var[a], na, var[b], nb)
        out = settle_probability(diff, se, rule.quantile(np.nan_to_num(df, nan=1.0)), eps)
        return np.where(open_, np.nan_to_num(out), 0.0)

    before = p(n[a], n[b])
    gains = np.zeros(len(sd))
    np.add.at(gains, a, (p(n[a] + 1, n[b]) - before).sum(-1))
    np.add.at(gains, b, (p(n[a], n[b] + 1) - before).sum(-1))
    return gains


@dataclass(frozen=True)
class PlanRow:
    """What an experiment with ``n`` target episodes per agent can expect (over simulated experiments)."""

    n: int
    width_mean: float  # PRPV order range width, mean
    width_q: float  # its ``confidence`` quantile
    p_width: float  # P(width ≤ the goal); NaN without a goal
    p_correct: float  # P(argmin PRPV = the world's best θ); NaN without candidates
    open_pairs: float  # mean number of target pairs left open
    p_settled: float = math.nan  # P(every target pair settled)


@dataclass
class Plan:
    """The planner's answer (see the module docstring)."""

    agents: list[str]
    metrics: tuple[str, ...]
    pilot_episodes: dict[str, int]
    rows: list[PlanRow]
    pairs: list[PairNeed]
    next_agents: list[str]
    confidence: float
    width: float | None = None
    n_for_width: int | None = None
    p_correct_goal: float | None = None
    n_for_p_correct: int | None = None
    candidates: list[str] = field(default_factory=list)
    pilot_prpv: dict[str, float] = field(default_factory=dict)
    best: list[str] = field(default_factory=list)
    tolerances: tuple[float, ...] = ()
    settle_all: tuple[float, float, float] = (math.nan, math.nan, math.nan)  # median, low, high episodes per agent
    range_level: float = 0.8
    uncertain: bool = True
    power: float = 0.8

    def to_dict(self) -> dict:
        def num(x: float) -> float | None:
            return x if math.isfinite(x) else None

        d = asdict(self)
        d["pairs"] = [{**asdict(p), **{k: num(getattr(p, k)) for k in ("episodes", "episodes_low", "episodes_high",
                                                                         "plug_in")}} for p in self.pairs]
        d["settle_all"] = [num(x) for x in self.settle_all]
        return d


@dataclass(frozen=True)
class _Worlds:
    """``reps`` worlds drawn from the posterior given the pilot: per agent and metric the target's mean and
    spread, the factor k = σ*/s that scales the pilot's episodes to it, and each candidate proxy's mean."""

    xbar_t: np.ndarray  # (K, m) pilot means
    mu_t: np.ndarray  # (R, K, m)
    k: np.ndarray  # (R, K, m)
    sd_t: np.ndarray  # (K, m) pilot spreads
    xbar_p: dict[str, np.ndarray]
    mu_p: dict[str, np.ndarray]
    sd_p: dict[str, np.ndarray]


def _worlds(target: Results, proxies: Mapping[str, Results], reps: int, uncertain: bool,
            rng: np.random.Generator) -> _Worlds:
    from proxybench.usefulness.indifference import posterior_draws

    agents = list(target)
    xbar = agent_means(target, agents)
    s = np.sqrt(np.stack([_var(np.asarray(target[a], float)) for a in agents]))
    if uncertain:
        mu, sig = posterior_draws(target, agents, reps, rng)
        k = np.where(s > 0, np.nan_to_num(sig) / np.where(s > 0, s, 1.0), 1.0)
    else:
        mu, k = np.broadcast_to(xbar, (reps, *xbar.shape)), np.ones((reps, *xbar.shape))
    xbar_p, mu_p, sd_p = {}, {}, {}
    for label, pres in proxies.items():
        xbar_p[label] = agent_means(pres, agents)
        sd_p[label] = np.sqrt(np.nan_to_num(np.stack([_var(np.asarray(pres[a], float)) for a in agents])))
        delta = [np.asarray(pres[a], float) - np.asarray(target[a], float) for a in agents]
        dbar = np.stack([np.nanmean(np.where(np.isfinite(d), d, np.nan), 0) if np.isfinite(d).any() else
                         np.full(d.shape[1], np.nan) for d in delta])
        dse = np.sqrt(np.nan_to_num(np.stack([_var(d) / np.maximum(np.isfinite(d).sum(0), 1) for d in delta])))
        noise = rng.standard_normal(mu.shape) * dse * k if uncertain else 0.0
        # a proxy's world: the target's world plus the paired difference (known far better than either mean)
        mu_p[label] = np.where(np.isfinite(dbar), mu + dbar + noise, xbar_p[label])
    return _Worlds(xbar, np.asarray(mu), np.asarray(k), np.nan_to_num(s), xbar_p, mu_p, sd_p)


def _simulate(target: Results, proxies: Mapping[str, Results], higher, n: int, rule: Rule,
              rng: np.random.Generator, w: _Worlds, width_of: str | None):
    """Order-range widths (reps,) of candidate ``width_of`` (None: a proxy ordering as the target, as noisy),
    PRPV of each candidate (reps, C) and open target pairs (reps,), at n episodes per agent."""
    from proxybench.usefulness.intervals import order_range
    from proxybench.usefulness.metrics import resampled_means

    agents = list(target)
    reps = w.mu_t.shape[0]
    idx = {a: rng.integers(0, len(target[a]), (reps, n)) for a in agents}
    raw = np.stack([resampled_means(target[a], idx[a]) for a in agents], 1)
    tm = w.mu_t + (raw - w.xbar_t) * w.k
    nn = np.full(tm.shape, float(n))
    lo_t, hi_t, _, _ = _sign_ranges(tm, w.sd_t * w.k, nn, higher, rule)
    open_pairs = _open(lo_t, hi_t).sum(-1)
    prpv = np.full((reps, len(proxies)), np.nan)
    widths = np.zeros(reps)
    side = {}
    for c, (label, pres) in enumerate(proxies.items()):
        raw_p = np.stack([resampled_means(pres[a], idx[a]) for a in agents], 1)
        pm = w.mu_p[label] + (raw_p - w.xbar_p[label]) * w.k
        prpv[:, c] = prpv_from_means(pm, tm, higher)
        side[label] = _sign_ranges(pm, w.sd_p[label] * w.k, nn, higher, rule)[:2]
    lo_p, hi_p = side[width_of] if width_of is not None else (lo_t, hi_t)
    for r in range(reps):
        low, high = order_range(lo_p[r], hi_p[r], lo_t[r], hi_t[r])
        widths[r] = high - low
    return widths, prpv, open_pairs


def plan(target: Results, higher: Sequence[bool], names: Sequence[str], *, proxies: Mapping[str, Results] | None = None,
         width: float | None = None, p_correct: float | None = None, confidence: float = 0.8,
         grid: Sequence[int] | None = None, reps: int = 400, level: float = 0.95, power: float = 0.8,
         batch: int = 4, seed: int = 0, tolerances: Sequence[float] | None = None, range_level: float = 0.8,
         uncertain: bool = True) -> Plan:
    """Plan the episodes per agent from a pilot on the target (and its replays in candidate proxies).

    ``tolerances``: ε per metric (pairs within it are ties; default 0, strict order); ``width``: the order-range
    width to reach (PRPV units) with probability ``confidence`` — of the pilot's best candidate, or without
    candidates of a proxy that orders the agents as the target and is as noisy; ``p_correct``: the probability
    of picking the world's best candidate. The answer is the smallest n on ``grid`` (default: the pilot's
    count, 5, 10, … 320) that reaches it, refined between grid points. ``uncertain=False``: the pilot is the
    truth (no posterior worlds).
    """
    agents = list(target)
    few = [a for a in agents if np.isfinite(np.asarray(target[a], float)).sum(0).min() < 2]
    if few:
        raise ValueError(f"a plan needs at least 2 pilot episodes with values per agent (to see their spread); "
                         f"{', '.join(few)} {'has' if len(few) == 1 else 'have'} fewer")
    proxies = dict(proxies or {})
    for label, pres in proxies.items():
        for a in agents:
            if len(pres[a]) != len(target[a]):
                raise ValueError(f"candidate {label!r}, agent {a!r}: {len(pres[a])} episodes, the pilot has "
                                 f"{len(target[a])}; candidates must replay the pilot's episodes")
    rule = _rule(tolerances, len(names), level)
    pilot_n = {a: int(len(target[a])) for a in agents}
    tmeans = agent_means(target, agents)
    pilot_prpv = {lb: float(prpv_from_means(agent_means(p, agents), tmeans, higher)) for lb, p in proxies.items()}
    lowest = min(pilot_prpv.values()) if pilot_prpv else None
    best = [lb for lb, v in pilot_prpv.items() if v == lowest]
    w = _worlds(target, proxies, reps, uncertain, np.random.default_rng([seed, 0x3D]))
    if proxies:  # the right θ of each world: its own argmin of PRPV
        true = np.stack([prpv_from_means(w.mu_p[lb], w.mu_t, higher) for lb in proxies], 1)
        right = np.isclose(true, true.min(1, keepdims=True))

    def evaluate(n: int) -> PlanRow:
        rng = np.random.default_rng([seed, n])
        wd, prpv, open_pairs = _simulate(target, proxies, higher, n, rule, rng, w, best[0] if best else None)
        p_ok = float("nan")
        if proxies:
            mins = prpv == prpv.min(1, keepdims=True)
            p_ok = float(((mins & right).sum(1) / mins.sum(1)).mean())  # ties: broken at random
        return PlanRow(n, float(wd.mean()), float(np.quantile(wd, confidence)),
                       float((wd <= width + 1e-9).mean()) if width is not None else float("nan"), p_ok,
                       float(open_pairs.mean()), float((open_pairs == 0).mean()))

    ns = sorted({min(pilot_n.values()), *(grid or DEFAULT_GRID)})
    rows = {n: evaluate(n) for n in ns}

    def smallest(ok) -> int | None:
        good = [n for n in ns if ok(rows[n])]
        if not good:
            return None
        hi = good[0]
        below = [n for n in ns if n < hi]
        lo = below[-1] if below else hi
        while hi - lo > 1:  # refine between grid points
            mid = (lo + hi) // 2
            rows.setdefault(mid, evaluate(mid))
            lo, hi = (lo, mid) if ok(rows[mid]) else (mid, hi)
        return hi

    n_w = smallest(lambda r: r.p_width >= confidence) if width is not None else None
    n_p = smallest(lambda r: r.p_correct >= p_correct) if p_correct is not None and proxies else None
    pairs = pair_needs(target, higher, names, level=level, power=power, tolerances=rule.tolerances,
                       range_level=range_level, seed=seed)
    nd = needs(target, higher, rule, power=power, range_level=range_level, seed=seed)
    return Plan(agents, tuple(names), pilot_n, [rows[n] for n in sorted(rows)], pairs,
                next_agents(target, higher, k=batch, level=level, tolerances=rule.tolerances), confidence, width,
                n_w, p_correct, n_p, list(proxies), pilot_prpv, best, rule.tolerances, nd.all_pairs, range_level,
                uncertain, power)
