"""``proxybench rank``, registered: K agents ranked on the target with a guarantee, the proxy as the predictor."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from proxybench.experiments.config import ExperimentStudy
from proxybench.experiments.rank.config import RankConfig
from proxybench.experiments.study import register

if TYPE_CHECKING:
    from proxybench.experiments.rank.run import RankResult

__all__ = ["RankStudy"]


@register
class RankStudy(ExperimentStudy):
    """Rank agents on the target: every pair decided a>b, b>a, tie (within ε) or undecided, and a rank-set per
    agent, with at most --alpha chance that any decision is wrong.

    The proxy's paired episodes (the same starts and seeds) and its own extra episodes are the predictor
    (prediction-powered inference, PPI++): a good proxy decides more pairs from the same target episodes, a bad
    one is weighted down to nothing. rank.json holds the decisions with the proxy and with the target alone.
    --sequential runs target episodes one at a time where they settle most and stops when every pair is
    decided; its intervals are anytime-valid (stop whenever you like). docs/rank.md.
    """

    name = "rank"
    config = RankConfig
    quick_help = "4 agents × 4 episodes × 6 s, 16 proxy-only episodes each; --sequential: budget 8"
    out_help = "folder for rank.json, rank.html, pairs.csv and the episode cache (OUT/runs)"
    exclude = ("search", "plan", "sweep", "pod_seconds", "n_boot", "truth", "plv")
    runs = "proxybench.experiments.rank.run:run_rank"
    reports = "proxybench.experiments.rank.report:write_rank"
    extra_defaults = {"param": "the nominal calibration", "proxy_episodes": "100; --quick 16",  # noqa: RUF012
                      "budget": "80; --quick 8", "episodes": "a recorded target's (all of them), else 10; --quick 4"}

    def example(self) -> RankResult:
        """A canned result: five agents' made-up scores, a proxy that tracks them (nothing runs)."""
        from proxybench.experiments.rank.report import canned_rank

        return canned_rank()

    def show(self, result: RankResult, console: Any, *, wall: float = 0.0) -> None:
        from proxybench.experiments.rank.report import show_rank

        show_rank(result, console)
