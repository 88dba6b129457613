"""``proxybench repeatability``, registered: MPD / MOD of one agent over one robot, robots and labs (thesis §5.4)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

from proxybench.experiments.repeatability.config import RepeatabilityConfig
from proxybench.experiments.study import ConfigError, Progress, Study, register

if TYPE_CHECKING:
    from proxybench.experiments.repeatability.run import RepeatabilityResult
    from proxybench.tasks.trajectory import Trajectory

__all__ = ["RepeatabilityStudy"]


@register
class RepeatabilityStudy(Study[RepeatabilityConfig, "RepeatabilityResult"]):
    """MPD / MOD of one agent, thesis §5.4: one robot, robots, labs (figs. 5.8–5.10).

    MPD is the mean signed lateral offset from the lane centre along the route [cm] (+ = left), MOD the
    mean heading error [deg]; STD is the run-to-run standard deviation along the route. The target is the
    reality model (simulated stand-ins for Duckiebots) unless --recorded or --robot-cmd is given.
    """

    name = "repeatability"
    config = RepeatabilityConfig
    quick_help = "the same designs (the study is small; kept for a uniform command line)"
    out_help = "folder for the tables and the plots"

    def help_defaults(self) -> dict[str, str]:
        return {"designs": "the thesis' three, 1×1×9, 1×3×3, 2×1×6", "runs": "each design's; robot nodes: 3"}

    def run(self, config: RepeatabilityConfig, out: Path, backend: Any, progress: Progress, *,
            quick: bool = False) -> RepeatabilityResult:
        from proxybench.experiments.repeatability.run import run_repeatability

        try:
            res = run_repeatability(config, progress=progress)
        except FileNotFoundError as exc:
            raise ConfigError(str(exc)) from None
        return dataclasses.replace(res, config=config)

    def write_report(self, result: RepeatabilityResult, out: Path, *, wall: float = 0.0) -> list[Path]:
        from proxybench.experiments.repeatability.report import write_report

        assert result.config is not None
        return write_report(result, result.config, out)

    def example(self) -> RepeatabilityResult:
        """A canned result: the thesis' three designs with 3 runs per robot, 10 s each along the loop's right lane,
        made-up offsets (no episode runs)."""
        from proxybench.experiments.repeatability.run import (
            DESIGNS,
            Design,
            DesignResult,
            RepeatabilityResult,
            design_figures,
        )

        cfg = RepeatabilityConfig(seconds=10.0, runs=3)
        designs = {}
        for k, (name, d) in enumerate(DESIGNS.items()):
            d = Design(d.labs, d.robots, 3)
            cells = [(lab, r, i) for lab in range(d.labs) for r in range(d.robots) for i in range(d.runs)]
            runs = [_canned_drive(cfg, k, lab, r, i) for lab, r, i in cells]
            labels = [f"lab {lab}/robot {r}" for lab, r, _ in cells]
            designs[name] = DesignResult(d, runs, labels, design_figures(runs, labels, d))
        return RepeatabilityResult(designs, "a canned example: made-up runs, no robot and no simulator ran",
                                   config=cfg)

    def show(self, result: RepeatabilityResult, console: Any, *, wall: float = 0.0) -> None:
        from rich.markup import escape
        from rich.table import Table

        from proxybench.experiments.repeatability.report import design_rows, thesis_text

        res, cfg = result, result.config
        assert cfg is not None
        table = Table(title=escape(f"repeatability of {cfg.agent} ({res.source}; {cfg.seconds:g} s runs): MPD [cm] "
                                   "(+ = left of the lane centre), MOD [deg]; STD = run-to-run"))
        for col in ("design", "labs×robots×runs", "AVG MPD", "STD MPD", "AVG MOD", "STD MOD",
                    "within / between STD MPD", "ended early", "route (m)",
                    "thesis (real robots): MPD ± STD, MOD ± STD"):
            table.add_column(col, justify="left" if col == "design" else "right")
        for (name, r), f in zip(res.designs.items(), design_rows(res), strict=True):
            split = f"{f['MPD_within_std_cm']:.2f} / {f['MPD_between_std_cm']:.2f}" if "MPD_within_std_cm" in f else "–"
            table.add_row(name, r.design.label, f"{f['MPD_cm']:+.2f}", f"{f['MPD_std_cm']:.2f}", f"{f['MOD_deg']:+.2f}",
                          f"{f['MOD_std_deg']:.2f}", split, f"{r.early}/{len(r.runs)}", f"{f['route_m']:.1f}",
                          thesis_text(name))
        console.print(table)
        for name, note in res.notes.items():
            console.print(f"{name}: {note}", highlight=False)


def _canned_drive(cfg: RepeatabilityConfig, design: int, lab: int, robot: int, run: int) -> Trajectory:
    """A made-up run of ``cfg.seconds`` along the right lane of ``cfg.map`` from its first straight tile, at
    0.25 m/s (15 Hz): off the lane centre by the lab's and the robot's own offset (the same robot in every design)
    and the run's placement, weaving slowly; the heading follows the weave."""
    import numpy as np

    from proxybench.domain.lanes import LaneNetwork, SegmentKind
    from proxybench.domain.maps import load_map
    from proxybench.tasks.trajectory import Trajectory

    m = load_map(cfg.map)
    net = LaneNetwork(m)
    own, rng = np.random.default_rng([cfg.seed, lab, robot]), np.random.default_rng([cfg.seed, design, lab, robot, run])
    t = np.arange(0.0, cfg.seconds + 1e-9, 1 / 15)
    s = 0.25 * t
    weave = 2 * np.pi * s / own.uniform(1.5, 2.5) + own.uniform(0, 2 * np.pi) + rng.normal(0.0, 0.5)
    lateral = -0.03 + 0.02 * lab + own.normal(0.0, 0.015) + rng.normal(0.0, 0.004) + 0.015 * np.sin(weave)
    wobble = np.convolve(rng.normal(0.0, 0.08, t.size + 7), np.ones(8) / 8, mode="valid")  # ~1.5° and smooth
    heading = np.arctan(np.gradient(lateral, s)) + wobble
    seg = next(g for g in net.segments if g.kind == SegmentKind.STRAIGHT)
    start, pose = 0.0, []
    for si, lat, head in zip(s, lateral, heading, strict=True):
        while si - start > seg.length:
            start += seg.length
            seg = net.segments[net.successors(seg.index)[0]]
        pose.append((*seg.position(si - start, lat), seg.heading_at(si - start) + head))
    return Trajectory.from_poses(m, t, np.array(pose), meta={"agent": cfg.agent, "lab": lab, "robot": robot,
                                                             "run": run, "source": "canned example"})
