"""PLV's measures over a run's records: the numbers behind Table 3.1, as :class:`Summary` (the report reads it; the
PLV objective scores a proxy with it). Glue only: the measures themselves are :mod:`proxybench.usefulness`'s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from proxybench.experiments.plv.run import PLVResult, target_label
from proxybench.usefulness.plv import DataCost, PLVValue, first_reaching, plv, reference_score, settled_rung
from proxybench.usefulness.plv_curve import CurvePLV, curve_plv
from proxybench.usefulness.plv_intervals import PLVIntervals, curves_from_runs, mean_band, plv_bootstrap

__all__ = ["CurvePoint", "ProxyRow", "Summary", "summarize", "zero_shot_by_seed"]


@dataclass(frozen=True)
class CurvePoint:
    """One rung of an arm's learning curve: samples (``n``; its ``cost`` in target samples, off- and on-policy),
    the mean score over seeds with its 95 % bootstrap band, and the per-seed scores."""

    n: float
    cost: float
    off_policy: float
    on_policy: float
    mean: float
    low: float
    high: float
    seeds: int
    scores: list[float]


@dataclass(frozen=True)
class ProxyRow:
    """A proxy's line of Table 3.1: its zero-shot score, the target samples it needs and its PLV, from the fitted
    curves (``needed``, ``plv``, ``reduction``, each with ``_label`` and ``_ci``) and by the ladder rule
    (``ladder_*``); None where a rule has no number (not reached, or no interval without seeds)."""

    proxy: str
    spec: Any
    zero_shot: float
    zero_shot_low: float
    zero_shot_high: float
    zero_shot_seeds: int
    zero_shot_scores: list[float]
    in_proxy: float
    ladder_needed: float | None
    ladder_needed_label: str
    first_reached: float | None
    first_reached_label: str
    tried_up_to: float
    ladder_plv: float | None
    ladder_plv_label: str
    ladder_reduction: float | None
    ladder_reduction_label: str
    ladder_status: str
    needed: float | None
    needed_label: str
    plv: float | None
    plv_label: str
    reduction: float | None
    reduction_label: str
    status: str
    ladder_needed_ci: str | None = None
    ladder_plv_ci: str | None = None
    ladder_reduction_ci: str | None = None
    ladder_reached_share: float | None = None
    ladder_plv_low: float | None = None
    ladder_plv_high: float | None = None
    needed_ci: str | None = None
    plv_ci: str | None = None
    plv_low: float | None = None
    plv_high: float | None = None
    reduction_ci: str | None = None
    reached_share: float | None = None
    lack_of_fit_p: float | None = None

    def band(self, ladder: bool = False) -> tuple[float | None, float | None, float | None]:
        """(low, high, estimate) of PLV: the fitted curves', or the ladder rule's."""
        if ladder:
            return self.ladder_plv_low, self.ladder_plv_high, self.ladder_plv
        return self.plv_low, self.plv_high, self.plv


@dataclass
class Summary:
    """The numbers behind Table 3.1: curves per arm, the reference score, samples needed and PLV per proxy.

    ``curves[arm]``: per rung the mean over seeds, its 95 % bootstrap band (``low``, ``high``) and the per-seed
    scores. ``fitted``: the fitted curves, P, samples needed and PLV with their intervals (the primary numbers:
    ``reference``, ``target_cost`` and the rows' ``needed`` / ``plv`` / ``reduction``); ``intervals`` and
    ``target_needed``: the ladder rule's (rows: ``ladder_*``).
    """

    curves: dict[str, list[CurvePoint]]
    converged: float
    converged_ok: bool
    reference: float
    target_needed: DataCost | None
    rows: list[ProxyRow]
    intervals: PLVIntervals | None = None
    target_first: DataCost | None = None
    fitted: CurvePLV | None = None
    target_cost: float | None = None  # fitted |D_target|
    ladder_reference: float = float("nan")
    target_label: str = "reality model, simulated"


def _curves(res: PLVResult) -> dict[str, list[CurvePoint]]:
    out: dict[str, list[CurvePoint]] = {}
    for arm in dict.fromkeys(r["arm"] for r in res.runs):
        rows = [r for r in res.runs if r["arm"] == arm]
        curve = []
        for n in sorted({r["n"] for r in rows}):
            at = sorted((r for r in rows if r["n"] == n), key=lambda r: r["seed"])
            m, lo, hi = mean_band(np.array([r["score"] for r in at]), replicates=res.config.replicates)
            curve.append(CurvePoint(n, at[0]["cost"], at[0]["off_policy"], at[0]["on_policy"], m, lo, hi, len(at),
                                    [r["score"] for r in at]))
        out[arm] = curve
    return out


def _split_at(curve: list[CurvePoint], cost: float | None) -> DataCost | None:
    if cost is None:
        return None
    if cost == 0:
        return DataCost(0)
    c = next(c for c in curve if c.cost == cost)
    return DataCost(c.off_policy, c.on_policy)


def zero_shot_by_seed(rec: dict[str, Any]) -> dict[int, float]:
    """Seed → zero-shot score of a proxy's pre-trained networks (one network, seed 0, in old records)."""
    by = rec.get("zero_shot_by_seed")
    return {int(k): float(v) for k, v in by.items()} if by else {0: float(rec["zero_shot"])}


def _label(v: float | None, fmt: str = "{:,.0f}") -> str:
    return "not reached" if v is None else fmt.format(v)


def summarize(res: PLVResult) -> Summary:
    """Reference score, |D_target|, and per proxy: zero-shot score, |D_proxy→target|, PLV, reduction, intervals.

    Primary: fitted curves (a continuous crossing of P; :func:`~proxybench.usefulness.plv_curve.curve_plv`).
    Beside them the ladder rule (the first rung from which the mean reaches P and stays, :func:`settled_rung`)
    and the first rung that reached P (the oldest rule). Intervals: bootstrap over seeds.
    """
    cfg = res.config
    curves = _curves(res)
    target = curves.get("target-only", [])
    converged = target[-1].mean if target else float("nan")
    ladder_ref = reference_score(converged, cfg.tolerance)
    ok = len(target) >= 2 and abs(target[-1].mean - target[-2].mean) <= cfg.tolerance * abs(converged)
    t_costs, t_means = [c.cost for c in target], [c.mean for c in target]
    d_target = _split_at(target, settled_rung(t_costs, t_means, ladder_ref, cfg.confirm, through_end=True))
    t_first = _split_at(target, first_reaching(t_costs, t_means, ladder_ref))
    ivs = fitted = None
    if target:
        t_curve = curves_from_runs(res.runs, "target-only", cfg.ladder)
        p_curves = {name: curves_from_runs(res.runs, name, cfg.ladder, zero_shot_by_seed(rec))
                    for name, rec in res.proxies.items()}
        ivs = plv_bootstrap(t_curve, p_curves, cfg.tolerance, cfg.confirm, cfg.replicates)
        fitted = curve_plv(t_curve, p_curves, cfg.tolerance, replicates=cfg.replicates, n0=float(cfg.ladder[0]))
    reference = fitted.reference.estimate if fitted is not None else ladder_ref
    t_cost = fitted.target_needed.estimate if fitted is not None else None
    rows = []
    for name, rec in res.proxies.items():
        curve = curves.get(name, [])
        zs = zero_shot_by_seed(rec)
        ns = [0.0, *(c.cost for c in curve)]
        means = [float(np.mean(list(zs.values()))), *(c.mean for c in curve)]
        tried_end = any(c.n == cfg.ladder[-1] for c in curve)
        need = _split_at(curve, settled_rung(ns, means, ladder_ref, cfg.confirm, through_end=tried_end))
        first = _split_at(curve, first_reaching(ns, means, ladder_ref))
        value: PLVValue = plv(d_target, need, cfg.eta_on, cfg.eta_off)
        cost = None if need is None else need.weighted(cfg.eta_on, cfg.eta_off)
        first_cost = None if first is None else first.weighted(cfg.eta_on, cfg.eta_off)
        zm, zlo, zhi = mean_band(np.array(list(zs.values())), replicates=cfg.replicates)
        row = {"proxy": name, "spec": rec["spec"], "zero_shot": zm, "zero_shot_low": zlo, "zero_shot_high": zhi,
               "zero_shot_seeds": len(zs), "zero_shot_scores": list(zs.values()), "in_proxy": rec["in_proxy"],
               "ladder_needed": cost, "ladder_needed_label": _label(cost), "first_reached": first_cost,
               "first_reached_label": _label(first_cost), "tried_up_to": max((c.cost for c in curve), default=0),
               "ladder_plv": value.value, "ladder_plv_label": value.label, "ladder_reduction": value.reduction,
               "ladder_reduction_label": value.reduction_label, "ladder_status": value.status}
        if ivs is not None:
            row |= {"ladder_needed_ci": ivs.needed[name].label(), "ladder_plv_ci": ivs.plv[name].label(),
                    "ladder_reduction_ci": ivs.reduction[name].label("{:.0f} %", scale=100.0),
                    "ladder_reached_share": ivs.reached[name], "ladder_plv_low": ivs.plv[name].low,
                    "ladder_plv_high": ivs.plv[name].high}
        row |= _fitted_row(fitted, name, t_cost, value.status if fitted is None else None)
        rows.append(ProxyRow(**row))
    return Summary(curves, converged, ok, reference, d_target, rows, ivs, t_first, fitted, t_cost, ladder_ref,
                   target_label(cfg))


def _fitted_row(fitted: CurvePLV | None, name: str, t_cost: float | None, fallback: str | None) -> dict[str, Any]:
    """The row's primary columns from the fitted curves."""
    if fitted is None:
        return {"needed": None, "needed_label": "–", "plv": None, "plv_label": fallback or "–", "reduction": None,
                "reduction_label": "–", "status": fallback or "target not reached"}
    need, pv, red = fitted.needed[name], fitted.plv[name], fitted.reduction[name]
    status = "target not reached" if t_cost is None else ("ok" if pv.estimate is not None else "not reached")
    return {"needed": need.estimate, "needed_label": _label(need.estimate), "needed_ci": need.label(),
            "plv": pv.estimate, "plv_label": _label(pv.estimate) if status != "target not reached" else status,
            "plv_ci": pv.label(), "plv_low": pv.low, "plv_high": pv.high, "reduction": red.estimate,
            "reduction_label": "–" if red.estimate is None else f"{100 * red.estimate:.0f} %",
            "reduction_ci": red.label("{:.0f} %", scale=100.0), "reached_share": fitted.reached[name],
            "status": status, "lack_of_fit_p": fitted.lack_of_fit.get(name)}
