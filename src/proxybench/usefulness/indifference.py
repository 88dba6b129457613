"""ε-indifference: when is the order of two agents on the target *settled*, and how many episodes until it is?

The benchmark orders agents by a lexicographic semiorder: a difference up to a criterion's tolerance ε is a tie
(AIDO's lane-following tolerances, ``benchmarks/aido_lf.yaml``). Asking the target to order every pair *exactly*
needs unboundedly many episodes for a pair whose true difference is near 0 (the planner once quoted 826 and
2,032 episodes for pairs 0.07 ± 0.83 standard errors apart). With indifference a pair's order on a metric is

- **ordered** when its (1 − α) interval excludes 0 (Welch's t, the two agents' episode spreads): its sign is
  known. If the true difference is within ε, that order is not wrong, only finer than the tolerance;
- **tied** when the interval lies inside (−ε, ε): the two one-sided tests of equivalence (TOST);
- **open** otherwise, and more episodes are needed.

Whatever the true difference d, one of the first two happens with enough episodes: the most a pair can need
is where the two meet (|d| ≈ ε/2), about 4 (q + z)² σ² / ε² episodes per agent — finite. With ε = 0 the old
rule is back (a pair with d = 0 is never settled).

The *pilot's* uncertainty is carried into the episode counts (:func:`needs`): the agents' true means and
spreads are drawn from their posterior given the pilot (normal episodes, flat prior: σ² ~ s²(n−1)/χ²ₙ₋₁,
μ ~ N(x̄, σ²/n)), the count is computed for every draw, and the answer is a range of its quantiles, never the
plug-in value alone. :mod:`proxybench.usefulness.stopping` spends episodes with this rule until every pair is
settled; its error rate is checked by simulation there.

>>> r = Rule((0.5,))
>>> int(settle_state(np.array([0.9]), np.array([0.2]), np.array([8.0]), r)[0])   # 0.9 ± 0.46 excludes 0
1
>>> int(settle_state(np.array([0.05]), np.array([0.1]), np.array([8.0]), r)[0])  # 0.05 ± 0.23 inside ±0.5: tie
0
>>> int(settle_state(np.array([0.3]), np.array([0.2]), np.array([8.0]), r)[0])   # 0.3 ± 0.46: open
2
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import special

from proxybench.usefulness.metrics import _signed, agent_means, pair_signs

__all__ = ["OPEN", "TIE", "PairStats", "Rule", "episodes_to_settle", "needs", "pair_stats", "posterior_draws",
           "semiorder_tolerances", "settle_probability", "settle_state", "sign_ranges"]

Results = Mapping[str, np.ndarray]
TIE, OPEN = 0, 2  # settle_state codes besides +1 / −1 (ordered: i better / j better)
#: the thesis' lane score is in seconds like survival time; AIDO's table has no criterion for it
_LIKE = {"lane_score": "survival_time"}


def semiorder_tolerances(metrics: Sequence[str], seconds: float, *, benchmark: str = "aido_lf",
                         overrides: Mapping[str, float] | None = None) -> tuple[float, ...]:
    """ε per metric: the benchmark's scoring tolerances scaled to episodes of ``seconds`` (AIDO's are for its
    60 s episodes; distances and times driven grow with the episode), the lane score taking survival time's.
    A metric the benchmark does not rank by gets 0 (strict order); ``overrides`` (metric → ε at ``seconds``)
    win over both.

    >>> semiorder_tolerances(("driven_lanedir_consec", "lane_score", "deviation_heading"), 20.0)
    (0.20666666666666667, 0.6666666666666666, 0.0)
    """
    from proxybench.tasks.benchmark import Benchmark, parse_scoring_metric

    bench = Benchmark.load(benchmark)
    base = {parse_scoring_metric(c.metric)[0]: c.tolerance * seconds / bench.duration for c in bench.criteria()}
    over = dict(overrides or {})
    return tuple(float(over[m]) if m in over else float(base.get(m, base.get(_LIKE.get(m, ""), 0.0)))
                 for m in metrics)


@dataclass(frozen=True)
class Rule:
    """When a pair counts as settled: tolerances ε (per metric), error level α = 1 − ``level`` per pair and
    metric, split evenly over ``looks`` (Bonferroni: a sequential loop checks after every batch)."""

    tolerances: tuple[float, ...]
    level: float = 0.95
    looks: int = 1

    def __post_init__(self) -> None:
        if not 0.0 < self.level < 1.0:
            raise ValueError(f"level must be in (0, 1), got {self.level}")
        if self.looks < 1:
            raise ValueError(f"looks must be >= 1, got {self.looks}")
        if any(not np.isfinite(e) or e < 0 for e in self.tolerances):
            raise ValueError(f"tolerances must be finite and >= 0, got {self.tolerances}")

    @property
    def tail(self) -> float:
        """One tail's error probability per look."""
        return (1.0 - self.level) / (2.0 * self.looks)

    def quantile(self, df: np.ndarray | float) -> np.ndarray:
        """Student's t quantile 1 − tail at ``df`` degrees of freedom (normal for df = inf)."""
        df = np.asarray(df, float)
        log_df, q = _t_table(self.tail)
        fin = np.isfinite(df) & (df > 0)
        inside = np.interp(np.log(np.clip(np.where(fin, df, 1.0), _DF[0], _DF[-1])), log_df, q)
        return np.where(fin, np.where(df > _DF[-1], special.ndtri(1.0 - self.tail), inside),
                        np.where(np.isfinite(df), np.nan, special.ndtri(1.0 - self.tail)))


_DF = np.geomspace(0.5, 1e7, 2000)


@functools.lru_cache(maxsize=32)
def _t_table(tail: float) -> tuple[np.ndarray, np.ndarray]:
    """t quantiles on a log grid of df (interpolated: scipy's stdtrit costs ~1 ms a call, the loop calls it often)."""
    return np.log(_DF), special.stdtrit(_DF, 1.0 - tail)


@dataclass(frozen=True)
class PairStats:
    """Every pair (i < j) of agents: signed mean differences (> 0: i better), Welch standard errors and degrees of
    freedom, the per-episode variance sum s_i² + s_j², and the plain signs (NaN means are worst)."""

    agents: list[str]
    i: np.ndarray
    j: np.ndarray
    diff: np.ndarray  # (P, m)
    se: np.ndarray
    df: np.ndarray
    var: np.ndarray
    signs: np.ndarray
    n: np.ndarray  # (K, m) episodes with values


def _welch(va: np.ndarray, na: np.ndarray, vb: np.ndarray, nb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standard error and Welch–Satterthwaite df of a difference of means; se NaN where an agent has < 2 values."""
    with np.errstate(invalid="ignore", divide="ignore"):
        a, b = va / na, vb / nb
        se = np.sqrt(a + b)
        den = np.where(na > 1, a * a / (na - 1), 0.0) + np.where(nb > 1, b * b / (nb - 1), 0.0)
        df = np.where(den > 0, (a + b) ** 2 / den, np.inf)
    few = (na < 2) | (nb < 2)
    return np.where(few, np.nan, se), np.where(few, np.nan, df)


def pair_stats(results: Results, higher: Sequence[bool], agents: Sequence[str] | None = None) -> PairStats:
    """:class:`PairStats` of ``results`` (agent → (episodes, m) values; NaN: no value)."""
    agents = list(agents or results)
    means = agent_means(results, agents)
    arrs = [np.asarray(results[a], float) for a in agents]
    n = np.stack([np.isfinite(x).sum(0) for x in arrs]).astype(float)
    var = np.stack([_var(x) for x in arrs])
    i, j = np.triu_indices(len(agents), 1)
    signed = _signed(means, higher)
    se, df = _welch(var[i], n[i], var[j], n[j])
    signs = pair_signs(means, higher)[i, j]
    return PairStats(agents, i, j, signed[i] - signed[j], se, df, var[i] + var[j], signs, n)


def _var(x: np.ndarray) -> np.ndarray:
    out = np.full(x.shape[1], np.nan)
    for k in range(x.shape[1]):
        v = x[:, k][np.isfinite(x[:, k])]
        if v.size >= 2:
            out[k] = float(np.var(v, ddof=1))
    return out


def settle_state(diff: np.ndarray, se: np.ndarray, df: np.ndarray, rule: Rule) -> np.ndarray:
    """(…, m) codes: +1 / −1 ordered (i / j better), :data:`TIE`, :data:`OPEN`. A NaN difference (an agent with
    no value is worst, :func:`~proxybench.usefulness.metrics.pair_signs`) is ordered; a NaN standard error (fewer
    than 2 values) is open; se = 0 (both agents always alike, e.g. at a cap) decides by the difference alone."""
    eps = np.asarray(rule.tolerances, float)
    q = rule.quantile(np.nan_to_num(df, nan=1.0)) * np.nan_to_num(se, nan=np.inf)
    with np.errstate(invalid="ignore"):
        tie = np.abs(diff) + q < eps
        exact_tie = (se == 0) & (np.abs(diff) <= eps)
        ordered = np.abs(diff) > q
    out = np.where(tie | exact_tie, TIE, np.where(ordered, np.sign(diff), OPEN))
    return np.where(np.isnan(diff), 9, out)  # 9: NaN, resolved by the caller's plain signs


def sign_ranges(stats_: PairStats, rule: Rule) -> tuple[np.ndarray, np.ndarray]:
    """(P, m) plausible sign ranges [lo, hi] under ``rule``: a tie is (0, 0), an order its sign, open (−1, 1)."""
    return ranges_of(settle_state(stats_.diff, stats_.se, stats_.df, rule), stats_.signs)


def ranges_of(state: np.ndarray, signs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sign ranges from :func:`settle_state` codes (and the plain signs where the difference is NaN)."""
    s = np.where(state == 9, signs, state).astype(float)
    open_ = state == OPEN
    return np.where(open_, -1.0, s), np.where(open_, 1.0, s)


def settle_probability(delta: np.ndarray, se: np.ndarray, q: np.ndarray | float = 1.959964,
                       eps: np.ndarray | float = 0.0) -> np.ndarray:
    """P(settled) when the true difference is ``delta``, its standard error ``se`` and the rule's quantile ``q``
    (default: a two-sided 95 % normal one): the estimate lands beyond q·se (ordered) or within ε − q·se (tied).
    se = 0: settled."""
    d, s = np.abs(np.asarray(delta, float)), np.asarray(se, float)
    q, e = np.asarray(q, float), np.asarray(eps, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(s > 0, q * s, 0.0)
        zs = np.where(s > 0, s, 1.0)
        order = special.ndtr((d - c) / zs) + special.ndtr((-d - c) / zs)
        room = e - c
        tie = np.where(room > 0, special.ndtr((room - d) / zs) - special.ndtr((-room - d) / zs), 0.0)
        p = np.where(room > c, 1.0, order + tie)
    return np.where(s > 0, np.clip(p, 0.0, 1.0), 1.0)


def episodes_to_settle(delta: np.ndarray, var: np.ndarray, eps: np.ndarray | float, rule: Rule, power: float = 0.8,
                       cap: int = 100_000) -> np.ndarray:
    """Episodes per agent (both agents alike) for a pair with true difference ``delta`` and per-episode variance
    sum ``var`` to be settled with probability ``power`` (t quantile at 2n − 2 df); inf beyond ``cap``; 0 for
    an exact pair (var = 0). Vectorised; a bisection over n."""
    d, v = np.broadcast_arrays(np.asarray(delta, float), np.asarray(var, float))
    e = np.broadcast_to(np.asarray(eps, float), d.shape)
    grid_q = rule.quantile(2.0 * np.arange(cap + 1) - 2.0)  # q at n episodes per agent (n ≥ 2)

    def ok(n: np.ndarray) -> np.ndarray:
        return settle_probability(d, np.sqrt(v / n), grid_q[n], e) >= power

    lo, hi = np.full(d.shape, 1), np.full(d.shape, cap)
    reach = ok(hi)
    for _ in range(int(np.ceil(np.log2(cap))) + 1):
        mid = (lo + hi) // 2
        good = ok(np.maximum(mid, 2))
        hi, lo = np.where(good, mid, hi), np.where(good, lo, mid)
    n = np.maximum(hi, 2).astype(float)
    exact = ~(v > 0)
    return np.where(exact, 0.0, np.where(reach, n, np.inf))


def posterior_draws(results: Results, agents: Sequence[str], draws: int, rng: np.random.Generator,
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(draws, K, m) true means and standard deviations drawn from their posterior given the episodes (normal
    episodes, flat prior). An agent whose values on a metric are all equal keeps them (a cap, a constant); with
    fewer than 2 values its mean is kept and its spread is NaN."""
    mu, sd = [], []
    for a in agents:
        x = np.asarray(results[a], float)
        n = np.isfinite(x).sum(0)
        m = np.where(n > 0, np.nansum(np.where(np.isfinite(x), x, 0.0), 0) / np.maximum(n, 1), np.nan)
        s2 = _var(x)
        df = np.maximum(n - 1, 1)
        chi = rng.chisquare(df, (draws, x.shape[1]))
        sig2 = np.where(s2 > 0, s2 * (n - 1) / chi, np.where(n >= 2, 0.0, np.nan))
        mu.append(m + rng.standard_normal((draws, x.shape[1])) * np.sqrt(np.nan_to_num(sig2) / np.maximum(n, 1)))
        sd.append(np.sqrt(sig2))
    return np.stack(mu, 1), np.stack(sd, 1)


@dataclass(frozen=True)
class Needs:
    """Episodes per agent to settle each pair ((P,) median, low, high over the pilot's posterior) and every pair."""

    median: np.ndarray
    low: np.ndarray
    high: np.ndarray
    all_pairs: tuple[float, float, float]  # median, low, high
    plug_in: np.ndarray  # the pilot's point values, for comparison only


def needs(results: Results, higher: Sequence[bool], rule: Rule, *, power: float = 0.8, range_level: float = 0.8,
          draws: int = 1000, seed: int = 0, cap: int = 100_000) -> Needs:
    """Episodes per agent (equal for all agents) to settle each pair, as a range over the pilot's posterior.

    A pair needs what its most demanding metric needs (conservative: a pair two metrics order in opposite
    directions is incomparable sooner). ``range_level``: the central share of draws the range spans.
    """
    agents = list(results)
    st = pair_stats(results, higher, agents)
    eps = np.asarray(rule.tolerances, float)
    mu, sd = posterior_draws(results, agents, draws, np.random.default_rng(seed))
    signed = _signed(mu, higher)
    d = signed[:, st.i] - signed[:, st.j]
    v = sd[:, st.i] ** 2 + sd[:, st.j] ** 2
    per = _pair_max(episodes_to_settle(d, v, eps, rule, power, cap), st.diff)
    point = _pair_max(episodes_to_settle(st.diff, st.var, eps, rule, power, cap), st.diff)
    a = (1.0 - range_level) / 2.0
    qs = np.quantile(per, [0.5, a, 1.0 - a], axis=0, method="higher")
    every = np.quantile(per.max(-1) if per.shape[-1] else np.zeros(draws), [0.5, a, 1.0 - a], method="higher")
    return Needs(qs[0], qs[1], qs[2], tuple(float(x) for x in every), point)


def _pair_max(n: np.ndarray, diff: np.ndarray) -> np.ndarray:
    """The most any metric of a pair needs; a metric with a NaN difference (an agent without values) needs none."""
    n = np.where(np.isnan(np.broadcast_to(diff, n.shape)) | np.isnan(n), 0.0, n)
    return n.max(-1) if n.shape[-1] else n[..., 0]
