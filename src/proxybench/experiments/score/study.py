"""``proxybench score-proxy``, registered: one θ against a target, paired against another θ (or the nominal)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import Field

from proxybench.experiments.config import ExperimentConfig, ExperimentStudy
from proxybench.experiments.study import Cli, Progress, register

if TYPE_CHECKING:
    from proxybench.experiments.score.run import ScoreResult

__all__ = ["ScoreConfig", "ScoreStudy"]


class ScoreConfig(ExperimentConfig):
    """The experiment file, and the two θ compared."""

    param: Annotated[dict[str, Any], Cli("--param", metavar="NAME=VALUE")] = Field(default_factory=dict)
    """the θ to score, on top of the nominal calibration (repeat for more parameters; names: proxybench params)"""
    vs_param: Annotated[dict[str, Any], Cli("--vs-param", metavar="NAME=VALUE")] = Field(default_factory=dict)
    """the θ to compare it with on the same episodes (default: the nominal calibration, i.e. changing nothing)"""


@register
class ScoreStudy(ExperimentStudy):
    """Score one θ against a target (PRPV, PPV, SRCC with intervals) and compare it with another θ, paired.

    Both θ replay the same target episodes, so ΔPRPV has a paired interval; the nominal calibration, the
    no-simulator baselines and the target's noise floor are shown beside them. Split a recording with
    --episodes (e.g. fit θ with `optimize --episodes 0-4`, score it here with --episodes 5-9).
    """

    name = "score-proxy"
    defaults_of = "predictivity"
    config = ScoreConfig
    quick_help = "the live target's quick episodes (12 agents × 3 × 20 s)"
    out = "out/score"
    out_help = "score.json and the episode cache (OUT/runs)"
    exclude = ("search", "plan", "sweep", "pod_seconds", "plv", "truth")  # not used by a score
    extra_defaults = {"param": "the nominal calibration", "vs_param": "the nominal calibration"}  # noqa: RUF012

    def run(self, config: ScoreConfig, out: Path, backend: Any, progress: Progress, *,
            quick: bool = False) -> ScoreResult:
        from proxybench.experiments.score.run import score_proxy

        return score_proxy(config, config.param, out / "runs", versus=config.vs_param, backend=backend,
                           progress=progress, quick=quick)

    def write_report(self, result: ScoreResult, out: Path, *, wall: float = 0.0) -> list[Path]:
        out.mkdir(parents=True, exist_ok=True)
        path = out / "score.json"
        path.write_text(json.dumps(result.to_dict(), indent=1, default=float))
        return [path]

    def example(self) -> ScoreResult:
        """A canned result: trim 0.1 against the nominal θ on made-up scores (no episode runs)."""
        from proxybench.experiments.baselines import NOMINAL
        from proxybench.experiments.examples import canned_experiment, canned_proxies, canned_target
        from proxybench.experiments.score.run import measure_score

        exp = canned_experiment()
        tgt = canned_target(exp)
        return measure_score(exp, tgt, canned_proxies(tgt, ["trim=0.1"]), "trim=0.1", {"trim": 0.1}, NOMINAL, {})

    def show(self, result: ScoreResult, console: Any, *, wall: float = 0.0) -> None:
        from rich.markup import escape
        from rich.table import Table

        from proxybench.experiments.predictivity.study import ci

        res = result
        console.print(f"[bold]target:[/bold] {escape(res.target.info.statement)}", highlight=False)
        exp = res.experiment
        table = Table(title=escape(f"θ against the target: {len(exp.agents)} agents × {exp.episode_count} episodes "
                                   f"× {exp.seconds:g} s; 95 % intervals; {wall:.0f} s"))
        for col in ("θ", "PRPV [order range]", "PPV (mean/agent)", "Pearson r", "Spearman ρ", "Kendall τ"):
            table.add_column(escape(col), justify="left" if col == "θ" else "right")
        rows = [(res.scored.label, res.scored.figures),
                *([(res.versus.label, res.versus.figures)] if res.versus.label != res.scored.label else []),
                *((k, u) for k, u in res.baselines.items() if k not in (res.scored.label, res.versus.label))]
        for label, u in rows:
            table.add_row(escape(label), ci(u["prpv"], ".1f"), ci(u["ppv"], ".2f"),
                          *(f"{u[k].value:.2f}" for k in ("pearson", "spearman", "kendall")))
        table.add_row("target noise floor", ci(res.noise, ".1f"), "", "", "", "")
        console.print(table)
        for c in (res.comparison, res.versus_nominal):
            if c is None:
                continue
            d = c.delta
            same = d.value == d.low == d.high == 0.0
            verdict = ("the same θ on the same episodes: no difference" if same else
                       f"{c.a} orders the agents more like the target" if c.a_lower else
                       f"{c.b} orders the agents more like the target" if c.separated else
                       "the episodes cannot tell them apart (the interval holds 0)")
            console.print(f"• ΔPRPV ({c.a}) − ({c.b}) = {d.value:+.1f} [{d.low:+.1f}, {d.high:+.1f}] (paired, "
                          f"{exp.episode_count} episodes per agent): {verdict}", highlight=False, markup=False)
