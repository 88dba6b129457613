"""``proxybench plv``, registered: how many target samples pre-training on a proxy saves a behaviour-cloning agent."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from proxybench.experiments.plv.config import PLVConfig
from proxybench.experiments.study import ConfigError, Progress, Study, register

if TYPE_CHECKING:
    from proxybench.experiments.plv.run import PLVResult

__all__ = ["PLVStudy"]


@register
class PLVStudy(Study[PLVConfig, "PLVResult"]):
    """How many target samples does pre-training on a proxy save a behaviour-cloning agent? \
(Table 3.1, Fig. 3.6)

    The target is the reality model, a *simulated* stand-in for a real Duckiebot, or a robot node (--target);
    the proxies are the simulator with camera pitch 3°, 19°, 35° and a domain-randomised family. PLV comes from
    fitted learning curves (a continuous crossing of P) with bootstrap intervals over seeds; the ladder rule is
    shown beside it. Work is cached in OUT/cache, so an interrupted run resumes.
    """

    name = "plv"
    config = PLVConfig
    config_help = "YAML or JSON file of PLVConfig fields (sections: train: {max_steps: 100}, eval, ...)"
    quick_help = "40×30 frames, short ladder, 3 seeds (minutes)"
    out_help = "report folder (figure, tables, report.html) and cache"

    def help_defaults(self) -> dict[str, str]:
        from proxybench.experiments.study import mode_defaults

        full, quick = PLVConfig(), PLVConfig.quick()
        return mode_defaults(full.to_dict(), quick.to_dict()) | {"seeds": f"{len(full.seeds)}; --quick "
                                                                          f"{len(quick.seeds)}"}

    def load(self, path: Path | None, overrides: dict[str, Any], *, quick: bool = False) -> PLVConfig:
        """The file and the options over ``PLVConfig()``, or with ``--quick`` over ``PLVConfig.quick()``."""
        base = PLVConfig.quick() if quick else PLVConfig()
        return PLVConfig.load(path, overrides, base=base.to_dict())

    def run(self, config: PLVConfig, out: Path, backend: Any, progress: Progress, *,
            quick: bool = False) -> PLVResult:
        from proxybench.experiments.optimize.plv_search import torch_available
        from proxybench.experiments.plv.run import run_plv
        from proxybench.protocol import RobotFailure

        if not torch_available():
            raise ConfigError("plv trains behaviour-cloning networks and needs PyTorch: pip install "
                              "'proxybench[learning]'")
        try:
            return run_plv(config, out, progress)
        except (RuntimeError, RobotFailure) as exc:  # a robot node that fails or serves no lane pose
            raise ConfigError(f"{config.target}: {exc}") from exc

    def write_report(self, result: PLVResult, out: Path, *, wall: float = 0.0) -> list[Path]:
        from proxybench.experiments.plv.report import write_report

        files = write_report(result, out)
        return [files["html"], files["fig3_6"], files["fig_plv"], files["table"], files["runs"]]

    def example(self) -> PLVResult:
        """A canned result: made-up learning curves of the target and two proxies, two seeds (nothing trains)."""
        from proxybench.experiments.plv.run import PLVResult

        cfg = PLVConfig(width=32, height=24, ladder=(250, 500, 1000, 2000), seeds=(0, 1),
                        proxies={"pitch-19": "proxy", "pitch-35": "proxy:camera_pitch=35"})

        def runs(arm: str, curve: list[tuple[int, float]]) -> list[dict[str, Any]]:
            return [{"arm": arm, "n": n, "seed": s, "off_policy": n, "on_policy": 0, "cost": float(n),
                     "score": v + 0.1 * s} for n, v in curve for s in (0, 1)]

        def proxy(spec: str, zero_shot: float) -> dict[str, Any]:
            return {"spec": spec, "zero_shot": zero_shot + 0.05, "in_proxy": 24.0,
                    "zero_shot_by_seed": {"0": zero_shot, "1": zero_shot + 0.1}}

        return PLVResult(cfg, runs("target-only", [(250, 5.0), (500, 12.0), (1000, 18.0), (2000, 20.0)])
                         + runs("pitch-19", [(250, 17.0), (500, 19.8), (1000, 19.9), (2000, 20.0)])
                         + runs("pitch-35", [(250, 3.0), (500, 6.0), (1000, 9.0), (2000, 12.0)]),
                         {"pitch-19": proxy("proxy", 8.0), "pitch-35": proxy("proxy:camera_pitch=35", 2.0)},
                         expert_score=21.0)

    def show(self, result: PLVResult, console: Any, *, wall: float = 0.0) -> None:
        from rich.markup import escape
        from rich.table import Table

        from proxybench.experiments.plv.measures import summarize
        from proxybench.experiments.plv.report import findings, table_rows

        s = summarize(result)
        note = f", {result.cached} units from the cache" if result.cached else ""
        rows = table_rows(result, s)
        table = Table(title=f"Table 3.1 — PLV of proxies (target: {s.target_label}) — {len(result.config.seeds)} "
                            f"seeds, fitted curves, 95 % bootstrap intervals over seeds — {wall:.0f} s{note}")
        for col in rows[0]:
            table.add_column(col, justify="left" if col == "domain" else "right")
        for r in rows:
            table.add_row(*(escape(str(v)) for v in r.values()))  # "[not reached, 900]" is not markup
        console.print(table)
        for line in findings(result, s):
            console.print(f"• {escape(line)}", highlight=False)
