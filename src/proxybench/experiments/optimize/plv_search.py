"""``optimize --objective plv``: the proxy that saves a learning agent the most target samples (thesis eq. 3.6.2).

The teaching counterpart of :func:`~proxybench.experiments.optimize.run.optimize_proxy`. Where PRPV compares
rankings of fixed agents, PLV trains one: a behaviour-cloning network is pre-trained on each proposed
proxy (an instance θ, or with ``search.family`` a uniform family p(θ)) and fine-tuned on target samples
until its score has settled above the reference P; PLV = |D_target| − |D_proxy→target| with a bootstrap
interval over seeds (:mod:`proxybench.experiments.plv.objective`, docs/learning.md). The search space, trials,
sampler, storage, seed and truth come from the experiment (``--config`` / the command line); the PLV
settings from its ``plv:`` section (``PLVConfig`` fields), on top of ``PLVConfig()`` or, with
``--quick``, ``PLVConfig.quick()``.

The target is the reality model: PLV needs target samples collected by the expert and evaluation
episodes *in* the target while it trains, which a recording cannot give. Needs PyTorch (the
``learning`` extra).
"""

from __future__ import annotations

import json
import textwrap
from dataclasses import dataclass, field
from importlib.util import find_spec
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.experiments.config import ConfigError, ExperimentConfig
from proxybench.experiments.plv.objective import SearchTrial
from proxybench.experiments.proxies import param_label

__all__ = ["PLV_TRIALS", "PLVOptimizeResult", "plot_plv_search", "plv_search_settings", "run_plv_search",
           "torch_available", "write_plv_search"]

#: trials of the PLV search when the experiment does not say (full, --quick): each costs a pre-training per
#: seed and a few fine-tuning runs
PLV_TRIALS = {False: 12, True: 4}
#: experiment fields that PLV does not use (it trains its own agent, on its own frames and evaluation episodes)
_NOT_USED = ("agents", "map", "episodes", "seconds", "metrics", "image_size", "sweep", "pod_seconds", "robot_nodes")


def torch_available() -> bool:
    """Whether PyTorch (the ``learning`` extra) is installed, without importing it."""
    return find_spec("torch") is not None


@dataclass
class PLVOptimizeResult:
    """The search (every trial's PLV with its interval, the best one and whether it stands apart) and its setting.

    ``truth``: the known θ of the target (the reality model's calibration, or the experiment's ``truth``),
    never seen by the search; ``ignored``: experiment fields given that PLV does not use.
    """

    search: Any  # learning.objective.PLVSearchResult
    space: dict[str, tuple[float, float]]
    family: bool
    config: Any  # learning.experiment.PLVConfig
    reference: float
    expert: float
    target_cost: float | None
    truth: dict[str, float] = field(default_factory=dict)
    ignored: list[str] = field(default_factory=list)

    @property
    def trials(self) -> list[SearchTrial]:
        return self.search.trials

    @property
    def best(self) -> SearchTrial:
        return self.search.best

    @property
    def reached(self) -> bool:
        """Whether any trial's agent settled above P (else every PLV is "not reached")."""
        return any(t.plv is not None for t in self.trials)

    def theta_label(self, trial: SearchTrial, name: str) -> str:
        v = trial.proposal[name]
        if self.family:
            lo, hi = v["uniform"]
            return f"U[{lo:.3g}, {hi:.3g}]"
        return f"{v:.3f}"

    def summary(self) -> dict[str, Any]:
        """What ``summary.json`` holds."""
        b = self.best
        return {"objective": "plv", "target": "reality model (a simulated stand-in for a real Duckiebot)",
                "family": self.family, "space": {k: list(v) for k, v in self.space.items()},
                "best": {"number": b.number, "proposal": b.proposal, "plv": b.plv, "plv_ci": b.plv_ci,
                         "plv_status": b.plv_status},
                "separated": self.search.separated, "reached": self.reached, "reference_P": self.reference,
                "expert_score": self.expert, "target_samples_needed": self.target_cost, "truth": self.truth,
                "ignored": self.ignored, "plv_config": self.config.to_dict()}


def plv_search_settings(cfg: ExperimentConfig, *, quick: bool = False):
    """(PLVConfig, PLVSearch, ignored fields) of an experiment; what PLV cannot do is a ConfigError naming the field."""
    from proxybench.experiments.plv.objective import PLVSearch
    from proxybench.experiments.plv.run import PLVConfig

    given = cfg.model_fields_set
    if cfg.target != "reality":
        raise ConfigError(f"target: the PLV objective trains on target samples it collects and evaluates in the "
                          f"target while it trains, so its target is the reality model (--target reality); got "
                          f"{cfg.target!r}")
    if cfg.target_params:
        raise ConfigError("target_params: the PLV objective's target is the reality model as calibrated; its "
                          "parameters cannot be overridden here")
    s = cfg.search
    if s.sampler not in ("tpe", "random"):
        raise ConfigError(f"search.sampler: the PLV search takes tpe or random, not {s.sampler!r}")
    try:
        base = PLVConfig.quick() if quick else PLVConfig()
        plv_cfg = PLVConfig.from_dict({**cfg.plv, **({"seed": cfg.seed} if cfg.seed else {}),
                                       **({"replicates": cfg.n_boot} if cfg.n_boot is not None else {})}, base)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"plv: {exc}") from None
    name = s.study_name if "study_name" in s.model_fields_set else "proxybench-plv"  # never a PRPV study's
    search = PLVSearch(dict(s.space), trials=s.trials or PLV_TRIALS[quick], family=s.family, sampler=s.sampler,
                       seed=cfg.seed, storage=s.storage, study_name=name,
                       fixed={k: v for k, v in cfg.proxy.items() if k not in s.space})
    ignored = [f for f in _NOT_USED if f in given] + (["robot_options"] if cfg.robot_options is not None else []) \
        + (["dtps_options"] if cfg.dtps_options is not None else [])
    return plv_cfg, search, ignored


def run_plv_search(cfg: ExperimentConfig, out: str | Path, progress=None, *, quick: bool = False) -> PLVOptimizeResult:
    """Search the experiment's space for the proxy of highest PLV; work and (with a storage) the study resume."""
    from proxybench.domain.reality import TRUTH
    from proxybench.experiments.plv.objective import optimize_plv

    plv_cfg, search, ignored = plv_search_settings(cfg, quick=quick)
    res = optimize_plv(search, plv_cfg, out, progress)
    _, expert, reference = res.objective.target()
    known = {**{k: float(v) for k, v in TRUTH.items() if isinstance(v, int | float)}, **cfg.truth}
    truth = {k: float(known[k]) for k in search.space if k in known}
    cost = next((t.target_cost for t in res.trials if t.target_cost is not None), None)
    return PLVOptimizeResult(res, dict(search.space), search.family, plv_cfg, reference, expert, cost, truth, ignored)


def plot_plv_search(res: PLVOptimizeResult, out: str | Path) -> list[Path]:
    """PLV of every trial with its 95 % interval, by trial number and by each searched parameter (PNG + SVG).

    A proxy whose agent never settled above P has no PLV: it is drawn as a cross on a dotted line under
    zero ("not reached"), not as a number; an interval whose lower end is "not reached" runs down to
    that line and ends in a triangle.
    """
    import matplotlib.ticker

    from proxybench.plots import pyplot, save_figure

    plt = pyplot()

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    trials = sorted(res.trials, key=lambda t: t.number)
    ok = [t for t in trials if t.plv is not None]
    missing = [t for t in trials if t.plv is None]
    names = list(res.space)
    fig, axes = plt.subplots(1, 1 + len(names), figsize=(4.6 * (1 + len(names)), 3.8), layout="constrained")
    axes = np.atleast_1d(axes)
    scale = max([abs(t.plv or 0.0) for t in ok] + [res.target_cost or 1.0, 1.0])
    floor = -0.08 * scale  # where "not reached" is drawn

    def draw(ax, xs_ok, xs_missing, xerr=None) -> None:
        if ok:
            y = np.array([t.plv for t in ok], float)
            lo = np.array([floor if t.plv_low is None else t.plv_low for t in ok], float)
            hi = np.array([t.plv if t.plv_high is None else t.plv_high for t in ok], float)
            ax.errorbar(xs_ok, y, yerr=[y - lo, hi - y], xerr=xerr, fmt="o", ms=4, capsize=3, color="tab:blue",
                        label="trial: PLV [95 % CI over seeds]")
            open_low = [x for x, t in zip(xs_ok, ok, strict=True) if t.plv_low is None]
            if open_low:  # the interval's lower end is "not reached": the bar runs down to that level
                ax.plot(open_low, [floor] * len(open_low), "v", color="tab:blue", ms=6,
                        label="interval's lower end: not reached")
        if xs_missing:
            ax.plot(xs_missing, [floor] * len(xs_missing), "x", color="tab:red", ms=8, label="not reached (no PLV)")
        if xs_missing or any(t.plv_low is None for t in ok):
            ax.axhline(floor, color="tab:red", lw=0.6, ls=":")
        best = res.best
        if best.plv is not None:
            bx = xs_ok[ok.index(next(t for t in ok if t.number == best.number))]
            ax.plot([bx], [best.plv], "*", ms=14, color="gold", mec="k",
                    label="best" + (" (stands apart)" if res.search.separated else " (ties: intervals overlap)"))
        ax.axhline(0.0, color="0.5", lw=0.8)
        if res.target_cost:
            ax.axhline(res.target_cost, color="0.5", lw=0.8, ls="--", label=f"|D_target| = {res.target_cost:,.0f}")
        ax.set_ylabel("PLV [target samples saved] (↑)")

    draw(axes[0], [t.number for t in ok], [t.number for t in missing])
    axes[0].set_xlabel("trial number")
    axes[0].xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    axes[0].legend(fontsize=7)
    for ax, name in zip(axes[1:], names, strict=True):
        if res.family:
            def centre(t, name=name):
                lo, hi = t.proposal[name]["uniform"]
                return (lo + hi) / 2, (hi - lo) / 2
            xs = [centre(t) for t in ok]
            draw(ax, [c for c, _ in xs], [centre(t)[0] for t in missing], xerr=[w for _, w in xs])
            ax.set_xlabel(f"{param_label(name)}: family centre ± half-width")
        else:
            draw(ax, [t.proposal[name] for t in ok], [t.proposal[name] for t in missing])
            ax.set_xlabel(param_label(name))
        if name in res.truth:
            ax.axvline(res.truth[name], color="tab:red", ls="--", lw=1, label="target's known θ (not used)")
        lo, hi = res.space[name]
        ax.set_xlim(lo - 0.03 * (hi - lo), hi + 0.03 * (hi - lo))
        ax.legend(fontsize=7)
    what = "families p(θ)" if res.family else "instances θ"
    fig.suptitle(textwrap.shorten(f"argmax PLV over {what} — target: reality model (simulated); "
                                  f"{len(res.config.seeds)} seeds, P = {res.reference:.2f}", 150, placeholder=" …"),
                 fontsize=10)
    path = out / "plv_search.png"
    save_figure(fig, path)
    return [path]


def write_plv_search(res: PLVOptimizeResult, out: str | Path, wall_s: float) -> list[Path]:
    """The plot, ``trials.json`` and ``summary.json`` of a PLV search."""
    out = Path(out)
    paths = plot_plv_search(res, out)
    (out / "trials.json").write_text(json.dumps([t.to_dict() for t in res.trials], indent=1, default=str))
    (out / "summary.json").write_text(json.dumps({**res.summary(), "wall_s": round(wall_s, 1)}, indent=1,
                                                 default=str))
    return [*paths, out / "trials.json", out / "summary.json"]
