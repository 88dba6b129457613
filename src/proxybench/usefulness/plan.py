"""Sample-size planning for PRPV: how many target episodes per agent, and which agents need them most.

Target episodes are what costs (robot time, lab time); proxies replay them for free. From a **pilot** —
a few episodes per agent on the target, of any kind (:mod:`proxybench.targets`), and optionally their
replays in candidate proxies θ — the planner answers:

- how many episodes per agent for PRPV's order range (:mod:`proxybench.usefulness.intervals`) to be at
  most W wide, with a given probability;
- how many for a given probability of picking the right θ among the candidates;
- which pairs of agents are near ties, and how many episodes each would need to be ordered (the pairs
  that deserve more episodes); :func:`next_agents` turns that into "run this agent next"
  (:mod:`proxybench.experiments.sequential` runs it in a loop on a live target).

**Model** (plug-in): the pilot is taken as the truth. An experiment with n episodes per agent is
simulated by drawing n of each agent's pilot episodes with replacement — the same draws on the target
and in every candidate proxy, since proxies replay the target's episodes — so pairing, exact ties, capped
metrics and skew carry over. In each simulated experiment a pair's sign on a metric is open when
|mean difference| ≤ z·se, se from the pilot's spreads and n (the normal approximation of the resampling
rule the order range uses); the order range and the argmin of PRPV follow. The "right θ" is the argmin
of PRPV on the pilot means. With a pilot of 2–3 episodes these are rough: plan, run more, plan again —
or let the sequential loop do it.

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
from scipy.stats import norm

from proxybench.usefulness.intervals import _alpha_options
from proxybench.usefulness.metrics import agent_means, pair_signs, prpv_from_means

__all__ = ["PairNeed", "Plan", "PlanRow", "next_agents", "pair_needs", "plan", "settle_probability"]

Results = Mapping[str, np.ndarray]
DEFAULT_GRID = (5, 10, 20, 40, 80, 160, 320)


def _sd(arr: np.ndarray) -> np.ndarray:
    """(m,) sample standard deviation of each metric over episodes (0 with fewer than 2 values)."""
    a = np.asarray(arr, float)
    out = np.zeros(a.shape[1])
    for k in range(a.shape[1]):
        v = a[:, k][np.isfinite(a[:, k])]
        out[k] = float(np.std(v, ddof=1)) if v.size >= 2 else 0.0
    return out


def _counts(arr: np.ndarray) -> np.ndarray:
    return np.isfinite(np.asarray(arr, float)).sum(0)


def settle_probability(delta: np.ndarray, se: np.ndarray, level: float = 0.95) -> np.ndarray:
    """P(|estimated difference| > z·se) when the true difference is ``delta`` and its standard error ``se``:
    the chance that a pair's order on a metric comes out settled. An exact tie (se = 0) is settled."""
    z = norm.ppf((1 + level) / 2)
    d, s = np.abs(np.asarray(delta, float)), np.asarray(se, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(s > 0, d / s, np.inf)
        p = norm.cdf(r - z) + norm.cdf(-r - z)
    return np.where(s > 0, p, 1.0)


@dataclass(frozen=True)
class PairNeed:
    """A pair of agents on the target: its observed difference on the metric that decides least clearly,
    and the episodes per agent that would order it with the planned power (inf: a tie within the noise)."""

    a: str
    b: str
    metric: str
    difference: float  # mean(a) − mean(b), in the metric's unit, signed so that > 0 means a is better
    se: float  # its standard error with the pilot's episodes
    settled: bool  # its order is decided with the pilot already
    episodes: float  # per agent, to settle it with probability ``power``


def _open(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(…,) whether a pair's α can still take more than one value, from (…, m) plausible sign ranges."""
    return _alpha_options(lo, hi).sum(-1) > 1


def _sign_ranges(means: np.ndarray, sd: np.ndarray, n: np.ndarray, higher, level: float):
    """(…, P, m) plausible sign ranges of every pair (i < j): open where |difference| ≤ z·se."""
    k = means.shape[-2]
    iu = np.triu_indices(k, 1)
    signs = pair_signs(means, higher)[..., iu[0], iu[1], :]
    s = np.asarray(sd, float)
    var = s * s / np.maximum(n, 1)
    se = np.sqrt(var[..., iu[0], :] + var[..., iu[1], :])
    signed = means * np.where(np.asarray(higher), 1.0, -1.0)
    diff = signed[..., iu[0], :] - signed[..., iu[1], :]
    z = norm.ppf((1 + level) / 2)
    with np.errstate(invalid="ignore"):
        open_ = (np.abs(diff) <= z * se) & (se > 0) & np.isfinite(diff)
    return np.where(open_, -1.0, signs), np.where(open_, 1.0, signs), diff, se


def pair_needs(results: Results, higher: Sequence[bool], names: Sequence[str], *, level: float = 0.95,
               power: float = 0.8) -> list[PairNeed]:
    """Every pair of agents on the target: settled or not, and the episodes per agent to settle it.

    n = ((z_level + z_power) · √(s_a² + s_b²) / |difference|)², the two-sample size formula, for the open
    metric that needs most (a pair whose metrics already disagree for sure is incomparable: settled).
    """
    agents = list(results)
    means = agent_means(results, agents)
    sd = np.stack([_sd(results[a]) for a in agents])
    n = np.stack([_counts(results[a]) for a in agents]).astype(float)
    lo, hi, diff, se = _sign_ranges(means, sd, n, higher, level)
    iu = np.triu_indices(len(agents), 1)
    zsum = norm.ppf((1 + level) / 2) + norm.ppf(power)
    out = []
    for q, (i, j) in enumerate(zip(*iu, strict=True)):
        is_open = bool(_open(lo[q], hi[q]))
        cand = np.flatnonzero(lo[q] != hi[q]) if is_open else np.arange(len(names))
        need = []
        for m in cand:
            spread2 = sd[i, m] ** 2 + sd[j, m] ** 2
            d = abs(diff[q, m]) if np.isfinite(diff[q, m]) else np.inf
            need.append(math.inf if d == 0 and spread2 > 0 else (zsum ** 2 * spread2 / d ** 2 if d > 0 else 0.0))
        m = int(cand[int(np.argmax(need))]) if is_open else int(cand[int(np.argmin(np.nan_to_num(se[q], nan=0.0)))])
        episodes = float(max(need)) if is_open else float(max(n[i, m], n[j, m]))
        out.append(PairNeed(agents[i], agents[j], names[m], float(diff[q, m]), float(se[q, m]), not is_open,
                            math.ceil(episodes) if math.isfinite(episodes) else math.inf))
    return sorted(out, key=lambda p: (p.settled, p.episodes))  # open pairs first, the cheapest to settle first


def next_agents(results: Results, higher: Sequence[bool], *, k: int = 1, level: float = 0.95) -> list[str]:
    """The next ``k`` target episodes to run: greedily, the agent whose one more episode most raises the
    expected number of settled pairs (:func:`settle_probability` on the open pairs, with the current means
    and spreads); agents with fewer than 2 episodes first (no spread yet). Empty when every pair is settled.
    """
    agents = list(results)
    means = agent_means(results, agents)
    sd = np.stack([_sd(results[a]) for a in agents])
    n = np.stack([_counts(results[a]) for a in agents]).astype(float)
    iu = np.triu_indices(len(agents), 1)
    picks: list[str] = []
    for _ in range(k):
        few = [i for i in range(len(agents)) if n[i].min() < 2]
        if few:
            i = min(few, key=lambda i: (n[i].min(), i))
        else:
            lo, hi, diff, _ = _sign_ranges(means, sd, n, higher, level)
            is_open = _open(lo, hi)
            if not is_open.any():
                break
            gains = np.zeros(len(agents))
            for q in np.flatnonzero(is_open):
                a, b = iu[0][q], iu[1][q]
                metrics = np.flatnonzero(lo[q] != hi[q])
                for who in (a, b):
                    n2 = n.copy()
                    n2[who] += 1
                    before = np.sqrt(sd[a, metrics] ** 2 / n[a, metrics] + sd[b, metrics] ** 2 / n[b, metrics])
                    after = np.sqrt(sd[a, metrics] ** 2 / n2[a, metrics] + sd[b, metrics] ** 2 / n2[b, metrics])
                    gains[who] += float((settle_probability(diff[q, metrics], after, level)
                                         - settle_probability(diff[q, metrics], before, level)).sum())
            i = int(np.argmax(gains - 1e-12 * n.min(1)))  # equal gains: the agent with fewer episodes
        picks.append(agents[i])
        n[i] += 1
    return picks


@dataclass(frozen=True)
class PlanRow:
    """What an experiment with ``n`` target episodes per agent can expect (over simulated experiments)."""

    n: int
    width_mean: float  # PRPV order range width, mean
    width_q: float  # its ``confidence`` quantile
    p_width: float  # P(width ≤ the goal); NaN without a goal
    p_correct: float  # P(argmin PRPV = the pilot's best θ); NaN without candidates
    open_pairs: float  # mean number of target pairs left open


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

    def to_dict(self) -> dict:
        d = asdict(self)
        d["pairs"] = [{**asdict(p), "episodes": p.episodes if math.isfinite(p.episodes) else None}
                      for p in self.pairs]
        return d


def _draws(results: Results, agents: list[str], n: int, reps: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {a: rng.integers(0, len(results[a]), (reps, n)) for a in agents}


def _simulate(target: Results, proxies: Mapping[str, Results], higher, n: int, reps: int, level: float,
              rng: np.random.Generator, sd_t: np.ndarray, sd_p: dict[str, np.ndarray], width_of: str | None):
    """Order-range widths (reps,) of candidate ``width_of`` (None: a proxy ordering as the target, as noisy),
    PRPV of each candidate (reps, C) and open target pairs (reps,), at n episodes per agent."""
    from proxybench.usefulness.intervals import order_range
    from proxybench.usefulness.metrics import resampled_means

    agents = list(target)
    idx = _draws(target, agents, n, reps, rng)
    tm = np.stack([resampled_means(target[a], idx[a]) for a in agents], 1)
    nn = np.full(sd_t.shape, float(n))
    lo_t, hi_t, _, _ = _sign_ranges(tm, sd_t, nn, higher, level)
    open_pairs = _open(lo_t, hi_t).sum(-1)
    prpv = np.full((reps, len(proxies)), np.nan)
    widths = np.zeros(reps)
    side = {}
    for c, (label, pres) in enumerate(proxies.items()):
        pm = np.stack([resampled_means(pres[a], idx[a]) for a in agents], 1)
        prpv[:, c] = prpv_from_means(pm, tm, higher)
        side[label] = _sign_ranges(pm, sd_p[label], nn, higher, level)[:2]
    lo_p, hi_p = side[width_of] if width_of is not None else (lo_t, hi_t)
    for r in range(reps):
        low, high = order_range(lo_p[r], hi_p[r], lo_t[r], hi_t[r])
        widths[r] = high - low
    return widths, prpv, open_pairs


def plan(target: Results, higher: Sequence[bool], names: Sequence[str], *, proxies: Mapping[str, Results] | None = None,
         width: float | None = None, p_correct: float | None = None, confidence: float = 0.8,
         grid: Sequence[int] | None = None, reps: int = 400, level: float = 0.95, power: float = 0.8,
         batch: int = 4, seed: int = 0) -> Plan:
    """Plan the episodes per agent from a pilot on the target (and its replays in candidate proxies).

    ``width``: the order-range width to reach (PRPV units) with probability ``confidence`` — of the pilot's
    best candidate, or without candidates of a proxy that orders the agents as the target and is as noisy;
    ``p_correct``: the probability of picking the pilot's best candidate. The answer is the smallest n on ``grid``
    (default: the pilot's count, 5, 10, … 320) that reaches it, refined between grid points.
    """
    agents = list(target)
    few = [a for a in agents if _counts(target[a]).min() < 2]
    if few:
        raise ValueError(f"a plan needs at least 2 pilot episodes with values per agent (to see their spread); "
                         f"{', '.join(few)} {'has' if len(few) == 1 else 'have'} fewer")
    proxies = dict(proxies or {})
    for label, pres in proxies.items():
        for a in agents:
            if len(pres[a]) != len(target[a]):
                raise ValueError(f"candidate {label!r}, agent {a!r}: {len(pres[a])} episodes, the pilot has "
                                 f"{len(target[a])}; candidates must replay the pilot's episodes")
    pilot_n = {a: int(len(target[a])) for a in agents}
    sd_t = np.stack([_sd(target[a]) for a in agents])
    sd_p = {lb: np.stack([_sd(p[a]) for a in agents]) for lb, p in proxies.items()}
    tmeans = agent_means(target, agents)
    pilot_prpv = {lb: float(prpv_from_means(agent_means(p, agents), tmeans, higher)) for lb, p in proxies.items()}
    lowest = min(pilot_prpv.values()) if pilot_prpv else None
    best = [lb for lb, v in pilot_prpv.items() if v == lowest]
    best_mask = np.array([lb in best for lb in proxies])

    def evaluate(n: int) -> PlanRow:
        rng = np.random.default_rng([seed, n])
        w, prpv, open_pairs = _simulate(target, proxies, higher, n, reps, level, rng, sd_t, sd_p,
                                        best[0] if best else None)
        p_ok = float("nan")
        if proxies:
            mins = prpv == prpv.min(1, keepdims=True)
            p_ok = float(((mins & best_mask).sum(1) / mins.sum(1)).mean())  # ties: broken at random
        return PlanRow(n, float(w.mean()), float(np.quantile(w, confidence)),
                       float((w <= width + 1e-9).mean()) if width is not None else float("nan"), p_ok,
                       float(open_pairs.mean()))

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
    return Plan(agents, tuple(names), pilot_n, [rows[n] for n in sorted(rows)],
                pair_needs(target, higher, names, level=level, power=power),
                next_agents(target, higher, k=batch, level=level), confidence, width, n_w, p_correct, n_p,
                list(proxies), pilot_prpv, best)
