"""``proxybench rank-check``, registered: rank's guarantee and savings measured over a family of targets."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from proxybench.experiments.rank_check.config import DEFAULTS, RankCheckConfig
from proxybench.experiments.study import Study, register

if TYPE_CHECKING:
    from pathlib import Path

    from proxybench.experiments.rank_check.run import RankCheckResult

__all__ = ["RankCheckStudy"]

@register
class RankCheckStudy(Study[RankCheckConfig, Any]):
    """Check rank on a family of targets: on each, rank decides every pair from a few target episodes (the nominal
    proxy as predictor, and an adversarial proxy that orders the agents backwards, and none), and many further
    target episodes judge the decisions.

    Reports, over targets: the share of targets with any decision the further episodes contradict (fixed sample,
    and anytime: at any episode count), the pairs decided with and without the proxy, and what one target episode
    is worth with the proxy. The targets are simulated (held-out stand-ins or gym-duckietown), never a robot.
    """

    name = "rank-check"
    config = RankCheckConfig
    quick_help = "2 targets, 3 agents, 4 + 10 episodes of 4 s"
    out_help = "folder for targets.csv, summary.json and the episode cache (OUT/runs)"

    def help_defaults(self) -> dict[str, str]:
        from proxybench.experiments.study import mode_defaults

        words = mode_defaults(DEFAULTS[False], DEFAULTS[True])
        return words | {"agents": f"{len(DEFAULTS[False]['agents'])} zoo agents; --quick "
                                  f"{len(DEFAULTS[True]['agents'])}"}

    def run(self, config: RankCheckConfig, out: Path, backend: Any, progress: Any, *,
            quick: bool = False) -> RankCheckResult:
        from proxybench.experiments.rank_check.run import run_rank_check

        return run_rank_check(config.filled(quick), out, backend, progress)

    def write_report(self, result: RankCheckResult, out: Path, *, wall: float = 0.0) -> list[Path]:
        from proxybench.experiments.rank_check.run import write_rank_check

        return write_rank_check(result, out)

    def example(self) -> RankCheckResult:
        """A canned result: three made-up targets' rows (nothing runs)."""
        from proxybench.experiments.rank_check.run import canned_rank_check

        return canned_rank_check()

    def show(self, result: RankCheckResult, console: Any, *, wall: float = 0.0) -> None:
        from proxybench.experiments.rank_check.run import summary_lines

        for line in summary_lines(result):
            console.print(line, highlight=False)
