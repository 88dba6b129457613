"""A finished PLV run read back: from ``proxybench plv``'s report folder (plv.json with its training runs) or from a
shipped ``results/NAME`` (plv.json and its tables: one row per training run, one per evaluation episode).

Why here and not in :mod:`proxybench.experiments.evidence`: both the shipped evidence (which rebuilds a run's
numbers) and ``plv-vs-prpv --plv from_run=DIR`` (which reads a run's PLV instead of training) read runs back, and
the evidence layer already imports the studies; this keeps the imports pointing one way.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from proxybench.experiments.plv.config import PLVConfig
from proxybench.experiments.plv.run import PLVResult

__all__ = ["EPISODES", "RUNS", "StoredRunError", "load_plv_run", "result_of", "runs_from_tables"]

#: a shipped run's training runs (one row each) and its evaluation episodes (one row each)
RUNS = "runs.csv.gz"
EPISODES = "episodes.csv.gz"


class StoredRunError(ValueError):
    """A PLV run that cannot be read back, or is unfinished; one line naming the file and what is wrong."""


def result_of(blob: dict[str, Any], runs: list[dict[str, Any]], where: Path) -> PLVResult:
    """The PLV result (config, training runs, proxies' records, expert) from plv.json's ``blob`` and ``runs``; a run
    lacking an arm or a proxy's pre-training is unfinished."""
    try:
        cfg = PLVConfig.from_dict(blob.get("config") or {})
    except (TypeError, ValueError) as exc:
        raise StoredRunError(f"{where}: its config does not load with this code ({exc})") from None
    missing = [name for name in cfg.proxies if name not in (blob.get("proxies") or {})]
    if missing:
        raise StoredRunError(f"{where}: no pre-training record of proxy {missing[0]!r}: the run is unfinished")
    arms = {r["arm"] for r in runs}
    if "target-only" not in arms or any(name not in arms for name in cfg.proxies):
        gone = "target-only" if "target-only" not in arms else next(n for n in cfg.proxies if n not in arms)
        raise StoredRunError(f"{where}: no training run of arm {gone!r}: the run is unfinished")
    return PLVResult(cfg, runs, dict(blob["proxies"]), float(blob["summary"]["expert"]))


def runs_from_tables(folder: Path) -> tuple[list[dict[str, Any]], list[str]]:
    """The training runs from ``RUNS``, each with its episodes' scores from ``EPISODES``; and the problems: a run
    whose score is not the mean of its episodes."""
    import pandas as pd

    try:
        runs = pd.read_csv(folder / RUNS)
        eps = pd.read_csv(folder / EPISODES, keep_default_na=False, dtype={"termination": str})
    except (OSError, ValueError) as exc:
        raise StoredRunError(f"{folder}: {RUNS} or {EPISODES} unreadable ({exc.__class__.__name__})") from None
    problems, out = [], []
    by_run = {key: g.sort_values("episode") for key, g in eps.groupby(["arm", "n", "seed"])}
    for r in runs.to_dict("records"):
        g = by_run.get((r["arm"], r["n"], r["seed"]))
        scores = [] if g is None else [float(v) for v in g["score"]]
        mean = sum(scores) / len(scores) if scores else None
        if mean is None or not math.isclose(mean, float(r["score"]), rel_tol=1e-9, abs_tol=1e-9):
            problems.append(f"{RUNS}: run {r['arm']} n={r['n']} seed={r['seed']} scores {r['score']!r}, its episodes "
                            f"in {EPISODES} average {mean if mean is not None else 'nothing'!r}")
        out.append({**r, "scores": scores, "terminations": [] if g is None else list(g["termination"])})
    return out, problems


def load_plv_run(folder: Path) -> PLVResult:
    """A finished PLV run from its report folder or a shipped ``results/NAME`` (refused if a run's score is not its
    episodes' mean)."""
    folder = Path(folder)
    try:
        blob = json.loads((folder / "plv.json").read_bytes())
    except FileNotFoundError:
        raise StoredRunError(f"{folder / 'plv.json'} is missing: not a finished `proxybench plv` run") from None
    except (OSError, ValueError) as exc:
        raise StoredRunError(f"{folder / 'plv.json'}: unreadable ({exc.__class__.__name__})") from None
    if not isinstance(blob, dict) or "summary" not in blob:
        raise StoredRunError(f"{folder / 'plv.json'}: not a `proxybench plv` report (no summary)")
    if blob.get("runs"):
        return result_of(blob, blob["runs"], folder / "plv.json")
    runs, problems = runs_from_tables(folder)
    if problems:
        raise StoredRunError(f"{folder}: {problems[0]}")
    return result_of(blob, runs, folder / "plv.json")
