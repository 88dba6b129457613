"""proxybench's simulator as the backend of a robot node: ``proxybench robot serve``.

:class:`SimRobot` is a :class:`~proxybench.protocol.robot_backend.RobotBackend` over a
:class:`~proxybench.domain.simulator.Simulator` of one robot, so that
:class:`~proxybench.protocol.robot_node.RobotNode` serves a *simulated* Duckiebot: the reference for physical
robots' bridges, a test double the runner cannot tell from one (except that it says ``kind:
"simulation"``), and a simulator AIDO's experiment manager accepts. Driven through the protocol it gives
exactly the in-process trajectory: it ends an episode by the runner's rule (``domain.episode_end``) and
reports the physics-rate trace the in-process runner records.

With ``streams`` (``proxybench robot serve --watchtowers``: a stand-in lab) the robot's world also holds the lab's
fixtures (its ground tags) and its fixed cameras are rendered after every frame from the episode's first step
on, each frame handed to the spec's sink (served as DTPS camera topics, :mod:`proxybench.autolab.served`): a lab's
watchtowers watching a robot node.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.domain.dynamics import ST, TRACE_FIELDS
from proxybench.domain.episode_end import end_event, ended
from proxybench.domain.events import Event
from proxybench.domain.fixed_cameras import FixedCameraRig
from proxybench.domain.lane_pose import LanePose
from proxybench.domain.maps import Map, MapError, MapObject, load_map, parse_map
from proxybench.domain.params import DomainParams
from proxybench.domain.routes import RouteInfo
from proxybench.domain.simulator import Simulator
from proxybench.domain.topdown import top_down
from proxybench.protocol import robot_wire
from proxybench.protocol.robot_backend import BackendState, FrameStep
from proxybench.runner.streams import StreamRecorder, StreamSpec

__all__ = ["SimRobot"]

_TRACE_IDX = [TRACE_FIELDS.index(k) for k in robot_wire.TRACE_COLUMNS[1:]]
_MAX_SIMS = 4


def _map_text(m: Map) -> str | None:
    path = Path(m.path)
    return path.read_text(encoding="utf-8") if path.is_file() else None


class SimRobot:
    """One simulated robot with θ ``params`` (default :class:`DomainParams`); ``map_``: a map to build the
    simulator for up front (``set_map`` with its text then costs nothing; other maps are built when set);
    ``streams``: fixed cameras of its world, rendered to their sink every frame (see the module)."""

    def __init__(self, params: DomainParams | None = None, map_: Map | str | None = None,
                 streams: StreamSpec | None = None):
        self.params = params or DomainParams()
        self.streams = streams
        self._fixtures: tuple[MapObject, ...] = () if streams is None else tuple(streams.fixtures)
        self._recorder: StreamRecorder | None = None
        self._rig: FixedCameraRig | None = None  # the fixed cameras' renderers, built before an episode's start
        self.frame_dt = 1.0 / self.params.frame_rate
        self.encoder_resolution = self.params.encoder_resolution
        self._sims: dict[tuple[str, tuple[MapObject, ...]], Simulator] = {}
        self.sim: Simulator | None = None
        self._text: str | None = None
        self._trace = np.zeros((1, self.params.substeps, len(TRACE_FIELDS)))
        if map_ is not None:
            m = load_map(map_) if isinstance(map_, str) else map_
            text = _map_text(m)
            if text is None:
                raise ValueError(f"map {m.name!r} has no source file, so set_map could never select it")
            self._sims[(text, self._fixtures)] = self._build(dataclasses.replace(m, objects=m.objects
                                                                                 + self._fixtures))

    def _build(self, m: Map) -> Simulator:
        """A simulator for ``m``, its compiled kernels loaded (or compiled) now, within the caller's init
        timeout, rather than at the first frame, within its step timeout; reset prepares each episode."""
        sim = Simulator(m, self.params)
        sim.render()
        sim.step(np.zeros((1, 2)))
        return sim

    def _simulator(self, text: str, extra: tuple[MapObject, ...] = ()) -> Simulator:
        """The simulator of map ``text`` with ``extra`` objects (parked robots, duckies), built once."""
        key = (text, extra)
        if key not in self._sims:
            try:
                m = parse_map(text, path="<set_map.map_data>", name="set_map")
            except MapError as exc:
                raise ValueError(f"set_map: map_data is not a valid map:\n{exc}") from exc
            if extra:
                m = dataclasses.replace(m, objects=m.objects + extra)
            if len(self._sims) >= _MAX_SIMS:
                self._sims.pop(next(iter(self._sims)))
            self._sims[key] = self._build(m)
        return self._sims[key]

    # ------------------------------------------------------------------------------- RobotBackend
    def set_map(self, text: str) -> None:
        self.sim = self._simulator(text, self._fixtures)
        self._text = text

    def reset(self, seed: int, pose: tuple[float, float, float] | None, route: list[str] | None,
              objects: tuple[MapObject, ...], camera: bool = True) -> None:
        self.close_streams()
        if objects:
            self.sim = self._simulator(self._text, self._fixtures + tuple(objects))
        self.sim.reset(0, seed, pose, route)
        if self.streams is not None and self.streams.cameras and (self._rig is None or self._rig.sim is not self.sim):
            self._rig = FixedCameraRig(self.sim, self.streams.cameras)  # now, not at the first command (its clock)

    def step_frame(self, pwm: np.ndarray) -> FrameStep:
        sim = self.sim
        first_tick = int(sim.frame_index[0]) * sim.substeps
        lanes = (int(sim.routes.pin[0]), int(sim.routes.next[0]))
        if self.streams is not None and self._recorder is None:  # the recording begins with the first command
            self._recorder = StreamRecorder(sim, self.streams, Path("episode"), rig=self._rig)
        sim.step(pwm[None], self._trace)
        if self._recorder is not None:
            self._recorder.frame(self.time())
        block = np.empty((sim.substeps, len(robot_wire.TRACE_COLUMNS)))
        block[:, 0] = (np.arange(1, sim.substeps + 1) + first_tick) * sim.params[0].physics_dt  # the runner's t
        block[:, 1:] = self._trace[0][:, _TRACE_IDX]
        return FrameStep(block, lanes)

    def close_streams(self) -> None:
        """End the episode's recording of the fixed cameras, if one runs (its sink ends the episode)."""
        recorder, self._recorder = self._recorder, None
        if recorder is not None:
            recorder.close()

    def time(self) -> float:
        return float(self.sim.time[0])

    def camera(self) -> np.ndarray:
        return self.sim.render()[0]

    def state(self) -> BackendState:
        sim = self.sim
        s = sim.state[0]
        return BackendState((float(s[ST.X]), float(s[ST.Y]), float(s[ST.THETA])), float(s[ST.V]), float(s[ST.OMEGA]),
                            (float(s[ST.WHEEL_L]), float(s[ST.WHEEL_R])), bool(sim.off_road[0]),
                            bool(sim.collided[0]))

    def lane(self) -> tuple[LanePose, RouteInfo | None]:
        sim = self.sim
        return LanePose.from_row(sim.lane[0]), sim.routes.info(0, sim.lane[0])

    def route_choices(self) -> dict[str, Any]:
        routes = self.sim.routes
        return {"active": bool(routes.active), "choices": routes.choices[0]}

    def ending(self) -> Event | None:
        return end_event(self.sim, 0) if ended(self.sim)[0] else None  # the runner's rule: equal trajectories

    def info(self) -> dict[str, Any]:
        p = self.params
        return {"kind": "simulation", "frame_rate": float(p.frame_rate), "physics_rate": float(p.physics_rate),
                "wheel_distance": float(p.wheel_distance), "encoder_resolution": float(p.encoder_resolution),
                "image_width": p.image_width, "image_height": p.image_height, "params": p.model_dump(mode="json")}

    def description(self) -> str:
        p = self.params
        return (f"proxybench simulator node: ONE SIMULATED Duckiebot (not a real robot) behind AIDO's simulator "
                f"protocol. Camera {p.image_width}x{p.image_height} at {p.frame_rate:g} Hz, physics "
                f"{p.physics_rate:g} Hz. Extensions (opt-in with yaml_payload proxybench: true): exact state, "
                f"physics-rate trace and true lane pose.")

    def top_view(self, px_per_tile: int) -> np.ndarray:
        sim = self.sim
        return top_down(sim.map, sim.state[:1, :3], px_per_tile, sim.params[0])
