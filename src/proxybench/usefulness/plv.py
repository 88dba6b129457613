"""Proxy learning value (PLV): how many target samples a proxy saves a learning agent (thesis §3.5).

An agent trained on the target alone needs |D_target| target samples to reach a reference score P
(the converged score of target-only training, less a tolerance). Pre-trained on the proxy, it needs
|D_proxy→target| target samples to reach the same P. Then

    PLV = |D_target| − |D_proxy→target|,   reduction = PLV / |D_target|.

The generalised PLV weighs on-policy target samples (DAgger: the learner drives the real robot and
the expert labels) and off-policy ones (the expert drives) differently, because they cost differently:
|D| = η_on · n_on + η_off · n_off.

A proxy whose pre-trained agent never reaches P on the ladder of data-set sizes tried has *no* PLV
on that ladder: it is reported as "not reached", never as a number (it is not −∞, nor the largest n).

**Reaching P once is not enough.** |D| is the smallest rung from which the score *stays* at or above
P on every larger rung tried (:func:`settled_rung`), the "reach and stay within the band" rule of a
step response's settling time (Ogata, *Modern Control Engineering*, §5-3: the time for the response
"to reach and stay within a range about the final value", usually 2 % or 5 %; our tolerance is the
band). The thesis' Def. 4 asks for performance "at convergence"; a rung that crosses P by seed noise
and falls back below it on the next is not converged performance. :func:`first_reaching` (the old,
once-is-enough rule) is kept to show the difference.

>>> first_reaching([250, 500, 1000], [3.0, 9.5, 10.2], threshold=9.5)
500
>>> settled_rung([0, 250, 500, 1000], [9.8, 9.0, 9.6, 9.7], threshold=9.5, confirm=1)
500
>>> settled_rung([0, 250], [9.8, 9.9], threshold=9.5, confirm=2) is None   # not yet confirmed
True
>>> first_reaching([250, 500], [3.0, 4.0], threshold=9.5) is None
True
>>> r = plv(DataCost(4000), DataCost(250))
>>> r.value, round(r.reduction, 4), r.status
(3750.0, 0.9375, 'ok')
>>> plv(DataCost(4000), None).label
'not reached'
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["DataCost", "PLVValue", "first_reaching", "ladder_done", "mean_ci", "plv", "reference_score",
           "settled_rung"]


@dataclass(frozen=True)
class DataCost:
    """Target samples used: collected with the expert driving (off-policy) and with the learner (on-policy)."""

    off_policy: int
    on_policy: int = 0

    def __post_init__(self) -> None:
        if self.off_policy < 0 or self.on_policy < 0:
            raise ValueError(f"sample counts must be >= 0, got {self}")

    @property
    def samples(self) -> int:
        return self.off_policy + self.on_policy

    def weighted(self, eta_on: float = 1.0, eta_off: float = 1.0) -> float:
        """|D| = η_on · n_on + η_off · n_off."""
        return eta_on * self.on_policy + eta_off * self.off_policy


@dataclass(frozen=True)
class PLVValue:
    """PLV in (weighted) target samples and the fractional reduction; both None unless ``status`` is "ok".

    ``status``: "ok"; "not reached" (the proxy-pre-trained agent never reached the reference score);
    "target not reached" (target-only training never did either, so there is nothing to compare to).
    """

    value: float | None
    reduction: float | None
    status: str
    target_cost: float | None
    proxy_cost: float | None

    @property
    def label(self) -> str:
        """For tables: the number, or why there is none."""
        if self.status != "ok" or self.value is None:
            return self.status
        return f"{self.value:,.0f}"

    @property
    def reduction_label(self) -> str:
        return "–" if self.reduction is None else f"{100 * self.reduction:.0f} %"


def plv(target: DataCost | None, proxy: DataCost | None, eta_on: float = 1.0, eta_off: float = 1.0) -> PLVValue:
    """The (generalised) PLV from the target samples each route needed; ``None`` means "never reached"."""
    if eta_on < 0 or eta_off < 0:
        raise ValueError("η weights must be >= 0")
    if target is None:
        pc = None if proxy is None else proxy.weighted(eta_on, eta_off)
        return PLVValue(None, None, "target not reached", None, pc)
    tc = target.weighted(eta_on, eta_off)
    if proxy is None:
        return PLVValue(None, None, "not reached", tc, None)
    pc = proxy.weighted(eta_on, eta_off)
    value = tc - pc
    return PLVValue(value, value / tc if tc > 0 else None, "ok", tc, pc)


def first_reaching(ns: Sequence[float], scores: Sequence[float], threshold: float) -> float | None:
    """The smallest ``n`` (ladder order) whose score is at least ``threshold``; None if none is.

    The ladder quantises the answer: the true requirement lies between this rung and the one below.
    """
    order = np.argsort(np.asarray(ns, dtype=float), kind="stable")
    for k in order:
        s = scores[int(k)]
        if s is not None and math.isfinite(s) and s >= threshold:
            n = ns[int(k)]
            return int(n) if float(n).is_integer() else float(n)
    return None


def settled_rung(ns: Sequence[float], scores: Sequence[float], threshold: float, confirm: int = 2,
                 through_end: bool = False) -> float | None:
    """The smallest ``n`` from which the score stays at or above ``threshold`` on every rung tried after it.

    ``ns`` are the rungs tried (0 for a zero-shot score), in any order. A rung counts only when it is
    *confirmed*: at least ``confirm`` rungs after it were tried and all stay above, or (``through_end``)
    the rungs tried run to the end of the ladder, so there is nothing left to check. None: the score
    never settles above ``threshold`` on the rungs tried (a NaN score counts as below).
    """
    if confirm < 0:
        raise ValueError(f"confirm must be >= 0, got {confirm}")
    order = np.argsort(np.asarray(ns, dtype=float), kind="stable")
    x = np.asarray(ns, dtype=float)[order]
    y = np.asarray([np.nan if v is None else v for v in scores], dtype=float)[order]
    above = np.nan_to_num(y, nan=-np.inf) >= threshold
    if not above.size or not above[-1]:
        return None
    k = int(above.size - np.argmin(above[::-1])) if not above.all() else 0  # first rung of the final run above
    if above.size - 1 - k < confirm and not through_end:
        return None
    return int(x[k]) if float(x[k]).is_integer() else float(x[k])


def ladder_done(means: Sequence[float], reference: float, confirm: int) -> bool:
    """Whether a proxy's ladder can stop: the last ``confirm + 1`` rung means tried (the zero-shot score counting
    as rung 0) are all at or above the reference, so "reach and stay" is decided whatever came before.

    >>> ladder_done([3.0, 9.6, 9.7, 9.9], 9.5, 2), ladder_done([3.0, 9.6, 9.4, 9.9], 9.5, 2)
    (True, False)
    """
    tail = list(means)[-(confirm + 1):]
    return len(tail) == confirm + 1 and min(tail) >= reference


def reference_score(converged: float, tolerance: float) -> float:
    """The score to reach: the converged target-only score less ``tolerance`` of its magnitude."""
    if not 0.0 <= tolerance < 1.0:
        raise ValueError(f"tolerance must be in [0, 1), got {tolerance}")
    return converged - tolerance * abs(converged)


def mean_ci(values: Sequence[float], level: float = 0.95) -> tuple[float, float, float]:
    """Mean and a Student-t confidence interval over training seeds; (m, m, m) for a single value."""
    v = np.asarray(values, dtype=float)
    m = float(v.mean())
    if v.size < 2:
        return m, m, m
    from scipy import stats

    half = float(stats.t.ppf(0.5 + level / 2, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size))
    return m, m - half, m + half
