"""The compiled pair loop behind :func:`proxybench.tasks.scoring.copeland_counts` (Numba, cached on disk)."""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["copeland_kernel"]


@njit(cache=True, nogil=True)
def copeland_kernel(values: np.ndarray, higher: np.ndarray, tol: np.ndarray):  # pragma: no cover - compiled
    """Wins, losses and ties of every row against every other, as ``scoring.compare`` decides each pair:
    the first criterion on which one is better by more than its tolerance; NaN is worst, two NaNs tie,
    and equal infinities tie (inf - inf is NaN, which beats nothing)."""
    k, c = values.shape
    wins = np.zeros(k, np.int64)
    losses = np.zeros(k, np.int64)
    ties = np.zeros(k, np.int64)
    for i in range(k):
        for j in range(i + 1, k):
            verdict = 0
            for m in range(c):
                a = values[i, m]
                b = values[j, m]
                a_nan = np.isnan(a)
                b_nan = np.isnan(b)
                if a_nan or b_nan:
                    verdict = int(b_nan) - int(a_nan)
                else:
                    gain = a - b if higher[m] else b - a
                    if gain > tol[m]:
                        verdict = 1
                    elif gain < -tol[m]:
                        verdict = -1
                if verdict != 0:
                    break
            if verdict > 0:
                wins[i] += 1
                losses[j] += 1
            elif verdict < 0:
                wins[j] += 1
                losses[i] += 1
            else:
                ties[i] += 1
                ties[j] += 1
    return wins, losses, ties
