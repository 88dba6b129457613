"""The files of a repeatability study: its figures per design beside the thesis', runs and MPD / MOD curves."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from proxybench.experiments.repeatability.config import RepeatabilityConfig
from proxybench.experiments.repeatability.run import THESIS_FIGURES, RepeatabilityResult

__all__ = ["design_rows", "thesis_text", "write_report"]


def thesis_text(design: str) -> str:
    """The thesis' figures of a design on real robots (MPD ± STD, MOD ± STD), or "–"."""
    th = THESIS_FIGURES.get(design)
    if th is None:
        return "–"
    return f"{th['MPD_cm']:+.1f} ± {th['MPD_std_cm']:.1f}, {th['MOD_deg']:+.1f} ± {th['MOD_std_deg']:.1f}"


def design_rows(res: RepeatabilityResult) -> list[dict[str, Any]]:
    """One row per design: its size, source, runs that ended early and every figure (repeatability.csv)."""
    return [{"design": name, "labs": r.design.labs, "robots": r.design.robots, "runs": r.design.runs,
             "source": res.source, "ended_early": r.early, **r.figures} for name, r in res.designs.items()]


def write_report(res: RepeatabilityResult, cfg: RepeatabilityConfig, out: str | Path) -> list[Path]:
    """repeatability.json / .csv, the runs over the map and the MPD / MOD curves (PNG + SVG) in ``out``."""
    import pandas as pd

    from proxybench.domain.maps import load_map
    from proxybench.plots import plot_deviation_curves, plot_trajectories
    from proxybench.tasks.metrics import deviation_curves

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "repeatability.json").write_text(json.dumps(
        {"source": res.source, "agent": cfg.agent, "seconds": cfg.seconds, "map": cfg.map, "figures": res.figures,
         "notes": res.notes}, indent=2))
    pd.DataFrame(design_rows(res)).to_csv(out / "repeatability.csv", index=False)
    titles = {k: f"{k} ({r.design.label})" for k, r in res.designs.items()}
    png = plot_trajectories(load_map(cfg.map), res.runs, out / "trajectories.png", titles)
    curves = plot_deviation_curves({k: deviation_curves(r.runs) for k, r in res.designs.items()},
                                   out / "mpd_mod.png", titles)
    return [out / "repeatability.json", out / "repeatability.csv", png, curves]
