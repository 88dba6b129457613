"""A recorded target: a directory of episodes from a lab (or from ``proxybench target record``), checked.

Two kinds, after the manifest (:mod:`proxybench.targets.manifest`):

- **trajectories**: one file per (agent, episode), CSV or Parquet with ``t`` [s], ``x``, ``y`` [m], ``theta``
  [rad] in the map frame (``time``/``timestamp``, ``heading``/``yaw`` are accepted too) and optionally ``v``,
  ``omega``, ``pwm_left``, ``pwm_right``; proxybench's own trajectory files are read as saved. The episode's
  start pose is its first row, so proxies can replay each episode from the same start.
- **metrics**: one table with ``agent``, ``episode`` and one column per task metric, for labs that kept only
  scores (no start poses then: proxies draw their starts from the episode seeds).

Every problem names the file, the row (1 = the first data row; for CSV also the line) and the column:
missing columns, files or agents, numbers that are not finite (in any column: a trajectory holds numbers
only), time that does not increase, a first pose off the map, a file recorded on another map, unknown
metrics. :func:`check_recording` collects them all; :func:`load_recording` raises :class:`TargetError`
with them.

A recording may come from another lab, so it is read as untrusted input: every path it names (the
trajectory files, ``map``, ``metrics_table``) lies inside its folder, through no link
(:func:`proxybench.untrusted.inside`), and each file's size, rows and columns are checked against
:data:`LIMITS` from its metadata (Parquet's footer, the CSV's size) before it is read.
"""

from __future__ import annotations

import difflib
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.domain.events import Event, Termination
from proxybench.messages import shown
from proxybench.targets.base import id_ranges
from proxybench.targets.manifest import MANIFEST_NAME, TargetError, TargetManifest, load_manifest
from proxybench.untrusted import UntrustedInputError, inside

__all__ = ["LIMITS", "CheckReport", "FileLimits", "RecordedEpisode", "Recording", "check_recording",
           "load_recording", "resolve_map"]

_ALIASES = {"time": "t", "timestamp": "t", "heading": "theta", "yaw": "theta"}
_CORE = ("t", "x", "y", "theta")
_OPTIONAL = ("v", "omega", "pwm_left", "pwm_right")
_MAX_PROBLEMS = 30
#: columns of a metrics table that describe a row rather than score it (``proxybench score --out`` writes them)
_INFO_COLUMNS = ("agent", "episode", "file", "source", "termination", "seed", "notes")


@dataclass(frozen=True)
class FileLimits:
    """What one file of a recording may hold, checked before it is read."""

    rows: int = 2_000_000  # samples of one trajectory (an hour at 500 Hz) or rows of a metrics table
    columns: int = 256
    csv_bytes: int = 256 << 20
    parquet_bytes: int = 512 << 20  # uncompressed, as its footer declares
    map_bytes: int = 4 << 20


LIMITS = FileLimits()


@dataclass
class RecordedEpisode:
    """One (agent, episode) of a recording: its scores, start pose and seed."""

    agent: str
    episode: int
    seed: int
    pose: tuple[float, float, float] | None
    file: str | None
    scores: dict[str, float]
    termination: Termination = Termination.TIMEOUT
    duration: float = float("nan")


@dataclass
class CheckReport:
    """What :func:`check_recording` found: problems (the target is unusable), notes, and the episodes."""

    root: Path
    manifest: TargetManifest | None
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    episodes: list[RecordedEpisode] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


@dataclass
class Recording:
    """A checked recorded target: manifest, map reference and every episode's scores."""

    root: Path
    manifest: TargetManifest
    map_ref: str
    episodes: dict[tuple[str, int], RecordedEpisode]
    metrics: tuple[str, ...]

    @property
    def agents(self) -> list[str]:
        return list(self.manifest.agents)

    def select(self, agents: list[str], episodes: int | Sequence[int] | None) -> list[RecordedEpisode]:
        """Episodes of ``agents`` (each must be recorded): the first ``episodes`` ids of the manifest (a count),
        those ids (a list: a fit / held-out split of one recording), or all (None)."""
        missing = [a for a in agents if a not in self.manifest.agents]
        if missing:
            raise TargetError(f"{self.root}: agent(s) {', '.join(map(repr, missing))} not in the recording "
                              f"(it has {', '.join(self.manifest.agents)})")
        ids = list(self.manifest.episodes)
        if isinstance(episodes, int):
            if episodes > len(ids):
                raise TargetError(f"episodes: {episodes} asked, the recording at {self.root} has {len(ids)}")
            ids = ids[:episodes]
        elif episodes is not None:
            absent = [e for e in episodes if e not in ids]
            if absent:
                raise TargetError(f"episodes: {', '.join(map(str, absent))} not in the recording at {self.root} (it "
                                  f"has {id_ranges(ids)})")
            ids = list(episodes)
        return [self.episodes[(a, e)] for a in agents for e in ids]


def resolve_map(root: Path, name: str) -> str:
    """A map file of the recording (relative to the manifest, inside its folder, no link) as an absolute path;
    a built-in name as it is. Raises :class:`~proxybench.untrusted.UntrustedInputError` for a path that leaves
    the folder, and for a map file over :data:`LIMITS`."""
    if "/" not in name and "\\" not in name and Path(name).suffix not in (".yaml", ".yml"):
        return name
    path = inside(root, name, field="map")
    if path.is_file() and path.stat().st_size > LIMITS.map_bytes:
        raise UntrustedInputError(f"map: {path}: {path.stat().st_size} bytes; a map file holds at most "
                                  f"{LIMITS.map_bytes}")
    return str(path)


def _row(k: int, csv: bool) -> str:
    """Human row number of sample ``k`` (0-based): data row k + 1, and the file line for CSV."""
    return f"row {k + 1} (line {k + 2})" if csv else f"row {k + 1}"


def _check_size(path: Path) -> None:
    """Refuse a file over :data:`LIMITS` from what it declares (Parquet's footer; a CSV's size), unread."""
    if path.suffix.lower() == ".parquet":
        import pyarrow.parquet as pq

        meta = pq.ParquetFile(path).metadata
        declared = sum(meta.row_group(k).total_byte_size for k in range(meta.num_row_groups))
        if meta.num_rows > LIMITS.rows:
            raise TargetError(f"{path}: {meta.num_rows} rows; a file of a recording holds at most {LIMITS.rows}")
        if meta.num_columns > LIMITS.columns:
            raise TargetError(f"{path}: {meta.num_columns} columns; at most {LIMITS.columns}")
        if declared > LIMITS.parquet_bytes:
            raise TargetError(f"{path}: {declared} bytes uncompressed; at most {LIMITS.parquet_bytes}")
    elif os.stat(path).st_size > LIMITS.csv_bytes:
        raise TargetError(f"{path}: {os.stat(path).st_size} bytes; a CSV file holds at most {LIMITS.csv_bytes}")


def _read_columns(path: Path) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """Columns of a CSV/Parquet file as object/number arrays, and proxybench's metadata block if any."""
    import json

    suffix = path.suffix.lower()
    try:
        _check_size(path)
        if suffix == ".parquet":
            import pyarrow.parquet as pq

            table = pq.read_table(path)
            raw = (table.schema.metadata or {}).get(b"proxybench")
            block = json.loads(raw) if raw is not None else None
            return {n: table.column(n).to_numpy(zero_copy_only=False) for n in table.column_names}, block
        if suffix in (".csv", ".txt"):
            import pandas as pd

            df = pd.read_csv(path, skipinitialspace=True, nrows=LIMITS.rows + 1)
            if len(df) > LIMITS.rows or len(df.columns) > LIMITS.columns:
                raise TargetError(f"{path}: more than {LIMITS.rows} rows or {LIMITS.columns} columns")
            return {str(c).strip(): df[c].to_numpy() for c in df.columns}, None
    except TargetError:
        raise
    except (OSError, ValueError) as exc:  # pyarrow's ArrowInvalid and pandas' ParserError are ValueErrors
        raise TargetError(f"{path}: cannot read ({str(exc).splitlines()[0]})") from None
    raise TargetError(f"{path}: unknown file format {suffix!r} (use .csv or .parquet)")


def _numbers(path: Path, name: str, values: Any, csv: bool) -> tuple[np.ndarray | None, str | None]:
    """Column ``name`` as float64, or a problem naming the first cell that is not a finite number."""
    import pandas as pd

    arr = pd.to_numeric(pd.Series(values), errors="coerce").to_numpy(dtype=np.float64)
    bad = ~np.isfinite(arr)
    if bad.any():
        k = int(np.argmax(bad))
        v = values[k]
        what = "empty (or NaN)" if isinstance(v, float | np.floating) and np.isnan(v) else \
            f"{shown(v)} is not a finite number"
        return None, f"{path}: {_row(k, csv)}, column {name!r}: {what}"
    return arr, None


def _check_trajectory_columns(path: Path, cols: dict[str, Any], csv: bool,
                              own_file: bool = False) -> tuple[dict[str, np.ndarray], list[str]]:
    """The core and optional columns as numbers, and every problem (an extra column of text, too: readers of
    the file later convert every column; ``own_file``: proxybench's own trajectory, whose columns it knows)."""
    data = {_ALIASES.get(k, k): v for k, v in cols.items()}
    problems = []
    missing = [c for c in _CORE if c not in data]
    if missing:
        return {}, [f"{path}: missing column(s) {', '.join(missing)}; found {', '.join(cols) or 'none'} (need t [s], "
                    "x [m], y [m], theta [rad] in the map frame)"]
    out: dict[str, np.ndarray] = {}
    for name in (*_CORE, *(c for c in _OPTIONAL if c in data)):
        arr, problem = _numbers(path, name, data[name], csv)
        if problem:
            problems.append(problem)
        else:
            out[name] = arr
    for name in (c for c in data if c not in _CORE and c not in _OPTIONAL and not own_file):
        _, problem = _numbers(path, name, data[name], csv)  # an extra column is ignored, but must be numbers
        if problem:
            problems.append(f"{problem} (a trajectory file holds numbers only; remove the column {name!r})")
    if "t" in out:
        t = out["t"]
        if t.size == 0:
            problems.append(f"{path}: no rows")
        elif t.size > 1 and np.any(np.diff(t) <= 0):
            k = int(np.argmax(np.diff(t) <= 0)) + 1
            problems.append(f"{path}: {_row(k, csv)}, column 't': time is not increasing ({shown(t[k - 1])} → "
                            f"{shown(t[k])} s)")
    return out, problems


def _episode_file(root: Path, manifest: TargetManifest, agent: str, episode: int) -> Path:
    return inside(root, manifest.trajectory_file(agent, episode), field="trajectories")


def _load_trajectory(root: Path, manifest: TargetManifest, m, agent: str, episode: int,
                     metrics: tuple[str, ...]) -> tuple[RecordedEpisode | None, list[str], list[str]]:
    """Check and score one episode file: (episode, problems, notes)."""
    from proxybench.tasks.metrics import METRICS
    from proxybench.tasks.trajectory import Trajectory, TrajectoryError

    try:
        path = _episode_file(root, manifest, agent, episode)
    except UntrustedInputError as exc:
        return None, [f"{root / MANIFEST_NAME}: {exc}"], []
    if not path.is_file():
        return None, [f"{path}: missing (agent {agent!r}, episode {episode}; pattern {manifest.pattern!r})"], []
    try:
        cols, block = _read_columns(path)
    except TargetError as exc:
        return None, [str(exc)], []
    csv = path.suffix.lower() != ".parquet"
    data, problems = _check_trajectory_columns(path, cols, csv, own_file=block is not None)
    notes: list[str] = []
    meta = (block or {}).get("meta", {})
    if block is not None:
        if meta.get("map") not in (None, m.name):
            problems.append(f"{path}: map mismatch: recorded on {meta['map']!r}, the manifest says {m.name!r}")
        if meta.get("agent") not in (None, agent):
            problems.append(f"{path}: holds agent {meta['agent']!r}'s run, the manifest's pattern says {agent!r}")
    if problems:
        return None, problems, notes
    pose0 = (float(data["x"][0]), float(data["y"][0]), float(data["theta"][0]))
    w, h = m.size_m
    off = ~((data["x"] >= 0) & (data["x"] < w) & (data["y"] >= 0) & (data["y"] < h))
    if off[0]:
        return None, [f"{path}: {_row(0, csv)}, columns 'x', 'y': the first pose ({pose0[0]:.3f}, {pose0[1]:.3f}) m "
                      f"is off the map {m.name!r} ({w:.2f} × {h:.2f} m): wrong map, units or frame?"], notes
    if off.any() and block is None:
        k = int(np.argmax(off))
        notes.append(f"{path}: the robot left the map at {_row(k, csv)} (t = {data['t'][k]:g} s); the run ends there")
    try:
        if block is not None and "valid" in cols:
            traj = Trajectory.load(path)
        else:
            traj = Trajectory.from_file(path, m, meta={"agent": agent, "episode": episode})
    except TrajectoryError as exc:
        return None, [str(exc)], notes
    traj.meta["episode_seconds"] = manifest.seconds
    if traj.termination is Termination.TIMEOUT:
        _mark_early_end(traj, manifest.seconds, m)
    if traj.duration > manifest.seconds + 0.5:
        notes.append(f"{path}: {traj.duration:.1f} s long, longer than the manifest's seconds ({manifest.seconds:g}); "
                     "survival_time is capped there")
    seed = int(meta.get("seed", manifest.seed * 10_000 + episode))
    scores = {name: METRICS[name](traj) for name in metrics}
    return RecordedEpisode(agent, episode, seed, pose0, str(path), scores, traj.termination, traj.duration), [], notes


def _mark_early_end(traj, seconds: float, m) -> None:
    """An imported run whose samples stop before the episode's length ended early: off the road when its last
    pose is off the drivable tiles (the simulator's rule), else for a reason the file does not say.

    A run that went the whole length is sampled from its first frame to its last, which may each be a frame
    period inside the episode (a localised run: the first pose at 0.13 s, the last at 9.80 s of 10 s, at a
    watchtower's 5 frames/s): up to two frame periods short is the whole length. The period is the slow end of
    the sampling (90th percentile of the steps: merged cameras sample unevenly), never under the median."""
    t = traj["t"]
    steps = np.diff(t)
    period = float(max(np.median(steps), np.percentile(steps, 90))) if steps.size else 0.0
    if seconds - traj.duration <= max(2 * period, 0.1):  # the recording runs to the end (within a frame each side)
        traj.meta["ran_whole_episode"] = True  # survival_time: the episode's length, not the last sample's time
        return
    x, y = float(traj["x"][-1]), float(traj["y"][-1])
    tile = m.tile_at(x, y)
    if tile is None or not tile.drivable:
        kind, why = Termination.OFF_ROAD, f"its last pose ({x:.2f}, {y:.2f}) m is off the road"
    else:
        kind, why = Termination.ENDED_EARLY, "the file does not say why"
    traj.termination = kind
    traj.events.append(Event(traj.duration, kind, f"the recording ends at {traj.duration:.2f} s of {seconds:g} s; "
                                                  f"{why}"))


def _metric_problem(name: str) -> str | None:
    from proxybench.tasks.metrics import METRICS

    if name in METRICS:
        return None
    close = difflib.get_close_matches(name, list(METRICS), n=1)
    return f"{name!r} is not a known metric" + (f" (did you mean {close[0]!r}?)" if close else
                                                 f"; known: {', '.join(METRICS)}")


def _load_table(root: Path, manifest: TargetManifest, metrics: tuple[str, ...] | None,
                problems: list[str]) -> tuple[list[RecordedEpisode], tuple[str, ...]]:
    assert manifest.metrics_table is not None
    try:
        path = inside(root, manifest.metrics_table, field="metrics_table")
    except UntrustedInputError as exc:
        problems.append(f"{root / MANIFEST_NAME}: {exc}")
        return [], ()
    if not path.is_file():
        problems.append(f"{path}: missing (the manifest's metrics_table)")
        return [], ()
    try:
        cols, _ = _read_columns(path)
    except TargetError as exc:
        problems.append(str(exc))
        return [], ()
    csv = path.suffix.lower() != ".parquet"
    for need in ("agent", "episode"):
        if need not in cols:
            problems.append(f"{path}: missing column {need!r} (columns: agent, episode, then one per metric)")
    if problems:
        return [], ()
    names = [c for c in cols if c not in _INFO_COLUMNS]
    for c in names:
        p = _metric_problem(c)
        if p:
            problems.append(f"{path}: column {c!r}: {p}")
    if not names:
        problems.append(f"{path}: no metric columns")
    wanted = tuple(names) if metrics is None else metrics
    for c in wanted:
        if c not in cols:
            problems.append(f"{path}: no column for the metric {c!r} (it has {', '.join(names) or 'none'})")
    values = {}
    for c in wanted:
        if c in cols:
            arr, p = _numbers(path, c, cols[c], csv)
            if p:
                problems.append(p)
            values[c] = arr
    episodes, p = _numbers(path, "episode", cols["episode"], csv)
    if p:
        problems.append(p)
    if problems:
        return [], ()
    assert episodes is not None
    seen: dict[tuple[str, int], int] = {}
    out = []
    for k, (agent, ep) in enumerate(zip(cols["agent"], episodes, strict=True)):
        agent, ep = str(agent).strip(), int(ep)
        if agent not in manifest.agents:
            problems.append(f"{path}: {_row(k, csv)}, column 'agent': {agent!r} is not in the manifest's agents")
            continue
        if ep not in manifest.episodes:
            problems.append(f"{path}: {_row(k, csv)}, column 'episode': {ep} is not in the manifest's episodes")
            continue
        if (agent, ep) in seen:
            problems.append(f"{path}: {_row(k, csv)}: agent {agent!r} episode {ep} again (first at "
                            f"{_row(seen[(agent, ep)], csv)})")
            continue
        seen[(agent, ep)] = k
        out.append(RecordedEpisode(agent, ep, manifest.seed * 10_000 + ep, None, None,
                                   {c: float(values[c][k]) for c in wanted}))
    for a in manifest.agents:
        lacking = [e for e in manifest.episodes if (a, e) not in seen]
        if lacking:
            problems.append(f"{path}: missing agent {a!r}, episode(s) {', '.join(map(str, lacking))}")
    return out, wanted


def check_recording(root: str | Path, metrics: tuple[str, ...] | None = None) -> CheckReport:
    """Check every file of a recorded target and score its episodes; collect every problem found.

    ``metrics``: the task metrics to score (default: the table's columns, or survival time and distance).
    """
    from proxybench.domain.maps import MapError, load_map

    root = Path(root)
    report = CheckReport(root, None)
    try:
        manifest = load_manifest(root)
    except TargetError as exc:
        report.problems.extend(str(exc).splitlines())
        return report
    report.manifest = manifest
    report.notes += [f"excluded: {x.agent}, {x.run}: {x.reason}" for x in manifest.excluded]
    if root.is_file():
        root = root.parent
        report.root = root
    for name in metrics or ():
        p = _metric_problem(name)
        if p:
            report.problems.append(f"metrics: {p}")
    if report.problems:
        return report
    if manifest.kind == "metrics":
        report.episodes, _ = _load_table(root, manifest, metrics, report.problems)
        return report
    try:
        m = load_map(resolve_map(root, manifest.map))
    except UntrustedInputError as exc:
        report.problems.append(f"{root / MANIFEST_NAME}: {exc}")
        return report
    except (MapError, FileNotFoundError) as exc:
        report.problems.append(f"{root / MANIFEST_NAME}: map: {exc}")
        return report
    wanted = metrics or ("survival_time", "driven_lanedir_consec")
    for agent in manifest.agents:
        for ep in manifest.episodes:
            got, problems, notes = _load_trajectory(root, manifest, m, agent, ep, wanted)
            report.problems += problems
            report.notes += notes
            if got is not None:
                report.episodes.append(got)
            if len(report.problems) >= _MAX_PROBLEMS:
                report.notes.append(f"stopped after {_MAX_PROBLEMS} problems")
                return report
    return report


def load_recording(root: str | Path, metrics: tuple[str, ...] | None = None) -> Recording:
    """A recorded target ready for experiments; :class:`TargetError` listing every problem otherwise."""
    report = check_recording(root, metrics)
    if not report.ok:
        shown = report.problems[:_MAX_PROBLEMS]
        more = len(report.problems) - len(shown)
        raise TargetError(f"{report.root}: not a usable recorded target ({len(report.problems)} problem(s)):\n  "
                          + "\n  ".join(shown) + (f"\n  … and {more} more" if more > 0 else ""))
    assert report.manifest is not None
    manifest = report.manifest
    got = tuple(report.episodes[0].scores) if report.episodes else tuple(metrics or ())
    return Recording(report.root, manifest, resolve_map(report.root, manifest.map),
                     {(e.agent, e.episode): e for e in report.episodes}, got)
