"""Trajectories: what one episode did, sampled at the physics rate, as a self-describing Parquet file.

A trajectory holds time, pose and (when known) velocities and applied commands, plus events and a
metadata block. The lane pose is *recomputed from the map* for every trajectory, whether it came from
the simulator, the reality model or a real lab's localisation system, so that all of them are scored
by the same code on the same footing.

Through intersections the lane pose follows the trajectory's route (``route_segment``: the lane the
simulator chose for a privileged agent, else the exit the robot took; see ``proxybench.domain.routes``),
and ``stop_distance`` / ``on_route`` record the stop line ahead and whether the robot is still on its
route, so that the intersection metrics need nothing but the file.

The Parquet file is readable with pandas or polars alone: one row per sample, the metadata as JSON in
the schema metadata under the key ``proxybench``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.domain.events import EPISODE_TERMINATIONS, Event, Termination
from proxybench.domain.kinds import DomainKind
from proxybench.domain.lane_pose import LANE_POSE_FIELDS, lane_poses
from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import Map, load_map
from proxybench.domain.routes import RouteGraph, pin_route, route_columns
from proxybench.messages import shown

__all__ = ["TERMINATIONS", "Event", "Termination", "Trajectory", "TrajectoryError"]

#: why an episode ended: the endings a trajectory may record (``Termination`` less ``robot_failure``)
TERMINATIONS = EPISODE_TERMINATIONS
_CORE = ("t", "x", "y", "theta")
_OPTIONAL = ("v", "omega", "pwm_left", "pwm_right")
_LANE = ("valid", "segment", "along", "lateral", "heading_error", "left_in_lane", "right_in_lane",
         "left_on_road", "right_on_road", "on_road", "tile_i", "tile_j", "curvature")
assert _LANE == LANE_POSE_FIELDS
#: route columns: the lane pinned on intersection tiles (-1 elsewhere), metres to the stop line ahead
#: along the lane (NaN: none), and 1 while the robot's lane continues its route
_ROUTE = ("route_segment", "stop_distance", "on_route")


class TrajectoryError(ValueError):
    """A trajectory (or a file claiming to be one) is unusable; the message names the file and column."""


class _NotSaved(TrajectoryError):
    """A Parquet file without the block :meth:`Trajectory.save` writes: a recorded run, for :meth:`~Trajectory.read`."""


@dataclass
class Trajectory:
    """One episode: ``columns`` maps names to equal-length 1-D arrays (see ``_CORE``, ``_OPTIONAL``, lane
    pose fields); ``meta`` holds θ, agent, map, episode spec, seed, versions and ``source`` (a ``DomainKind``:
    "simulation", "reality-model" or "recorded"; on a robot node, the node's own word); ``events`` are
    :class:`Event` records (``{t, kind, message, ...}`` objects in the file); ``termination`` says why the
    episode ended.
    """

    columns: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)
    events: list[Event] = field(default_factory=list)
    termination: Termination = Termination.TIMEOUT

    def __post_init__(self) -> None:
        self.termination = _termination(self.termination, "trajectory")

    # -- construction ----------------------------------------------------------------------------

    @classmethod
    def from_poses(
        cls, m: Map, t: np.ndarray, pose: np.ndarray, *, extra: dict[str, np.ndarray] | None = None,
        meta: dict[str, Any] | None = None, events: list[Event] | None = None,
        termination: Termination = Termination.TIMEOUT, wheel_distance: float = 0.102, origin: str = "trajectory",
    ) -> Trajectory:
        """Build from times [s] and poses (T, 3) [m, m, rad]; the lane pose is computed from the map."""
        t = np.asarray(t, dtype=np.float64)
        pose = np.asarray(pose, dtype=np.float64).reshape(-1, 3)
        _check_samples(t, pose, origin)
        net = LaneNetwork(m)
        lane = lane_poses(net, pose, wheel_distance)
        cols: dict[str, np.ndarray] = {"t": t, "x": pose[:, 0], "y": pose[:, 1], "theta": pose[:, 2]}
        for name, arr in (extra or {}).items():
            arr = np.asarray(arr, dtype=np.float64)
            if arr.shape != t.shape:
                raise TrajectoryError(f"{origin}: column {name!r} has {arr.size} samples, time has {t.size}")
            cols[name] = arr
        graph = RouteGraph(net)
        route, visits = pin_route(graph, pose, lane, wheel_distance, cols.get("route_segment"))
        for k, name in enumerate(LANE_POSE_FIELDS):
            cols[name] = lane[:, k]
        cols["route_segment"] = route.astype(np.float64)
        cols.update(route_columns(graph, lane))
        termination = _termination(termination, origin)
        meta = {"map": m.name, **(meta or {})}
        if visits:
            meta["route"] = [{"t": float(t[v.pop("sample")]), **v} for v in visits]
        return cls(cols, meta, list(events or []), termination)

    # -- access ----------------------------------------------------------------------------------

    def __len__(self) -> int:
        return int(self.columns["t"].size)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise KeyError(f"trajectory has no column {name!r}; it has {', '.join(self.columns)}") from None

    @property
    def duration(self) -> float:
        """Time from the first to the last sample [s]."""
        t = self.columns["t"]
        return float(t[-1] - t[0]) if t.size else 0.0

    @property
    def lane(self) -> np.ndarray:
        """(T, LP.N) lane-pose rows, the layout the lane-pose kernel writes."""
        return np.stack([self.columns[name] for name in LANE_POSE_FIELDS], axis=1)

    def event(self, kind: str) -> Event | None:
        """The first event of ``kind`` (e.g. ``Termination.COLLISION``), or None."""
        return next((e for e in self.events if e.kind == kind), None)

    @property
    def failure(self) -> Event | None:
        """The agent's failure (its ``agent_failure`` event: message, reason, a node's exit status and last
        stderr lines), or None when the agent did not fail."""
        return self.event(Termination.AGENT_FAILURE)

    def pose(self) -> np.ndarray:
        return np.stack([self.columns["x"], self.columns["y"], self.columns["theta"]], axis=1)

    # -- files -----------------------------------------------------------------------------------

    def save(self, path: str | Path) -> Path:
        """Write Parquet atomically (temporary file + rename): a crash never leaves half a file."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        path = Path(path)
        table = pa.table({k: pa.array(v) for k, v in self.columns.items()})
        block = {"meta": self.meta, "events": [e.to_dict() for e in self.events], "termination": self.termination,
                 "format": 1}
        table = table.replace_schema_metadata({b"proxybench": json.dumps(block, default=_jsonable).encode()})
        tmp = path.with_name(f".{path.name}.tmp")
        pq.write_table(table, tmp, compression="zstd")
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> Trajectory:
        """Read a file written by :meth:`save`."""
        import pyarrow.parquet as pq

        path = Path(path)
        try:
            table = pq.read_table(path)
        except (OSError, ValueError) as exc:
            raise TrajectoryError(f"{path}: not a readable Parquet file ({exc})") from exc
        raw = (table.schema.metadata or {}).get(b"proxybench")
        if raw is None:
            raise _NotSaved(f"{path}: no proxybench metadata block (import recorded runs with from_file)")
        block = json.loads(raw)
        cols = {name: table.column(name).to_numpy() for name in table.column_names}
        missing = [c for c in (*_CORE, *LANE_POSE_FIELDS) if c not in cols]
        if missing:
            raise TrajectoryError(f"{path}: missing column(s) {', '.join(missing)}")
        return cls(cols, block.get("meta", {}), _events(block.get("events", []), str(path)),
                   _termination(block.get("termination", Termination.TIMEOUT), str(path)))

    @classmethod
    def read(cls, path: str | Path, m: Map | str) -> Trajectory:
        """A file as :meth:`save` wrote it, else a recorded run imported against the map ``m`` (:meth:`from_file`)."""
        path = Path(path)
        if path.suffix == ".parquet":
            try:
                return cls.load(path)
            except _NotSaved:
                pass
        return cls.from_file(path, m)

    @classmethod
    def from_file(cls, path: str | Path, m: Map | str, *, meta: dict[str, Any] | None = None) -> Trajectory:
        """Import a recorded run (CSV or Parquet with columns ``t`` [s], ``x``, ``y`` [m], ``theta`` [rad] in
        the map frame, as a localisation system such as the Autolab's watchtowers produces).

        The lane pose is recomputed from the map; a pose off the map ends the run there (``left_map``).
        """
        path = Path(path)
        m = load_map(m) if isinstance(m, str) else m
        data = _read_table(path)
        aliases = {"time": "t", "timestamp": "t", "heading": "theta", "yaw": "theta"}
        data = {aliases.get(k, k): v for k, v in data.items()}
        missing = [c for c in _CORE if c not in data]
        if missing:
            raise TrajectoryError(
                f"{path}: missing column(s) {', '.join(missing)}; found {', '.join(data) or 'none'} "
                "(need t [s], x [m], y [m], theta [rad] in the map frame)"
            )
        t = data["t"] - data["t"][0] if data["t"].size else data["t"]
        pose = np.stack([data["x"], data["y"], data["theta"]], axis=1)
        _check_samples(t, pose, str(path))
        w, h = m.size_m
        off = ~((pose[:, 0] >= 0) & (pose[:, 0] < w) & (pose[:, 1] >= 0) & (pose[:, 1] < h))
        termination, events = Termination.TIMEOUT, []
        if off.any():
            k = int(np.argmax(off))
            if k == 0:
                raise TrajectoryError(f"{path}: the first pose ({pose[0, 0]:.3f}, {pose[0, 1]:.3f}) m is off the "
                                      f"map {m.name!r} ({w:.2f} × {h:.2f} m): wrong map or frame?")
            events.append(Event(float(t[k]), Termination.LEFT_MAP, f"pose {k} is off the map"))
            t, pose, termination = t[:k], pose[:k], Termination.LEFT_MAP
        extra = {k: v[: t.size] for k, v in data.items() if k in _OPTIONAL}
        info = {"source": DomainKind.RECORDED, "file": str(path), **(meta or {})}
        return cls.from_poses(m, t, pose, extra=extra, meta=info, events=events, termination=termination,
                              origin=str(path))


def _termination(value: object, origin: str) -> Termination:
    """``value`` as a trajectory's :class:`Termination`; an unknown one is an error naming ``origin``."""
    if value not in TERMINATIONS:
        raise TrajectoryError(f"{origin}: unknown termination {value!r} (one of {', '.join(TERMINATIONS)})")
    return Termination(value)


def _events(raw: object, origin: str) -> list[Event]:
    """The events of a file's metadata block; a malformed one is an error naming ``origin`` and the event."""
    if not isinstance(raw, list):
        raise TrajectoryError(f"{origin}: events must be a list, got {type(raw).__name__}")
    out = []
    for k, data in enumerate(raw):
        try:
            out.append(Event.from_dict(data))
        except ValueError as exc:
            raise TrajectoryError(f"{origin}: event {k}: {exc}") from None
    return out


def _check_samples(t: np.ndarray, pose: np.ndarray, origin: str) -> None:
    if t.ndim != 1 or t.size == 0:
        raise TrajectoryError(f"{origin}: no samples")
    if pose.shape[0] != t.size:
        raise TrajectoryError(f"{origin}: {pose.shape[0]} poses for {t.size} time stamps")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(pose))):
        bad = int(np.argmax(~(np.isfinite(t) & np.isfinite(pose).all(axis=1))))
        raise TrajectoryError(f"{origin}: sample {bad} is not a finite number")
    if t.size > 1 and np.any(np.diff(t) <= 0):
        k = int(np.argmax(np.diff(t) <= 0)) + 1
        raise TrajectoryError(f"{origin}: time is not increasing at sample {k} ({shown(t[k - 1])} → {shown(t[k])})")


def _read_table(path: Path) -> dict[str, np.ndarray]:
    if not path.exists():
        raise TrajectoryError(f"{path}: no such file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".parquet":
            import pyarrow.parquet as pq

            table = pq.read_table(path)
            return {n: np.asarray(table.column(n).to_numpy(), dtype=np.float64) for n in table.column_names}
        if suffix in (".csv", ".txt"):
            import pyarrow.csv as pcsv

            table = pcsv.read_csv(path)
            return {n.strip(): np.asarray(table.column(n).to_numpy(), dtype=np.float64) for n in table.column_names}
    except (OSError, ValueError) as exc:  # pyarrow raises ArrowInvalid (a ValueError) on bad content
        raise TrajectoryError(f"{path}: cannot read ({exc})") from exc
    raise TrajectoryError(f"{path}: unknown trajectory format {suffix!r} (use .csv or .parquet)")


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, float) and math.isnan(obj):
        return None
    return str(obj)
