"""The PLV objective: how many target samples one proxy saves, as a function an optimiser can call.

Thesis §3.6: for teaching, the proxy to find is p(θ)* = argmax_{p(θ)} PLV(θ) (eq. 3.6.2) — one
instance θ, or a distribution of instances (domain randomisation). :class:`PLVObjective` fixes
everything but the proxy: the target-only learning curve (and with it the reference P and |D_target|)
is computed once and cached; each call pre-trains on the proxy it is given (one network per seed),
fine-tunes up the ladder until the score has settled above P, and returns the PLV of the fitted curves with its
bootstrap interval over seeds. Every unit of work is cached under ``out``, so a repeated θ costs nothing.

PLV comes from fitted learning curves (a continuous crossing of P, :mod:`proxybench.usefulness.plv_curve`), and
a proxy may never reach P; an optimiser still needs a number, so :attr:`PLVTrial.value` is the PLV, and for
"not reached" |D_target| − 2 · (largest rung): as if the proxy had needed twice the largest data set tried,
worse than every proxy that reaches P.
The PLV itself stays "not reached" in :attr:`PLVTrial.plv`.

>>> family_domain({"trim": {"uniform": [-0.1, 0.1]}}, 40, 30).kind
'family'
>>> instance_domain({"camera_pitch": 17.25}, 40, 30).name
'proxy:camera_pitch=17.25'
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from proxybench.experiments.plv.run import PLVConfig, PLVResult, Progress, Workspace, proxy_arm, target_arm
from proxybench.learning.domains import Domain, proxy_domain, randomized_domain
from proxybench.usefulness.plv import PLVValue
from proxybench.usefulness.plv_intervals import Interval

__all__ = [
    "PLVObjective",
    "PLVSearch",
    "PLVSearchResult",
    "PLVTrial",
    "SearchTrial",
    "family_domain",
    "instance_domain",
    "objective_value",
    "optimize_plv",
]


def instance_domain(values: Mapping[str, Any], width: int, height: int) -> Domain:
    """The proxy instance θ: the calibrated simulator with ``values`` changed (named by them, for the cache)."""
    items = sorted(values.items())
    name = "proxy:" + ",".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in items)
    return proxy_domain(width, height, name=name, **dict(values))


def family_domain(dists: Mapping[str, Any], width: int, height: int) -> Domain:
    """A family p(θ): a ``ParamSpace`` mapping around the calibrated simulator, named by a hash of it."""
    key = hashlib.sha256(json.dumps(dists, sort_keys=True, default=str).encode()).hexdigest()[:10]
    return randomized_domain(width, height, dict(dists), name=f"family-{key}")


@dataclass
class PLVTrial:
    """One proxy's result: the PLV (or "not reached"), its interval, and the number an optimiser maximises."""

    proxy: str
    domain: dict[str, Any]
    value: float
    plv: PLVValue
    interval: Interval
    reached_share: float
    needed: float | None
    zero_shot: float
    runs: list[dict[str, Any]] = field(repr=False, default_factory=list)

    def attrs(self) -> dict[str, Any]:
        """JSON-able summary, e.g. for an Optuna trial's user attributes."""
        return {"proxy": self.proxy, "plv": self.plv.value, "plv_label": self.plv.label, "plv_status": self.plv.status,
                "plv_ci": self.interval.label(), "plv_low": self.interval.low, "plv_high": self.interval.high,
                "reduction": self.plv.reduction, "reached_share": self.reached_share, "needed": self.needed,
                "zero_shot": self.zero_shot, "target_cost": self.plv.target_cost}


def objective_value(value: PLVValue, largest_rung: float) -> float:
    """The number to maximise: the PLV, or |D_target| − 2 · largest rung when the proxy never settled above P.

    >>> objective_value(PLVValue(750.0, 0.75, "ok", 1000.0, 250.0), 2000.0)
    750.0
    >>> objective_value(PLVValue(None, None, "not reached", 1000.0, None), 2000.0)
    -3000.0
    """
    if value.value is not None:
        return float(value.value)
    return (value.target_cost or 0.0) - 2.0 * largest_rung


class PLVObjective:
    """PLV(proxy) against one target-only curve, computed once: ``objective(proxy) -> PLVTrial``.

    ``proxy``: a domain spec (``"proxy:camera_pitch=17"``, ``"randomized"``, a family file), a ``Domain``,
    or a mapping: parameter values (an instance θ) or, with ``family=True``, a ``ParamSpace`` mapping.
    """

    def __init__(self, cfg: PLVConfig, out: str | Path, progress: Progress | None = None):
        self.cfg = cfg
        self.work = Workspace(cfg, out, progress)
        self._target: tuple[list[dict[str, Any]], float, float] | None = None

    def target(self) -> tuple[list[dict[str, Any]], float, float]:
        """The target-only runs, the expert's score and the reference P (computed on first use, then cached)."""
        if self._target is None:
            self._target = target_arm(self.work)
        return self._target

    def domain(self, proxy: str | Domain | Mapping[str, Any], family: bool = False) -> tuple[str, str | Domain]:
        if isinstance(proxy, str):
            return proxy, proxy
        if isinstance(proxy, Domain):
            return proxy.name, proxy
        d = (family_domain if family else instance_domain)(proxy, self.cfg.width, self.cfg.height)
        return d.name, d

    def __call__(self, proxy: str | Domain | Mapping[str, Any], family: bool = False) -> PLVTrial:
        from proxybench.experiments.plv.measures import summarize

        runs, expert, reference = self.target()
        name, spec = self.domain(proxy, family)
        record, arm = proxy_arm(self.work, name, spec, reference)
        s = summarize(PLVResult(self.cfg, [*runs, *arm], {name: record}, expert))
        row, fitted = s.rows[0], s.fitted
        value = PLVValue(row.plv, row.reduction, row.status, s.target_cost, row.needed)
        score = objective_value(value, max(float(r["cost"]) for r in runs))
        return PLVTrial(name, record["domain"], score, value, fitted.plv[name], fitted.reached[name], row.needed,
                        row.zero_shot, arm)

    def close(self) -> None:
        """Stop a robot target's node (if one was started)."""
        self.work.close()


@dataclass(frozen=True)
class PLVSearch:
    """What to search: ``space`` maps a parameter to its range (lo, hi); instances θ, or families p(θ).

    With ``family=True`` each trial proposes, per parameter, a centre in [lo, hi] and a half-width in
    [0, (hi − lo) / 2]: the proxy is the uniform family over [centre ± half-width] ∩ [lo, hi], drawn
    per episode (eq. 3.6.2's p(θ)). ``fixed``: values every proposal has besides (not searched).
    """

    space: dict[str, tuple[float, float]]
    trials: int = 12
    family: bool = False
    sampler: str = "tpe"  # tpe | random
    seed: int = 0
    storage: str | None = None  # an Optuna storage URL or a SQLite file, so a search resumes
    study_name: str = "plv"
    fixed: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.space:
            raise ValueError("the PLV search needs at least one parameter range")
        for name, (lo, hi) in self.space.items():
            if not lo < hi:
                raise ValueError(f"{name}: the range must have lo < hi, got ({lo}, {hi})")
        if self.trials < 1:
            raise ValueError(f"trials must be >= 1, got {self.trials}")
        if self.sampler not in ("tpe", "random"):
            raise ValueError(f"sampler must be tpe or random, got {self.sampler!r}")


@dataclass(frozen=True)
class SearchTrial:
    """One finished trial of a PLV search: the proxy it proposed and what its :class:`PLVTrial` gave (as the
    Optuna trial's user attributes keep it, so a resumed search reads the same)."""

    number: int
    value: float
    proposal: dict[str, Any]  # θ by name, or with a family {"uniform": [lo, hi]} per parameter
    proxy: str
    plv: float | None
    plv_label: str
    plv_status: str
    plv_ci: str
    plv_low: float | None
    plv_high: float | None
    reduction: float | None
    reached_share: float
    needed: float | None
    zero_shot: float
    target_cost: float | None

    @classmethod
    def of(cls, trial: Any) -> SearchTrial:
        """From an Optuna ``FrozenTrial`` whose user attributes :func:`optimize_plv` set."""
        a = trial.user_attrs
        named = {f.name for f in fields(cls)} - {"number", "value", "proposal"}
        return cls(number=trial.number, value=float(trial.value), proposal=json.loads(a["proposal"]),
                   **{k: a.get(k) for k in named})

    def to_dict(self) -> dict[str, Any]:
        """A row of ``trials.json`` (the proposal as the JSON text the trial stored)."""
        return {**asdict(self), "proposal": json.dumps(self.proposal)}


@dataclass
class PLVSearchResult:
    """Every trial's proxy and PLV (with its interval), the best one, and whether its interval stands apart."""

    trials: list[SearchTrial]
    best: SearchTrial
    separated: bool  # the best trial's lower PLV bound is above every other trial's upper bound
    study: Any = field(repr=False, default=None)
    objective: PLVObjective | None = field(repr=False, default=None)  # its target curve: ``objective.target()``


def _propose(trial, search: PLVSearch) -> dict[str, Any]:
    if not search.family:
        return {**search.fixed, **{k: trial.suggest_float(k, lo, hi) for k, (lo, hi) in search.space.items()}}
    dists: dict[str, Any] = {k: {"choice": [v]} for k, v in search.fixed.items()}
    for k, (lo, hi) in search.space.items():
        c = trial.suggest_float(f"{k}.centre", lo, hi)
        w = trial.suggest_float(f"{k}.half_width", 0.0, (hi - lo) / 2)
        dists[k] = {"uniform": [max(lo, c - w), min(hi, c + w)]}
    return dists


def optimize_plv(search: PLVSearch, cfg: PLVConfig, out: str | Path, progress: Progress | None = None,
                 ) -> PLVSearchResult:
    """p(θ)* = argmax PLV (thesis eq. 3.6.2) with Optuna: each trial is one :class:`PLVObjective` call.

    The target-only curve is computed once; trials, their PLVs and intervals are cached under ``out``
    (a repeated θ costs nothing) and, with ``search.storage``, the study itself resumes.
    """
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    objective = PLVObjective(cfg, out, progress)
    objective.target()
    sampler = (optuna.samplers.RandomSampler(seed=search.seed) if search.sampler == "random" else
               optuna.samplers.TPESampler(seed=search.seed, n_startup_trials=min(5, search.trials)))
    storage = search.storage
    if storage and "://" not in storage:
        storage = f"sqlite:///{Path(storage).resolve()}"
    study = optuna.create_study(direction="maximize", sampler=sampler, storage=storage,
                                study_name=search.study_name, load_if_exists=True)

    def run(trial) -> float:
        proxy = _propose(trial, search)
        res = objective(proxy, family=search.family)
        for k, v in {**res.attrs(), "proposal": json.dumps(proxy)}.items():
            trial.set_user_attr(k, v)
        if progress:
            progress("search", trial.number + 1, search.trials)
        return res.value

    remaining = search.trials - len([t for t in study.trials if t.state.is_finished()])
    try:
        if remaining > 0:
            study.optimize(run, n_trials=remaining)
    finally:
        objective.close()
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    rows = [SearchTrial.of(t) for t in done]
    best = max(rows, key=lambda r: r.value)
    others = [r.plv_high for r in rows if r is not best]
    separated = bool(others) and best.plv_low is not None and all(h is None or best.plv_low > h for h in others)
    return PLVSearchResult(rows, best, separated, study, objective)
