"""Bradley–Terry scores with intervals from paired episodes: how strong each agent is, how sure that is, and how
few episodes first place rests on.

A leaderboard's semiorder says who is ahead, not whether the episodes settle it. Here every pair of agents is
compared in each episode both ran — episodes are paired by id (the same start and seed for every agent), so an
episode's difficulty cancels — and the Bradley–Terry model P(a beats b) = 1 / (1 + exp(s_b − s_a)) is fitted to the
wins: a beats b when better by more than the tolerance ε, a difference up to ε is a tie and counts half a win each
way, an episode where either value is missing (NaN) is skipped for that pair. Several metrics compare
lexicographically, as the benchmark's semiorder does (:func:`bradley_terry_lexicographic`): the first metric that is
not a tie decides.

- **Scores** are log-strengths with mean 0 over the agents compared: exp(s_a − s_b) is the odds that a beats b in
  an episode. They are fitted by maximum likelihood with `choix`'s ILSR, regularised by ``alpha`` (its Markov
  chain starts with that rate between every pair: about one drawn virtual episode per pair at alpha = 0.25), so an
  agent that wins every comparison keeps a finite score and agents that never met are still placed (near 0).
- **Intervals** are percentile bootstraps over episode ids (seeded): resampling whole episodes keeps all the pairs
  of an episode together, so their correlation is in the interval. Each is widened, where narrower, to the model's
  own (Wald) interval: with a perfect record or a handful of episodes every resample has the same outcomes and the
  bootstrap alone would claim certainty.
- **Provisional** when the leader's interval overlaps the runner-up's: first place is not settled.
- **Fragility**: the fewest episodes whose removal changes first place, searched greedily (remove the episode where
  the leader did best against the runner-up, refit, repeat) up to a cap; "> N" when the cap is reached. Greedy gives
  an upper bound on the true fewest; one or two means one lucky episode could be the whole lead.

>>> values = {"a": {0: 3.0, 1: 2.0, 2: 4.0, 3: 3.0}, "b": {0: 1.0, 1: 1.0, 2: 2.0, 3: 3.0},
...           "c": {0: 0.0, 1: 0.0, 2: 1.0, 3: 2.9}}
>>> r = bradley_terry(values, tolerance=0.5, resamples=50)
>>> [s.agent for s in r.scores], r.scores[0].score > r.scores[1].score > r.scores[2].score
(['a', 'b', 'c'], True)
>>> r.provisional, str(r.fragility)
(True, '3')
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from proxybench.tasks.aggregate import STATS

__all__ = [
    "ALPHA",
    "FRAGILITY_CAP",
    "LEVEL",
    "RESAMPLES",
    "AgentScore",
    "BTResult",
    "EpisodeScores",
    "Fragility",
    "Outcomes",
    "RelativeScore",
    "bradley_terry",
    "bradley_terry_lexicographic",
    "episode_metric",
    "fit_bradley_terry",
    "fit_strengths",
    "lexicographic_outcomes",
    "pairwise_outcomes",
    "ppi_bradley_terry",
]

ALPHA = 0.25  # choix's regularisation: ≈ one drawn virtual episode per pair; keeps a perfect record finite
RESAMPLES = 200  # bootstrap resamples over episode ids
LEVEL = 0.95
FRAGILITY_CAP = 50  # episodes removed at most in the fragility search
_TOP_TIE = 1e-6  # scores closer than this share first place (the fits converge to ~1e-8)


@dataclass(frozen=True)
class EpisodeScores:
    """One metric's per-episode values, agent → {episode id → value}, with its direction and tolerance ε."""

    values: Mapping[Hashable, Mapping[Hashable, float]]
    higher_is_better: bool = True
    tolerance: float = 0.0

    def __post_init__(self) -> None:
        if not (isinstance(self.tolerance, int | float) and math.isfinite(self.tolerance) and self.tolerance >= 0):
            raise ValueError(f"tolerance must be a finite number >= 0, got {self.tolerance!r}")


@dataclass(frozen=True)
class Outcomes:
    """Every pair in every episode: ``table[e, i, j]`` is 1 when agent i beat j in episode e, 0.5 a tie, 0 a loss,
    NaN when the pair was not compared there (either value missing; the diagonal)."""

    agents: tuple[Hashable, ...]
    episodes: tuple[Hashable, ...]
    table: np.ndarray  # (episodes, agents, agents)

    @property
    def wins(self) -> np.ndarray:
        """``table`` with NaN as 0: summed over episodes it is the win matrix (ties as halves)."""
        return np.nan_to_num(self.table, nan=0.0)

    @property
    def compared(self) -> np.ndarray:
        """(agents, agents): in how many episodes each pair was compared."""
        return (~np.isnan(self.table)).sum(axis=0)


@dataclass(frozen=True)
class AgentScore:
    """One agent's Bradley–Terry score (log-strength, mean 0 over the agents compared) and its interval; all None
    for an agent compared with no one (no episode in common with another agent)."""

    agent: Hashable
    score: float | None
    lo: float | None
    hi: float | None
    comparisons: int  # (episode, opponent) comparisons it took part in
    contender: bool = False  # its interval reaches the leader's: it could be first (the leader itself included)

    def text(self, decimals: int = 2) -> str:
        """"0.41 [0.12, 0.70]", or "—" without a score."""
        if self.score is None:
            return "—"
        if self.lo is None or self.hi is None:
            return f"{self.score:.{decimals}f}"
        return f"{self.score:.{decimals}f} [{self.lo:.{decimals}f}, {self.hi:.{decimals}f}]"


@dataclass(frozen=True)
class Fragility:
    """The fewest episodes whose removal changes first place (greedy search): ``removals`` None when first place
    survived ``cap`` removals; ``removed`` the episode ids taken out, in order."""

    removals: int | None
    cap: int
    removed: tuple[Hashable, ...] = ()

    def __str__(self) -> str:
        return f"> {self.cap}" if self.removals is None else str(self.removals)


@dataclass(frozen=True)
class BTResult:
    """A board's Bradley–Terry scores, best first (agents without a score last), and how settled first place is."""

    scores: tuple[AgentScore, ...]
    provisional: bool  # the leader's interval overlaps the runner-up's (or first place is shared)
    fragility: Fragility | None  # None when there is no first place to lose (fewer than two agents compared)
    episodes: int  # distinct episode ids
    resamples: int
    level: float
    alpha: float
    notes: tuple[str, ...] = ()  # what limits the scores: disconnected agents, too few of them

    def by_agent(self) -> dict[Hashable, AgentScore]:
        return {s.agent: s for s in self.scores}

    @property
    def leader(self) -> Hashable | None:
        return self.scores[0].agent if self.scores and self.scores[0].score is not None else None

    def to_json(self) -> dict[str, Any]:
        """The board-level summary as plain data (the per-agent scores go with each agent's row)."""
        return {"method": "bradley-terry", "episodes": self.episodes, "resamples": self.resamples,
                "level": self.level, "alpha": self.alpha, "leader": self.leader, "provisional": self.provisional,
                "fragility": None if self.fragility is None else
                {"episodes": self.fragility.removals, "cap": self.fragility.cap, "text": str(self.fragility)},
                "notes": list(self.notes)}


def episode_metric(criterion: str) -> str:
    """The per-episode metric a benchmark criterion aggregates (``survival_time_median`` → ``survival_time``): what
    a board's Bradley–Terry scores compare episode by episode.

    >>> episode_metric("driven_lanedir_consec_median"), episode_metric("distance")
    ('driven_lanedir_consec', 'distance')
    """
    base, _, stat = criterion.rpartition("_")
    return base if base and stat in STATS else criterion


def _sorted_ids(ids: Sequence[Hashable]) -> tuple[Hashable, ...]:
    """Sorted when they sort (a deterministic order for the seeded bootstrap), else as first seen."""
    unique = list(dict.fromkeys(ids))
    try:
        return tuple(sorted(unique))  # type: ignore[type-var]
    except TypeError:
        return tuple(unique)


def lexicographic_outcomes(criteria: Sequence[EpisodeScores]) -> Outcomes:
    """Pairwise outcomes per episode under several metrics in order: the first metric on which the two differ by
    more than its tolerance decides; a tie on every metric is a tie; a missing value (NaN, or no value for that
    episode) on a metric that is consulted leaves the pair uncompared in that episode."""
    if not criteria:
        raise ValueError("no metric to compare on")
    agents = tuple(dict.fromkeys(a for c in criteria for a in c.values))
    episodes = _sorted_ids([e for c in criteria for per in c.values.values() for e in per])
    k, n = len(agents), len(episodes)
    where = {e: i for i, e in enumerate(episodes)}
    out = np.full((n, k, k), 0.5)
    decided = np.zeros((n, k, k), dtype=bool)
    missing = np.zeros((n, k, k), dtype=bool)
    for c in criteria:
        v = np.full((n, k), np.nan)
        for j, a in enumerate(agents):
            for e, x in c.values.get(a, {}).items():
                v[where[e], j] = _float(x)
        nan = np.isnan(v)
        gain = v[:, :, None] - v[:, None, :]
        if not c.higher_is_better:
            gain = -gain
        open_ = ~decided & ~missing
        missing |= open_ & (nan[:, :, None] | nan[:, None, :])
        open_ &= ~missing
        with np.errstate(invalid="ignore"):  # inf − inf: equal infinities tie, as in the semiorder
            win, loss = open_ & (gain > c.tolerance), open_ & (gain < -c.tolerance)
        out[win], out[loss] = 1.0, 0.0
        decided |= win | loss
    out[missing] = np.nan
    idx = np.arange(k)
    out[:, idx, idx] = np.nan
    return Outcomes(agents, episodes, out)


def pairwise_outcomes(values: Mapping[Hashable, Mapping[Hashable, float]], higher_is_better: bool = True,
                      tolerance: float = 0.0) -> Outcomes:
    """Pairwise outcomes per episode of one metric (agent → {episode id → value})."""
    return lexicographic_outcomes([EpisodeScores(values, higher_is_better, tolerance)])


def _float(x: Any) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def fit_strengths(wins: np.ndarray, alpha: float = ALPHA, initial: np.ndarray | None = None,
                  tol: float = 1e-8) -> np.ndarray:
    """Bradley–Terry log-strengths (mean 0) from a win matrix ``wins[i, j]`` (i's wins over j, ties as halves), by
    choix's ILSR; ``initial`` warm-starts it (a bootstrap resample from the full fit converges in a few steps)."""
    import choix

    k = wins.shape[0]
    if k == 1:
        return np.zeros(1)
    try:
        return np.asarray(choix.ilsr_pairwise_dense(wins, alpha=alpha, initial_params=initial, max_iter=1000, tol=tol))
    except (RuntimeError, ValueError) as exc:  # no convergence, or a chain without a unique stationary state
        raise ValueError(f"Bradley–Terry fit failed ({exc}); a larger alpha regularises more") from exc


def _components(compared: np.ndarray) -> int:
    from scipy.sparse.csgraph import connected_components

    return int(connected_components(compared > 0, directed=False)[0])


def fit_bradley_terry(outcomes: Outcomes, *, alpha: float = ALPHA, resamples: int = RESAMPLES, level: float = LEVEL,
                      seed: int = 0, fragility_cap: int = FRAGILITY_CAP) -> BTResult:
    """Scores, intervals (``resamples`` bootstrap resamples of episode ids, seeded), provisional and fragility from
    pairwise outcomes. ``resamples=0`` skips the intervals (then nothing is provisional by overlap)."""
    if not alpha > 0:
        raise ValueError(f"alpha must be > 0 (it keeps a perfect record finite), got {alpha!r}")
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level!r}")
    if resamples < 0 or fragility_cap < 0:
        raise ValueError("resamples and fragility_cap must be >= 0")
    wins = outcomes.wins
    compared = outcomes.compared
    per_agent = compared.sum(axis=1)
    fitted = np.flatnonzero(per_agent > 0)
    n_ep = len(outcomes.episodes)
    notes: list[str] = []
    unscored = [outcomes.agents[i] for i in np.flatnonzero(per_agent == 0)]
    if len(outcomes.agents) < 2:
        notes.append("one agent: nothing to compare")
    elif unscored:
        notes.append(f"{len(unscored)} agent(s) share no episode with another agent: no score")
    if len(fitted) < 2:
        scores = tuple(AgentScore(a, None, None, None, 0) for a in outcomes.agents)
        return BTResult(scores, False, None, n_ep, 0, level, alpha, tuple(notes))
    sub = wins[:, fitted][:, :, fitted]  # (E, k, k)
    flat = sub.reshape(n_ep, -1)
    k = len(fitted)
    point = fit_strengths(sub.sum(axis=0), alpha)
    parts = _components(compared[np.ix_(fitted, fitted)])
    if parts > 1:
        notes.append(f"the agents fall into {parts} groups that share no episode: scores across groups are not "
                     "comparable")
    lo = hi = None
    if resamples and n_ep:
        rng = np.random.default_rng(seed)
        draws = rng.multinomial(n_ep, np.full(n_ep, 1.0 / n_ep), size=resamples).astype(float)
        boot = np.empty((resamples, k))
        for r in range(resamples):
            boot[r] = fit_strengths((draws[r] @ flat).reshape(k, k), alpha, initial=point, tol=1e-4)
        q = (1 - level) / 2
        wald = _wald_halfwidth(point, compared[np.ix_(fitted, fitted)], level)
        lo = np.minimum(np.quantile(boot, q, axis=0), point - wald)
        hi = np.maximum(np.quantile(boot, 1 - q, axis=0), point + wald)
    order = sorted(range(k), key=lambda i: -point[i])
    lead = order[0]
    top_shared = point[order[0]] - point[order[1]] <= _TOP_TIE
    contender = np.zeros(k, dtype=bool)
    contender[lead] = True
    if lo is not None and hi is not None:
        contender |= hi >= lo[lead]
    if top_shared:
        contender |= point >= point[lead] - _TOP_TIE
    provisional = bool(top_shared or parts > 1 or (lo is not None and hi is not None and hi[order[1]] >= lo[lead]))
    fragility = _fragility(sub, point, alpha, fragility_cap, outcomes.episodes, top_shared)
    scored = [AgentScore(outcomes.agents[fitted[i]], float(point[i]), None if lo is None else float(lo[i]),
                         None if hi is None else float(hi[i]), int(per_agent[fitted[i]]), bool(contender[i]))
              for i in order]
    scored += [AgentScore(a, None, None, None, 0) for a in unscored]
    return BTResult(tuple(scored), provisional, fragility, n_ep, resamples if n_ep else 0, level, alpha, tuple(notes))


def _wald_halfwidth(point: np.ndarray, compared: np.ndarray, level: float) -> np.ndarray:
    """Half-widths of the model's own (Wald) intervals: the inverse Fisher information of the centred log-strengths,
    n_ij p_ij (1 − p_ij) per pair (a graph Laplacian; its pseudo-inverse is the covariance under the mean-0
    constraint). The bootstrap alone sees no spread when every resample has the same outcomes (a perfect record, a
    handful of episodes) and would then claim certainty; the interval reported is the hull of both."""
    from statistics import NormalDist

    p = 1.0 / (1.0 + np.exp(point[None, :] - point[:, None]))
    w = compared * p * (1.0 - p)
    laplacian = np.diag(w.sum(axis=1)) - w
    var = np.clip(np.diag(np.linalg.pinv(laplacian, hermitian=True)), 0.0, None)
    return NormalDist().inv_cdf(0.5 + level / 2) * np.sqrt(var)


def _fragility(wins: np.ndarray, point: np.ndarray, alpha: float, cap: int, episodes: tuple[Hashable, ...],
               top_shared: bool) -> Fragility:
    """Greedy: take out the episode where the leader did best against the current runner-up (their head-to-head
    outcome, then the leader's wins minus the runner-up's over the whole field), refit, until someone else leads."""
    n = wins.shape[0]
    cap = min(cap, max(n - 1, 0))
    if top_shared:
        return Fragility(0, cap)
    lead = int(np.argmax(point))
    total = wins.sum(axis=0)
    field = wins.sum(axis=2)  # (E, k): each agent's wins in each episode
    alive = np.ones(n, dtype=bool)
    removed: list[Hashable] = []
    s = point
    for step in range(1, cap + 1):
        others = np.where(np.arange(len(s)) == lead, -np.inf, s)
        run = int(np.argmax(others))
        head = wins[:, lead, run] - wins[:, run, lead]
        margin = field[:, lead] - field[:, run]
        key = np.where(alive, head * (2 * len(s) + 1) + margin, -np.inf)  # head-to-head first, then the field
        e = int(np.argmax(key))
        alive[e] = False
        removed.append(episodes[e])
        total = total - wins[e]
        s = fit_strengths(total, alpha, initial=s, tol=1e-10)
        if np.delete(s, lead).max() >= s[lead] - _TOP_TIE:  # someone else leads, or shares the lead
            return Fragility(step, cap, tuple(removed))
    return Fragility(None, cap, tuple(removed))


def bradley_terry_lexicographic(criteria: Sequence[EpisodeScores], **kwargs: Any) -> BTResult:
    """:func:`fit_bradley_terry` on episodes compared under several metrics in order (the semiorder, per episode)."""
    return fit_bradley_terry(lexicographic_outcomes(criteria), **kwargs)


def bradley_terry(values: Mapping[Hashable, Mapping[Hashable, float]], higher_is_better: bool = True,
                  tolerance: float = 0.0, **kwargs: Any) -> BTResult:
    """:func:`fit_bradley_terry` on one metric's per-episode values (agent → {episode id → value}); ``kwargs``:
    alpha, resamples, level, seed, fragility_cap."""
    return fit_bradley_terry(pairwise_outcomes(values, higher_is_better, tolerance), **kwargs)


@dataclass(frozen=True)
class RelativeScore:
    """An agent's Bradley–Terry log-odds of beating the reference agent in an episode, with its interval."""

    agent: Hashable
    score: float
    lo: float
    hi: float


def ppi_bradley_terry(target: Mapping[Hashable, Mapping[Hashable, float]],
                      proxy: Mapping[Hashable, Mapping[Hashable, float]] | None, higher_is_better: bool = True,
                      tolerance: float = 0.0, level: float = LEVEL) -> tuple[tuple[RelativeScore, ...], float]:
    """Bradley–Terry scores from the target's paired episodes with a proxy's as the predictor, and the weight λ
    the proxy got (AutoEval Done Right, Boyeau et al. 2025: PPI++ on the logistic regression of who beats whom).

    Each compared pair in a target episode is an observation (x = +1 for a, −1 for b; the first agent is the
    reference, its column left out) with outcome o (1, ½ for a tie, 0); the proxy's outcome in the same episode
    is its prediction ô, its outcomes in its own episodes (ids the target lacks) the unlabeled observations. The
    M-estimator, its λ and the sandwich interval (summed per episode: an episode's pairs share its start) are
    PPI++'s (Angelopoulos, Duchi & Zrnic 2023), written here because ``ppi_py.ppi_logistic_ci`` compiles with
    Numba on every new process (14–21 s); x takes one value per pair, so every sum runs over pairs. No proxy:
    λ = 0, the maximum-likelihood fit. Scores are relative to the first agent (0); intervals are per agent."""
    from scipy import stats as st

    t = pairwise_outcomes(target, higher_is_better, tolerance)
    agents, k = t.agents, len(t.agents)
    i, j, xp = _pair_rows(k)
    o = t.table[:, i, j]  # target episodes × pairs (NaN: not compared)
    o_hat = np.full(o.shape, np.nan)
    u = np.empty((0, len(i)))
    if proxy is not None:
        p = pairwise_outcomes({a: proxy.get(a, {}) for a in agents}, higher_is_better, tolerance)
        at = {e: n for n, e in enumerate(p.episodes)}
        have = [n for n, e in enumerate(t.episodes) if e in at]
        o_hat[have] = p.table[[at[t.episodes[n]] for n in have]][:, i, j]
        u = p.table[[n for n, e in enumerate(p.episodes) if e not in set(t.episodes)]][:, i, j]
    fit = _PPILogistic(xp, o, o_hat, u)
    lam = fit.weight() if fit.usable else 0.0
    theta = fit.solve(lam)
    half = st.norm.ppf(0.5 + level / 2) * np.sqrt(np.maximum(np.diag(fit.cov(theta, lam)), 0.0))
    out = [RelativeScore(agents[0], 0.0, 0.0, 0.0)]
    out += [RelativeScore(a, float(theta[n]), float(theta[n] - half[n]), float(theta[n] + half[n]))
            for n, a in enumerate(agents[1:])]
    return tuple(out), float(lam)


def _pair_rows(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(i, j, x) of every pair i < j: x the covariates of "i against j", agent 0 the reference (its column left
    out)."""
    i, j = np.triu_indices(k, 1)
    x = np.zeros((len(i), k))
    x[np.arange(len(i)), i], x[np.arange(len(i)), j] = 1.0, -1.0
    return i, j, x[:, 1:]


def _sigmoid(z: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * z))


class _PPILogistic:
    """PPI++ for the pairwise logistic model on episode × pair tables: ``o`` the target's outcomes, ``o_hat`` the
    proxy's on the same episodes, ``u`` the proxy's on its own (NaN: not compared)."""

    def __init__(self, xp: np.ndarray, o: np.ndarray, o_hat: np.ndarray, u: np.ndarray, ridge: float = 1e-3):
        self.xp, self.ridge = xp, ridge
        seen = ~np.isnan(o)
        self.usable = bool(len(u) >= 2 and not np.isnan(o_hat[seen]).any() and (~np.isnan(u)).sum() >= 2)
        self.o, self.o_hat = np.where(seen, o, np.nan), np.where(seen, o_hat, np.nan)
        self.u = u
        self.n, self.big_n = seen.sum() + len(xp), (~np.isnan(u)).sum()
        # per pair: observations and Σ outcomes, with one virtual tie (choix's regularisation, as the boards'):
        # a perfect record keeps a finite score
        self.n_p, self.o_p = seen.sum(0) + 1.0, np.nansum(self.o, 0) + 0.5
        self.h_p = np.nansum(self.o_hat, 0) if self.usable else np.zeros(len(xp))
        self.m_p = (~np.isnan(u)).sum(0) if self.usable else np.zeros(len(xp))
        self.u_p = np.nansum(u, 0) if self.usable else np.zeros(len(xp))

    def _s(self, theta: np.ndarray) -> np.ndarray:
        return _sigmoid(self.xp @ theta)

    def _hessian(self, s: np.ndarray, lam: float) -> np.ndarray:
        big_n = max(self.big_n, 1)
        d = s * (1 - s) * ((1 - lam) * self.n_p / self.n + lam * self.m_p / big_n)
        return (self.xp * d[:, None]).T @ self.xp + self.ridge * np.eye(self.xp.shape[1])

    def solve(self, lam: float) -> np.ndarray:
        """argmin of mean ℓ(θ; o) − λ mean ℓ(θ; ô) + λ mean_u ℓ(θ; ô_u) (+ a tiny ridge: a perfect record stays
        finite), by Newton's method (convex for λ ∈ [0, 1])."""
        theta, big_n = np.zeros(self.xp.shape[1]), max(self.big_n, 1)
        for _ in range(100):
            s = self._s(theta)
            r = ((1 - lam) * self.n_p * s - self.o_p + lam * self.h_p) / self.n
            r = r + lam * (self.m_p * s - self.u_p) / big_n
            step = np.linalg.solve(self._hessian(s, lam), self.xp.T @ r + self.ridge * theta)
            theta -= step
            if np.abs(step).max() < 1e-10:
                break
        return theta

    def _residuals(self, s: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """Per episode × pair: the labeled gradient's scalar (s − o) − λ(s − ô), and the unlabeled one's s − ô_u
        (0 where not compared)."""
        lab = np.nan_to_num((s - self.o) - lam * (s - np.nan_to_num(self.o_hat)))
        unl = np.nan_to_num(s - self.u) if self.usable else np.zeros((0, len(s)))
        return lab, unl

    def cov(self, theta: np.ndarray, lam: float) -> np.ndarray:
        """The sandwich H⁻¹(V_l + λ²V_u)H⁻¹, each V from the gradients summed per episode; its diagonal at least
        the model's own H⁻¹/n at λ = 0 (a perfect record has no spread to estimate V from, and would claim
        certainty: the boards' intervals are widened the same way)."""
        s = self._s(theta)
        lab, unl = self._residuals(s, lam)
        inv = np.linalg.pinv(self._hessian(s, lam) - self.ridge * np.eye(len(theta)))
        v = _episode_var(lab @ self.xp) / self.n**2
        if self.usable and lam:
            v = v + lam**2 * _episode_var(unl @ self.xp) / self.big_n**2
        out = inv @ v @ inv
        model = np.linalg.pinv(self._hessian(s, 0.0) - self.ridge * np.eye(len(theta))) / self.n
        idx = np.diag_indices(len(theta))
        out[idx] = np.maximum(out[idx], model[idx])
        return out

    def _rows(self, r: np.ndarray) -> np.ndarray:
        """Per-observation gradients r·x of an episode × pair table of residuals (NaN: no observation)."""
        e, pair = np.nonzero(~np.isnan(r))
        return r[e, pair][:, None] * self.xp[pair]

    def weight(self) -> float:
        """PPI++'s λ for the whole vector at the λ = 1 fit: tr(H⁻¹(C + Cᵀ)H⁻¹) / (2(1 + n/N) tr(H⁻¹V̂H⁻¹)), clipped
        to [0, 1]; C the covariance of the per-observation gradients with o and with ô, V̂ that of the ô-gradients
        (labeled and unlabeled)."""
        s = self._s(self.solve(1.0))
        g, g_hat, g_u = self._rows(s - self.o), self._rows(s - self.o_hat), self._rows(s - self.u)
        inv = np.linalg.pinv(self._hessian(s, 0.0) - self.ridge * np.eye(self.xp.shape[1]))
        gc, ghc = g - g.mean(0), g_hat - g_hat.mean(0)
        cross = (gc.T @ ghc + ghc.T @ gc) / len(g)
        allh = np.concatenate([g_hat, g_u])
        var = np.cov(allh.T).reshape(len(cross), len(cross))
        den = 2 * (1 + self.n / self.big_n) * np.trace(inv @ var @ inv)
        return float(np.clip(np.trace(inv @ cross @ inv) / den, 0.0, 1.0)) if den > 0 else 0.0


def _episode_var(g: np.ndarray) -> np.ndarray:
    """Σ over episodes of (G_e − Ḡ)(G_e − Ḡ)ᵀ · E/(E − 1), G_e an episode's gradient (its pairs summed)."""
    e = len(g)
    centred = g - g.mean(0)
    return centred.T @ centred * e / max(e - 1, 1)
