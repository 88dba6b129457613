"""``proxybench heldout``, registered: how often each usefulness metric picks the best available θ on held-out
targets."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from proxybench.experiments.heldout.config import HeldOutConfig, default_help
from proxybench.experiments.study import Progress, Study, register

if TYPE_CHECKING:
    from proxybench.experiments.heldout.analysis import HeldOutResult
    from proxybench.experiments.heldout.run import HeldOutRun

__all__ = ["HeldOutStudy"]


@register
class HeldOutStudy(Study[HeldOutConfig, "HeldOutResult"]):
    """Score PRPV, PPV, SRCC (Pearson), Spearman, Kendall and MMRV on targets they were not tuned on.

    Held-out targets (simulated, with structural differences the proxies cannot express and a θ drawn from a
    hidden seed) and the standing negative case are run as black boxes; the pass criteria are written to
    OUT/criteria.json before any episode runs; hit rates come with Wilson intervals. Episodes are cached
    in OUT/runs, so an interrupted run resumes.
    """

    name = "heldout"
    config = HeldOutConfig
    quick_help = "3 held-out targets + the negative case, 8 agents, 3×3 grid, 2 + 4 episodes × 12 s"
    out_help = "report folder (report.html, figures, tables, runs/)"

    def help_defaults(self) -> dict[str, str]:
        return default_help()

    def run(self, config: HeldOutConfig, out: Path, backend: Any, progress: Progress, *,
            quick: bool = False) -> HeldOutResult:
        from proxybench.experiments.heldout.analysis import score_heldout
        from proxybench.experiments.heldout.run import run_heldout

        return score_heldout(run_heldout(config, out, backend, progress, quick=quick))

    def write_report(self, result: HeldOutResult, out: Path, *, wall: float = 0.0) -> list[Path]:
        from proxybench.experiments.heldout.report import write_heldout_report

        result.run.wall_s = wall
        files = write_heldout_report(result, out)
        crit = result.run.criteria_file  # None in a canned result: nothing ran, so nothing was fixed before
        return [files["html"], files["fig_hits"], files["fig_maps"], files["rates"], files["cases"],
                *([crit] if crit is not None else [])]

    def example(self) -> HeldOutResult:
        """A canned result: two held-out targets and the negative case on the --quick 3×3 grid, five agents,
        made-up scores (no episode runs)."""
        from proxybench.experiments.heldout.analysis import score_heldout

        return score_heldout(_canned_run())

    def show(self, result: HeldOutResult, console: Any, *, wall: float = 0.0) -> None:
        from rich.table import Table

        from proxybench.experiments.heldout.report import findings

        res, run = result, result.run
        task, ref, tol = res.primary()
        console.print("[bold]targets:[/bold] SIMULATED held-out stand-ins and the shipped reality model; no real "
                      "robot.", highlight=False)
        table = Table(title=f"hit rates on {sum(cr.case.kind == 'held-out' for cr in run.cases)} held-out targets — "
                            f"task {task}; pick within {tol} step(s) of the "
                            f"{'best available θ' if ref == 'order' else 'θ nearest the truth'}; {wall:.0f} s")
        for col in ("metric", "hits", "rate [95% Wilson]", "random pick"):
            table.add_column(col, justify="left" if col == "metric" else "right")
        for r in res.rates:
            if (r.task, r.reference, r.tolerance) == (task, ref, tol):
                table.add_row(r.metric, f"{r.hits}/{r.n}",
                              f"{100 * r.rate:.0f}% [{100 * r.low:.0f}, {100 * r.high:.0f}]", f"{100 * r.chance:.0f}%")
        console.print(table)
        for line in findings(res):
            console.print(f"• {line}", highlight=False, markup=False)


def _canned_run() -> HeldOutRun:
    """Made-up episodes of three cases: each agent's scores around its own means, shifted per case; a proxy's
    further off the further its θ lies from the case's truth (in grid steps, by how much each agent feels each
    axis), and the negative case's pinhole proxies off by a lens error on top."""
    import numpy as np

    from proxybench.experiments.examples import AGENTS, CANNED, MEANS, CannedTarget
    from proxybench.experiments.heldout.run import Case, CaseRun, HeldOutRun, resolve_settings
    from proxybench.runner.jobs import AgentSpec
    from proxybench.targets.base import TargetEpisode, TargetRun
    from proxybench.usefulness.heldout_scoring import Grid

    s = resolve_settings(HeldOutConfig(targets=2, agents=list(AGENTS), episodes=3, reference_episodes=4, seconds=20.0,
                                       n_boot=20, agent_boot=40, reference_boot=10), quick=True)
    grid = Grid.from_dict(s.grid)
    metrics = tuple(dict.fromkeys(m for ms in s.tasks.values() for m in ms))  # distance, lane score, survival
    n = s.episodes + s.reference_episodes
    rng = np.random.default_rng(0)
    feel = {a: rng.normal(0.0, 1.5, (len(grid.names), len(metrics))) for a in AGENTS}  # per grid step of each axis
    top = np.array([np.inf, s.seconds, s.seconds])

    def table(mean: dict[str, np.ndarray], shift: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {a: np.clip(mean[a] + shift[a] + rng.normal(0.0, 0.8, (n, 3)), 0.0, top) for a in AGENTS}

    truths = {"heldout-0": {"trim": 0.08, "camera_pitch": 17.6}, "heldout-1": {"trim": -0.13, "camera_pitch": 21.9},
              "lens-negative": {"trim": 0.0, "camera_pitch": 19.15}}
    runs = []
    for name, truth in truths.items():
        neg = name == "lens-negative"
        case = Case(name, "negative" if neg else "held-out", CannedTarget(), {"fisheye": False} if neg else {},
                    "a canned case: made-up scores", truth)
        mean = {a: np.array([d, 0.85 * sv, sv]) + rng.normal(0.0, 0.5, 3) for a, (d, sv) in MEANS.items()}
        lens = {a: rng.normal(0.0, 2.0, 3) * neg for a in AGENTS}
        target = TargetRun(CANNED, s.map, s.seconds, metrics,
                           [TargetEpisode(a, e, 1000 + e, None) for a in AGENTS for e in range(n)],
                           table(mean, dict.fromkeys(AGENTS, np.zeros(3))))
        steps = [(np.array([p[k] - truth[k] for k in grid.names]) / grid.steps()) for p in grid.points]
        proxies = [table(mean, {a: off @ feel[a] + lens[a] for a in AGENTS}) for off in steps]
        runs.append(CaseRun(case, target, proxies, metrics))
    return HeldOutRun(s, grid, [AgentSpec(a) for a in AGENTS], runs, None)
