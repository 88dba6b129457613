"""Per-agent statistics over episodes, with percentile-bootstrap confidence intervals.

Input is the long table every evaluation produces — one row per (agent, domain, episode, metric) with
its ``value`` — and output is one row per (agent, domain) with columns ``<metric>_<stat>`` (the names
AIDO's scoring uses, e.g. ``driven_lanedir_consec_median``), so a benchmark's scoring criteria can
refer to them directly.

NaN values (a metric an episode could not produce) are left out of the statistics; ``<metric>_n``
says how many episodes were used.

>>> rows = [{"agent": "a", "domain": "sim", "episode": e, "metric": "distance", "value": v}
...         for e, v in enumerate([1.0, 2.0, 6.0])]
>>> out = aggregate(rows, n_resamples=200)
>>> out.loc[0, ["distance_mean", "distance_median", "distance_min", "distance_max"]].tolist()
[3.0, 2.0, 1.0, 6.0]
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

__all__ = ["COLUMNS", "STATS", "aggregate", "bootstrap_ci", "scores_by_agent"]

#: the columns of the long input table
COLUMNS = ("agent", "domain", "episode", "metric", "value")

#: statistics over episodes, by the suffix they give column names
STATS: dict[str, Callable[..., Any]] = {"mean": np.mean, "median": np.median, "min": np.min, "max": np.max}


def _generator(rng: np.random.Generator | int | None) -> np.random.Generator:
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def _stat_rows(stat: Callable[..., Any], samples: np.ndarray) -> np.ndarray:
    """``stat`` of every row of ``samples``; vectorised when ``stat`` takes ``axis``, else row by row."""
    try:
        out = np.asarray(stat(samples, axis=1), dtype=float)
        if out.shape == (samples.shape[0],):
            return out
    except TypeError:
        pass
    return np.array([float(stat(row)) for row in samples])


def bootstrap_ci(
    values: Sequence[float] | np.ndarray,
    stat: Callable[..., Any] = np.median,
    level: float = 0.95,
    n: int = 2000,
    rng: np.random.Generator | int | None = 0,
) -> tuple[float, float]:
    """Percentile-bootstrap interval (lo, hi) of ``stat`` over ``values``.

    ``n`` resamples with replacement of the same size; the interval is the (1−level)/2 and (1+level)/2
    quantiles of their statistics. Episodes are few and metric distributions skewed (a crash cuts
    survival short), so the percentile bootstrap is used rather than a normal approximation. The
    result is fixed by ``rng`` (a seed or a Generator). NaNs are dropped; no values give (nan, nan).
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    x = np.asarray(values, dtype=float).ravel()
    x = x[~np.isnan(x)]
    if x.size == 0:
        return (float("nan"), float("nan"))
    idx = _generator(rng).integers(0, x.size, size=(n, x.size))
    boot = _stat_rows(stat, x[idx])
    lo, hi = np.quantile(boot, [(1.0 - level) / 2.0, (1.0 + level) / 2.0])
    return (float(lo), float(hi))


def _as_frame(table: pd.DataFrame | Iterable[Mapping[str, Any]]) -> pd.DataFrame:
    """The long table as a DataFrame with the required columns, numeric values and no duplicate cells."""
    df = table.copy() if isinstance(table, pd.DataFrame) else pd.DataFrame(list(table))
    missing = [c for c in COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"aggregate: missing column(s) {', '.join(missing)}; need {', '.join(COLUMNS)}")
    try:
        df["value"] = pd.to_numeric(df["value"]).astype(float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"aggregate: column 'value' must be numeric ({exc})") from exc
    dup = df.duplicated(["agent", "domain", "episode", "metric"])
    if dup.any():
        row = df[dup].iloc[0]
        raise ValueError(f"aggregate: agent {row['agent']!r}, domain {row['domain']!r}, episode {row['episode']!r} "
                         f"has more than one value of {row['metric']!r} (counted twice?)")
    return df


def _cell_rng(seed: int, *names: Any) -> np.random.Generator:
    """A generator fixed by the seed and the cell's names, so a cell's interval does not depend on which
    other agents, domains or metrics are in the table."""
    key = tuple(zlib.crc32(str(n).encode()) for n in names)
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def _cell(values: np.ndarray, metric: str, stats: Sequence[str], ci: Sequence[str], level: float,
          n_resamples: int, rng: np.random.Generator) -> dict[str, float]:
    x = values[~np.isnan(values)]
    out: dict[str, float] = {f"{metric}_n": int(x.size)}
    for s in stats:
        out[f"{metric}_{s}"] = float(STATS[s](x)) if x.size else float("nan")
    for s in ci:
        out[f"{metric}_{s}_lo"], out[f"{metric}_{s}_hi"] = bootstrap_ci(x, STATS[s], level, n_resamples, rng)
    return out


def aggregate(
    table: pd.DataFrame | Iterable[Mapping[str, Any]],
    *,
    stats: Sequence[str] = ("mean", "median", "min", "max"),
    ci: Sequence[str] = ("mean", "median"),
    level: float = 0.95,
    n_resamples: int = 2000,
    seed: int = 0,
) -> pd.DataFrame:
    """One row per (agent, domain): ``episodes`` and, per metric, ``<metric>_<stat>`` for ``stats``,
    ``<metric>_<stat>_lo`` / ``_hi`` bootstrap intervals for the stats in ``ci``, and ``<metric>_n``.

    Rows are sorted by agent then domain; metric columns follow the metrics' order of first appearance.
    """
    unknown = [s for s in (*stats, *ci) if s not in STATS]
    if unknown:
        raise ValueError(f"aggregate: unknown statistic(s) {', '.join(unknown)} (one of {', '.join(STATS)})")
    df = _as_frame(table)
    metrics = list(dict.fromkeys(df["metric"]))
    rows = []
    for (agent, domain), group in df.groupby(["agent", "domain"], sort=True):
        row: dict[str, Any] = {"agent": agent, "domain": domain, "episodes": int(group["episode"].nunique())}
        by_metric = dict(tuple(group.groupby("metric", sort=False)["value"]))
        for m in metrics:
            values = by_metric[m].to_numpy() if m in by_metric else np.array([])
            row.update(_cell(values, m, stats, ci, level, n_resamples, _cell_rng(seed, agent, domain, m)))
        rows.append(row)
    return pd.DataFrame(rows)


def scores_by_agent(aggregated: pd.DataFrame, domain: Any | None = None) -> dict[Any, dict[str, float]]:
    """``{agent: {column: value}}`` from :func:`aggregate`'s output for one domain, the input of
    :func:`proxybench.tasks.scoring.leaderboard`. ``domain`` may be omitted when there is only one."""
    domains = list(dict.fromkeys(aggregated["domain"]))
    if domain is None:
        if len(domains) != 1:
            raise ValueError(f"scores_by_agent: the table has domains {domains}; say which one")
        domain = domains[0]
    sub = aggregated[aggregated["domain"] == domain]
    if sub.empty:
        raise ValueError(f"scores_by_agent: no rows for domain {domain!r} (have {domains})")
    skip = {"agent", "domain"}
    return {r["agent"]: {k: float(v) for k, v in r.items() if k not in skip} for r in sub.to_dict("records")}
