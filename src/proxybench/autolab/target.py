"""Logs in, target out: ``proxybench localize LOGDIR --map M --out TARGETDIR``.

Every run under LOGDIR (``logs.find_logs``) is localised (``localize``) and validated (``validate``). The valid
runs become a recorded target (docs/targets.md) that ``proxybench target check`` accepts::

    TARGETDIR/target.yaml                          the manifest: source (as the logs say), map, episode length,
                                                   agents, episodes, and ``excluded`` runs with their reasons
    TARGETDIR/episodes/<agent>/<episode>.csv       the active robot: t, x, y, theta, pwm_left, pwm_right (bags),
                                                   sigma_x, sigma_y [m], sigma_theta [rad], views
    TARGETDIR/localization/<agent>/<episode>/      every robot of the run (<robot>.csv), and run.json: the log,
                                                   counts, the verdict, the watchtowers as solved

Each agent's valid runs are its episodes 0, 1, … in the order of the logs; an agent keeps as many as every
agent has (the manifest pairs episodes by id), and any others are listed as excluded too.

Names from the logs become file names here, so they are checked as single path components when the logs are
read (``logs.check_names``; the layout's robot names here), before anything is written, and every file is
written by :func:`proxybench.untrusted.write_file_under`: inside TARGETDIR, through no link, atomically.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from pydantic import ValidationError

from proxybench import __version__
from proxybench.autolab.localize import Localization, RobotTrack, localize_log
from proxybench.autolab.logs import Log, find_logs, read_log
from proxybench.autolab.validate import Thresholds, Verdict, validate_run
from proxybench.autolab.watchtowers import LayoutError, UnsafeLogError, load_layout
from proxybench.domain.maps import Map
from proxybench.targets.manifest import MANIFEST_NAME, ExcludedRun, TargetManifest, format_errors
from proxybench.untrusted import UntrustedInputError, path_component, write_file_under

__all__ = ["LocalizeSummary", "localize_logs", "track_table"]

_COLUMNS = ("t", "x", "y", "theta", "pwm_left", "pwm_right", "sigma_x", "sigma_y", "sigma_theta", "views")


@dataclass
class LocalizeSummary:
    """What ``localize_logs`` did: the target written, and per run its verdict."""

    root: Path
    manifest: TargetManifest | None
    runs: list[tuple[Path, Verdict, Localization]]


def track_table(track: RobotTrack, start: float, commands: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """A robot's samples as target columns (time from the run's start; wheel commands held between messages)."""
    t = track.t - start
    cols = {"t": t, "x": track.pose[:, 0], "y": track.pose[:, 1], "theta": track.pose[:, 2]}
    if commands is not None and len(commands):
        k = np.clip(np.searchsorted(commands[:, 0] - start, t, side="right") - 1, 0, len(commands) - 1)
        cols["pwm_left"], cols["pwm_right"] = commands[k, 1], commands[k, 2]
    cols.update({"sigma_x": track.sigma[:, 0], "sigma_y": track.sigma[:, 1], "sigma_theta": track.sigma[:, 2],
                 "views": track.views})
    return cols


def _write(out: Path, relative: str, text: str) -> None:
    """``text`` to ``out/relative``, inside ``out`` whatever the names and whatever is planted there."""
    try:
        write_file_under(out, relative, text)
    except UntrustedInputError as exc:
        raise UnsafeLogError(str(exc)) from None


def _write_csv(out: Path, relative: str, cols: dict[str, np.ndarray]) -> None:
    import pandas as pd

    _write(out, relative, pd.DataFrame({k: cols[k] for k in _COLUMNS if k in cols}).to_csv(
        index=False, float_format="%.6g"))


def _run_info(log: Log, loc: Localization, verdict: Verdict) -> dict:
    from proxybench.autolab.geometry import planar

    return {"log": str(log.root), "truth": str(log.truth) if log.truth is not None else None,
            "source": log.manifest.source, "agent": log.manifest.agent,
            "valid": verdict.valid, "reasons": verdict.reasons, "frames": loc.frames, "detections": loc.detections,
            "notes": loc.notes, "timing_s": loc.timing,
            "robots": {r: {"samples": int(t.t.size),
                           "median_sigma_xy_m": float(np.nanmedian(t.sigma[:, :2])) if t.t.size else None}
                       for r, t in loc.robots.items()},
            "watchtowers": {n: [*planar(T), float(T[2, 3])] for n, T in loc.towers.items()}}


def localize_logs(
    logdir: str | Path, m: Map, out: str | Path, *, layout: str | Path | None = None,
    calibrations: str | Path | None = None, overrides: dict | None = None, limits: Thresholds | None = None,
    detector: str = "apriltag", solver: str = "gtsam", workers: int | None = None, decimate: float = 2.0,
    progress: Callable[[str, int, int], None] | None = None,
) -> LocalizeSummary:
    """Localise and validate every run under ``logdir`` and write the valid ones as a recorded target ``out``."""
    paths = find_logs(logdir)
    if not paths:
        raise LayoutError(f"{logdir}: no runs (folders with log.yaml or watchtowers/, or ROS bags)")
    lay = load_layout(layout) if layout is not None else None
    robots = dict(lay.robots) if lay is not None and lay.robots else None
    for tag, name in (robots or {}).items():
        try:
            path_component(name, field=f"robots.{tag}")
        except UntrustedInputError as exc:
            raise UnsafeLogError(f"{layout}: {exc}") from None
    extra_tags = list(lay.ground_tags) if lay is not None else []
    out = Path(out)
    runs: list[tuple[Path, Verdict, Localization]] = []
    logs: list[Log] = []
    for path in paths:
        log = read_log(path, calibrations, overrides)
        if extra_tags:
            log.manifest = log.manifest.model_copy(update={"ground_tags": [*log.manifest.ground_tags, *extra_tags]})
        if log.manifest.map not in (None, m.name, m.path):
            raise LayoutError(f"{path}: recorded on map {log.manifest.map!r}, --map is {m.name!r}")
        tick = (lambda d, t, p=path: progress(str(p), d, t)) if progress else None
        loc = localize_log(log, m, robots=robots, detector=detector, solver=solver, workers=workers,
                           decimate=decimate, progress=tick)
        runs.append((path, validate_run(log, loc, limits or Thresholds()), loc))
        logs.append(log)
    sources = {log.manifest.source for log in logs}
    if len(sources) > 1:
        raise LayoutError(f"{logdir}: the runs come from different sources ({', '.join(sorted(sources))}): one target "
                          "holds runs of one kind")
    valid: dict[str, list[int]] = {}
    excluded = []
    for k, ((path, verdict, _), log) in enumerate(zip(runs, logs, strict=True)):
        if verdict.valid:
            valid.setdefault(log.manifest.agent, []).append(k)
        else:
            excluded.append(ExcludedRun(agent=log.manifest.agent, run=str(path), reason="; ".join(verdict.reasons)))
    if not valid:
        raise LayoutError(f"{logdir}: no valid run to make a target of:\n  " + "\n  ".join(
            f"{x.run}: {x.reason}" for x in excluded))
    n_ep = min(len(v) for v in valid.values())
    for agent, ks in valid.items():
        excluded += [ExcludedRun(agent=agent, run=str(runs[k][0]), reason=f"valid, but the other agents have only "
                                 f"{n_ep} valid run(s) (episodes are paired by id)") for k in ks[n_ep:]]
    seconds = max((log.manifest.seconds or (max(s.frames[-1].t for s in log.streams) - log.manifest.start))
                  for log in logs)
    for agent, ks in valid.items():
        for e, k in enumerate(ks[:n_ep]):
            log, loc = logs[k], runs[k][2]
            active = loc.robots[log.manifest.active]
            _write_csv(out, f"episodes/{agent}/{e}.csv",
                       track_table(active, log.manifest.start, log.commands.get(log.manifest.active)))
            folder = f"localization/{agent}/{e}"
            for name, track in loc.robots.items():
                _write_csv(out, f"{folder}/{name}.csv", track_table(track, log.manifest.start, log.commands.get(name)))
            _write(out, f"{folder}/run.json", json.dumps(_run_info(log, loc, runs[k][1]), indent=2))
    try:  # what the logs say must make a valid manifest (an episode's length, names): else one error naming it
        manifest = TargetManifest(
            source=sources.pop(), description=f"localised by proxybench localize from {len(runs)} run(s) of "
                                              f"{len(logs[0].streams)} watchtower(s) ({detector}, {solver})",
            map=_map_ref(m),
            seconds=math.ceil(seconds * 100) / 100, agents=list(valid), episodes=list(range(n_ep)),
            trajectories="episodes/{agent}/{episode}.csv", recorded_with=f"proxybench {__version__} (localize)",
            excluded=excluded)
    except ValidationError as exc:
        raise LayoutError(format_errors(exc, f"{logdir}: the target's manifest", TargetManifest)) from None
    # what targets.manifest.write_manifest writes, written through no link
    _write(out, MANIFEST_NAME, yaml.safe_dump(manifest.model_dump(mode="json", exclude_none=True), sort_keys=False,
                                              allow_unicode=True))
    return LocalizeSummary(out, manifest, runs)


def _map_ref(m: Map) -> str:
    """How the manifest names the map: by name where ``load_map`` finds it so, else its file's absolute path."""
    from proxybench.domain.maps import MapError, load_map

    try:
        same = Path(load_map(m.name).path).resolve() == Path(m.path).resolve()
    except (MapError, OSError):
        same = False
    return m.name if same else str(Path(m.path).resolve())
