"""``proxybench dtps serve``: the simulator as a virtual DB21J that an SDK agent started by the user drives.

The runner's part of :mod:`proxybench.dtps`: it builds the plant (:func:`~proxybench.runner.episode.sim_plant`)
and plays :func:`~proxybench.runner.rollout.rollout` with a :class:`ServeDriver` on the virtual robot. The
server runs in real time whether or not an agent is connected (the robot holds (0, 0) until a command comes),
like the Duckiematrix. An episode ends when the agent publishes ``state/reset`` (termination ``reset``), when
the robot leaves the road or collides, or after ``episode_seconds``; the robot is then teleported to the next
start pose (seed + 1) and a new episode begins. Serving stops when ``seconds`` of *wall* time have passed, in the
middle of an episode if need be (its termination ``timeout``, its detail saying so): a simulation slower than
real time must not stretch the serve (issue 39: ``--seconds 90`` ran 250–290 s). ``on_late`` hears when the
simulation falls behind the wall clock (:class:`~proxybench.dtps.lateness.Lateness`). Every episode is saved as
a trajectory (``episode-<k>.parquet``) in the output folder, with the serve's timing in its metadata.

The serve lives only as long as its bridge: a bridge that ended (killed, crashed) ends the serve with a
:class:`~proxybench.dtps.link.BridgeError` of one line, and the episode it cut short is not saved (issue 38: a
``DELETE`` that killed the bridge made the serve write ~100 empty episodes a second). An episode in which no
step ran is never saved. What clients may ask of the robot's HTTP server is the bridge's to refuse
(``bridge.py``, the robot policy: reads, and writes to the command topics only).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.agents.base import Observation
from proxybench.domain.maps import Map, load_map
from proxybench.domain.params import DomainParams
from proxybench.dtps.driver import RobotDriver
from proxybench.dtps.link import BridgeError
from proxybench.dtps.virtual_robot import DEFAULT_NAME, DEFAULT_PORT, VirtualDB21J
from proxybench.runner.episode import sim_plant
from proxybench.runner.rollout import AgentPolicy, rollout
from proxybench.runner.streams import StreamRecorder, StreamSpec, with_fixtures
from proxybench.tasks.trajectory import Event, Termination

__all__ = ["WALL_TIME_UP", "ServeDriver", "serve"]


class ServeDriver(RobotDriver):
    """Real time with an agent that comes and goes: no start or silence timeouts (the robot holds the last
    command, (0, 0) before any), and ``state/reset`` requests are remembered for the plant to end the episode."""

    start_frame_counts = True  # the first frame waits for nobody: an answer to it is an answer like any other

    def __init__(self, robot: VirtualDB21J, *, warn: Callable[[str], None] | None = None, hint: str = ""):
        super().__init__(robot, timing="realtime", start_timeout=float("inf"), step_timeout=float("inf"), warn=warn,
                         hint=hint)
        self.name = "dtps-agent"
        self.reset_requested = False

    def reset(self, seed: int, episode: str | None = None) -> None:
        super().reset(seed, episode)
        self.reset_requested = False

    def act(self, obs: Observation) -> np.ndarray:
        if self.t0 is None:
            self.t0 = time.monotonic() - obs.time
            self.first_seq = self.robot.seq + 1
        resets = self.resets
        out = super().act(obs)
        self.reset_requested = self.reset_requested or self.resets > resets
        return out


#: episodes in a row that ran no step before the serve gives up
_MAX_EMPTY = 20

#: the detail of an episode cut short by the end of the serve
WALL_TIME_UP = "the serve's time (wall clock) ran out"


class _ResetPlant:
    """A plant whose episode also ends when the driver saw ``state/reset`` (termination ``reset``), and when the
    wall clock reaches ``end`` (``timeout``, :data:`WALL_TIME_UP`)."""

    def __init__(self, plant: Any, driver: ServeDriver, end: float = float("inf"),
                 stop: threading.Event | None = None):
        self._plant, self._driver, self._end, self._stop = plant, driver, end, stop

    def _stopped(self) -> bool:
        return time.monotonic() >= self._end or (self._stop is not None and self._stop.is_set())

    def __getattr__(self, name: str) -> Any:
        return getattr(self._plant, name)

    def advance(self, commands: np.ndarray, alive: np.ndarray, k: int) -> list[tuple[int, Event, bool]]:
        out = self._plant.advance(commands, alive, k)
        if self._driver.reset_requested and not any(final for _, _, final in out):
            out.append((0, Event(self._plant.time(0), Termination.RESET, "the agent published state/reset"), True))
        elif self._stopped() and not any(final for _, _, final in out):
            out.append((0, Event(self._plant.time(0), Termination.TIMEOUT, WALL_TIME_UP), True))
        return out


def _recording(recorder: StreamRecorder | None):
    """The rollout's frame hook that renders the fixed cameras due at the robot's time (None: no cameras)."""
    if recorder is None:
        return None

    def on_frame(k: int, images, alive, plant) -> None:
        if alive[0]:
            recorder.frame(plant.time(0))
    return on_frame


def serve(map_name: str, out: Path, *, name: str = DEFAULT_NAME, port: int = DEFAULT_PORT,
          seconds: float = float("inf"), episode_seconds: float = 60.0, seed: int = 0,
          params: DomainParams | None = None, on_episode: Callable[[int, Any], None] | None = None,
          on_ready: Callable[[str], None] | None = None, host: str = "127.0.0.1",
          on_late: Callable[[str], None] | None = None, late_hint: str = "",
          stop: threading.Event | None = None, streams: StreamSpec | None = None) -> list[Path]:
    """Serve until ``seconds`` of wall time have passed (or Ctrl-C); the trajectory files written.

    ``on_ready(url)`` runs once the robot's queues exist: an SDK agent started before then cannot connect
    (the SDK gives up at once on a server that is not there), so say "start your agent" only then.
    ``on_late(message)``: the simulation fell behind the wall clock (rate-limited; the message ends with
    ``late_hint``, what to do about it). ``stop``: set it to end the serve as the wall clock would (an embedding
    program's Ctrl-C). ``streams``: fixed cameras of the same world (a lab's simulated watchtowers, their fixtures
    in the world), recorded or sent to the spec's sink every episode (``episode-<k>.streams``): a stand-in for a
    lab whose watchtowers see this robot (docs/autolab.md). Raises :class:`BridgeError` (one line) when the bridge
    ends under the serve.
    """
    out.mkdir(parents=True, exist_ok=True)
    world: Map | str = map_name
    if streams is not None:  # the lab's calibration tags on its floor
        world = with_fixtures(load_map(map_name), streams.fixtures)
    plant = sim_plant(world, params)
    robot = VirtualDB21J(name=name, port=port, host=host)
    files: list[Path] = []
    try:
        robot.publish_map(plant.map)
        if on_ready is not None:
            on_ready(robot.url)
        driver = ServeDriver(robot, warn=on_late, hint=late_hint)
        end = time.monotonic() + seconds
        k = empty = 0
        while time.monotonic() < end and not (stop is not None and stop.is_set()):
            length = min(episode_seconds, end - time.monotonic())
            meta = {"map": plant.map.name, "episode": k, "served": {"url": robot.url, "timing": "realtime"}}
            recorder = StreamRecorder(plant.sim, streams, out / f"episode-{k}.streams") if streams else None
            try:
                traj = rollout(_ResetPlant(plant, driver, end, stop), AgentPolicy([driver]), [seed + k], length,
                               metas=[meta], on_frame=_recording(recorder))[0]
            finally:
                if recorder is not None:
                    recorder.close()
            if not getattr(robot, "alive", True):  # the robot is gone: no episode of it, and no more episodes
                raise BridgeError(f"the virtual robot's bridge ended during episode {k} (exit code "
                                  f"{getattr(robot, 'exit_code', None)}): the serve stops; start it again")
            if len(traj) == 0:  # nothing ran: nothing to save (and never a loop of such episodes)
                empty += 1
                if empty >= _MAX_EMPTY:
                    raise BridgeError(f"{empty} episodes in a row ran no step: the serve stops")
                continue
            empty = 0
            traj.meta["served"]["stats"] = driver.stats()
            path = out / f"episode-{k}.parquet"
            traj.save(path)
            files.append(path)
            if on_episode is not None:
                on_episode(k, traj)
            k += 1
    finally:
        robot.close()
    (out / "served.json").write_text(json.dumps({"url": robot.url, "episodes": [p.name for p in files]}, indent=2))
    return files
