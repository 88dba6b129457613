"""Scores as people read them: each metric with its label, unit, direction and a precision that suits
its unit; the benchmark's ranking criteria first, in order, with their tolerance; the statistic with its
interval, the spread over episodes and the episode count; a missing value as "—" that says why.

A result's scores are the columns :func:`proxybench.tasks.aggregate.aggregate` writes (``<metric>_<stat>``,
``<metric>_<stat>_lo`` / ``_hi`` for the 95 % percentile-bootstrap interval over episodes, ``<metric>_n``,
``episodes``); the labels and units come from the metrics' own definitions
(:data:`proxybench.tasks.metrics.METRICS`), so a page never restates them. Only the pages use this
module: the JSON API returns the columns as they are stored.

>>> rows = score_rows({"survival_time_median": 38.251, "survival_time_median_lo": 32.6,
...                    "survival_time_median_hi": 60.0, "survival_time_min": 32.592, "survival_time_max": 60.0,
...                    "survival_time_n": 5, "deviation_heading_median": 6.506},
...                   [{"metric": "survival_time_median", "higher_is_better": True, "tolerance": 2.0}])
>>> r = rows[0]
>>> r.title, r.direction, r.criterion, r.stat, str(r.value), r.interval, r.spread, r.n, r.tolerance
('Survival time [s]', '↑', 1, 'median', '38.3', '[32.6, 60.0]', '32.6 … 60.0', 5, '± 2')
>>> rows[1].criterion, str(rows[1].value), rows[1].decimals
(None, '6.51', 2)
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from markupsafe import Markup, escape

from proxybench.tasks.aggregate import STATS
from proxybench.tasks.metrics import METRICS, Metric

__all__ = ["BT_DECIMALS", "CI_LEVEL", "EPISODE_NAN", "NOT_COMPUTED", "NOT_REPORTED", "BoardColumn", "Column",
           "ScoreRow", "board_cells", "board_columns", "bt_cell", "column_of", "criterion_column", "episode_counts",
           "fmt_value", "metric_column", "score_rows", "value_cell"]

CI_LEVEL = "95 %"  # aggregate()'s default level, which evaluators use
BT_DECIMALS = 2  # Bradley–Terry log-strengths: a difference of 0.01 is a 0.25 % change in the odds of winning
#: why a value is missing, by where it is missing
NOT_COMPUTED = "not computed: no episode gave a finite value (NaN); it ranks worst"
NOT_REPORTED = "not in this result (the evaluator did not report it)"
EPISODE_NAN = "no value in this episode (NaN): left out of the statistics over episodes"
_SUFFIXES = ("n", *STATS, *(f"{s}_{end}" for s in STATS for end in ("lo", "hi")))


@dataclass(frozen=True)
class Column:
    """How one metric (or an unknown score column) is shown: its label, unit, direction and decimals."""

    name: str  # the metric's name (or the raw column for an unknown one)
    label: str
    unit: str
    direction: str  # "↑", "↓", or "" when unknown
    description: str
    decimals: int
    missing: str = ""  # what a NaN of this metric means, when it has a meaning of its own

    @property
    def title(self) -> str:
        return f"{self.label} [{self.unit}]" if self.unit else self.label

    @property
    def better(self) -> str:
        return {"↑": "higher is better", "↓": "lower is better"}.get(self.direction, "")

    @property
    def tooltip(self) -> str:
        """What a header's ``title`` says: the description, direction and the stored name."""
        parts = [self.description, self.better, f"column {self.name}"]
        return "; ".join(p for p in parts if p)


def metric_column(name: str) -> Column:
    """The :class:`Column` of a metric name; an unknown name is shown as it is, 3 decimals, no unit."""
    m: Metric | None = METRICS.get(name)
    if m is None:
        return Column(name, name, "", "", "", 3)
    return Column(m.name, m.display_name, m.unit, m.direction, m.description, m.decimals, m.missing)


def column_of(key: str) -> tuple[str, str] | None:
    """(metric, suffix) of an aggregated column (``survival_time_median_lo`` → (survival_time, median_lo)),
    or None when it is no metric's. The longest metric name that fits wins."""
    for base in sorted(METRICS, key=len, reverse=True):
        if key.startswith(base + "_") and key[len(base) + 1:] in _SUFFIXES:
            return base, key[len(base) + 1:]
    return None


def _number(v: Any) -> float | None:
    """A finite float, or None (missing, NaN, ±inf, or not a number)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    x = float(v)
    return x if math.isfinite(x) else None


def _tolerance_decimals(tolerance: float) -> int:
    """Decimals that show a difference of ``tolerance``: 0.62 → 1, 0.01 → 2, 0.005 → 3, 2 → 0."""
    if tolerance <= 0 or not math.isfinite(tolerance):
        return 0
    return max(0, -math.floor(math.log10(tolerance)))


def fmt_value(v: Any, decimals: int, unit: str = "") -> str:
    """A finite number with ``decimals`` (thousands separated); a count shows whole numbers as such.

    >>> fmt_value(12345.678, 2), fmt_value(2.0, 0, "count"), fmt_value(0.4, 0, "count"), fmt_value(None, 2)
    ('12,345.68', '2', '0.4', '—')
    """
    x = _number(v)
    if x is None:
        return "—"
    if unit == "count" and x != int(x):
        decimals = max(decimals, 1)
    text = f"{x:,.{decimals}f}"
    return "0" + text[2:] if text.startswith("-0") and float(text.replace(",", "")) == 0 else text


def value_cell(v: Any, col: Column, why: str = NOT_COMPUTED, decimals: int | None = None) -> Markup:
    """A value for a table cell; a missing one (None, NaN, ±inf) is "—" whose ``title`` says why: ``why``,
    or, for a metric whose NaN has a meaning of its own, that meaning (unless the value was not reported)."""
    x = _number(v)
    if x is not None:
        return Markup(escape(fmt_value(x, col.decimals if decimals is None else decimals, col.unit)))
    reason = f"NaN: {col.missing}" if col.missing and why != NOT_REPORTED else why
    return Markup(f'<span class="missing" title="{escape(reason)}">—</span>')


@dataclass(frozen=True)
class ScoreRow:
    """One metric of a result, as the scores table shows it."""

    column: Column
    criterion: int | None  # its place among the ranking criteria (1 = first), None: not ranked by
    tolerance: str | None  # "± 0.62" (criteria only)
    stat: str  # the statistic over episodes shown: median, mean, ...
    key: str  # the stored column it is read from
    value: Markup
    interval: str | None  # "[lo, hi]" (95 % bootstrap over episodes), None when the result has none
    spread: str | None  # "min … max" over episodes
    n: int | None  # episodes with a value
    decimals: int

    @property
    def title(self) -> str:
        return self.column.title

    @property
    def direction(self) -> str:
        return self.column.direction


def _criteria(criteria: Iterable[Any]) -> list[dict[str, Any]]:
    """Criteria as dicts (the board's form), from dicts or :class:`~proxybench.tasks.scoring.Criterion`."""
    out = []
    for c in criteria:
        if isinstance(c, Mapping):
            out.append({"metric": c["metric"], "higher_is_better": c.get("higher_is_better", True),
                        "tolerance": float(c.get("tolerance", 0.0))})
        else:
            out.append({"metric": c.metric, "higher_is_better": c.higher_is_better, "tolerance": c.tolerance})
    return out


def criterion_column(criterion: Mapping[str, Any]) -> tuple[Column, str, int]:
    """(column, statistic, decimals) of a criterion: its metric's column with the criterion's direction, and
    enough decimals to show a difference of its tolerance."""
    parsed = column_of(criterion["metric"])
    base, stat = parsed if parsed is not None and parsed[1] in STATS else (criterion["metric"], "")
    col = metric_column(base)
    col = Column(col.name, col.label, col.unit, "↑" if criterion.get("higher_is_better", True) else "↓",
                 col.description, col.decimals, col.missing)
    return col, stat, max(col.decimals, _tolerance_decimals(float(criterion.get("tolerance", 0.0))))


def _row(scores: Mapping[str, Any], col: Column, stat: str, key: str, decimals: int, *,
         criterion: int | None = None, tolerance: float | None = None, n_fallback: int | None = None) -> ScoreRow:
    lo, hi = _number(scores.get(f"{key}_lo")), _number(scores.get(f"{key}_hi"))
    mn, mx = _number(scores.get(f"{col.name}_min")), _number(scores.get(f"{col.name}_max"))
    n = _number(scores.get(f"{col.name}_n"))
    why = NOT_REPORTED if key not in scores else NOT_COMPUTED
    return ScoreRow(
        col, criterion, None if tolerance is None else f"± {tolerance:g}", stat, key,
        value_cell(scores.get(key), col, why, decimals),
        f"[{fmt_value(lo, decimals, col.unit)}, {fmt_value(hi, decimals, col.unit)}]" if lo is not None
        and hi is not None else None,
        f"{fmt_value(mn, decimals, col.unit)} … {fmt_value(mx, decimals, col.unit)}" if mn is not None
        and mx is not None else None,
        int(n) if n is not None else n_fallback, decimals)


def score_rows(scores: Mapping[str, Any] | None, criteria: Iterable[Any] = (),
               episode_counts: Mapping[str, int] | None = None) -> list[ScoreRow]:
    """The rows of a result's scores table: the ranking criteria first, in their order, then every other
    metric the result has (in its order), each with the statistic the first criterion uses (else the
    median, else the mean). ``episode_counts``: episodes with a value per metric, from the per-episode
    report, for results whose scores lack ``<metric>_n``. Columns of no known metric come last, as they are.
    """
    scores = dict(scores or {})
    crit = _criteria(criteria)
    rows: list[ScoreRow] = []
    done: set[str] = set()
    counts = episode_counts or {}
    for k, c in enumerate(crit):
        col, stat, decimals = criterion_column(c)
        rows.append(_row(scores, col, stat, c["metric"], decimals, criterion=k + 1, tolerance=c["tolerance"],
                         n_fallback=counts.get(col.name)))
        done.add(col.name)
    default_stat = next((stat for c in crit for stat in [criterion_column(c)[1]] if stat), "")
    others: list[str] = []
    unknown: list[str] = []
    for key in scores:
        parsed = column_of(key)
        if parsed is None:
            if key != "episodes":
                unknown.append(key)
        elif parsed[0] not in done and parsed[0] not in others:
            others.append(parsed[0])
    for base in others:
        col = metric_column(base)
        stat = next((s for s in (default_stat, "median", "mean", *STATS) if s and f"{base}_{s}" in scores), "median")
        rows.append(_row(scores, col, stat, f"{base}_{stat}", col.decimals, n_fallback=counts.get(base)))
    for key in unknown:
        col = metric_column(key)
        rows.append(ScoreRow(col, None, None, "", key, value_cell(scores[key], col), None, None, None, col.decimals))
    return rows


def episode_counts(metrics: Sequence[str], rows: Sequence[Mapping[str, Any]]) -> dict[str, int]:
    """Per metric, how many per-episode rows have a finite value (the ``n`` of the statistics)."""
    return {m: sum(_number(r["values"].get(m)) is not None for r in rows) for m in metrics}


@dataclass(frozen=True)
class BoardColumn:
    """A ranking criterion as a leaderboard column: its metric's column, statistic, decimals and tolerance."""

    key: str
    column: Column
    stat: str
    decimals: int
    tolerance: str

    @property
    def tooltip(self) -> str:
        return (f"{self.column.description}; {self.stat} over episodes; {self.column.better}; differences up to "
                f"{self.tolerance.removeprefix('± ')} {self.column.unit} are ties; column {self.key}")


def board_columns(criteria: Iterable[Any]) -> list[BoardColumn]:
    """The leaderboard's criterion columns, in ranking order."""
    out = []
    for c in _criteria(criteria):
        col, stat, decimals = criterion_column(c)
        out.append(BoardColumn(c["metric"], col, stat, decimals, f"± {c['tolerance']:g}"))
    return out


def board_cells(scores: Mapping[str, Any], columns: Sequence[BoardColumn],
                details: Mapping[str, Any] | None) -> list[dict[str, Any]]:
    """One leaderboard row's cells: the ranked value (from the board), its interval and episode count (from
    the result's stored scores, ``details``; None when they are not at hand)."""
    details = details or {}
    cells = []
    for bc in columns:
        v = scores.get(bc.key)
        lo, hi = _number(details.get(f"{bc.key}_lo")), _number(details.get(f"{bc.key}_hi"))
        n = _number(details.get(f"{bc.column.name}_n"))
        why = NOT_COMPUTED if bc.key in scores else NOT_REPORTED
        cells.append({"value": value_cell(v, bc.column, why, bc.decimals),
                      "interval": f"[{fmt_value(lo, bc.decimals, bc.column.unit)}, "
                                  f"{fmt_value(hi, bc.decimals, bc.column.unit)}]"
                      if lo is not None and hi is not None else None,
                      "n": None if n is None else int(n)})
    return cells


def bt_cell(bt: Mapping[str, Any] | None, leader: bool = False, provisional: bool = False) -> dict[str, Any] | None:
    """A row's Bradley–Terry cell: the score and its interval as text, whether it could be first, and whether it
    carries the "provisional" mark (the leader's, when its interval overlaps the runner-up's); None without a score.

    >>> bt_cell({"score": 1.276, "lo": 0.873, "hi": 1.827, "contender": True}, leader=True, provisional=True)
    {'value': '1.28', 'interval': '[0.87, 1.83]', 'contender': True, 'provisional': True}
    """
    if not bt or _number(bt.get("score")) is None:
        return None
    lo, hi = _number(bt.get("lo")), _number(bt.get("hi"))
    return {"value": fmt_value(bt["score"], BT_DECIMALS),
            "interval": f"[{fmt_value(lo, BT_DECIMALS)}, {fmt_value(hi, BT_DECIMALS)}]"
            if lo is not None and hi is not None else None,
            "contender": bool(bt.get("contender")), "provisional": leader and provisional}
