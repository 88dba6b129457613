"""The plant contract: what every plant of the episode engine (simulator, robot node, a lab's bridge) must do.

A plant is where the robots of :func:`~proxybench.runner.rollout.rollout` live (the ``Plant`` protocol of
``runner/rollout.py``). Checks (each a :class:`~proxybench.testing.results.CheckResult`):

- ``starts``: the factory makes a plant and it begins an episode (a plant that cannot start raises a clear,
  named error, e.g. :class:`~proxybench.protocol.RobotFailure` ``start-failed``: the reason says which);
- ``start-pose``: an episode begun at a requested start pose starts there (t = 0, within a tolerance);
- ``stepping``: the plant runs at the frame rate asked for (``plant.frame_rate``), ``begin`` counts the
  episode's frames, ``advance`` holds the commands and answers events as (robot, an ``Event``, ends it; an
  ending's kind is a ``Termination``), the robots move, and ``samples`` are finite rows
  t, x, y, θ, v, ω, pwm_left, pwm_right from t = 0 to the last frame's time;
- ``observations``: camera frames are (H, W, 3) uint8 of one size; observation times advance by 1/frame_rate;
  camera agents are given no ground truth, privileged agents the true lane pose (where the plant has one);
- ``determinism``: the same seeds and commands give the same trajectories, frames and events, after other
  episodes on the same plant and on a fresh one;
- ``failure``: ``end()`` is safe twice and the plant begins again after it; a robot node that dies
  mid-episode is a named :class:`~proxybench.protocol.RobotFailure`, and the next episode starts a fresh node.

Build one with :meth:`PlantContract.for_simulator` (the batched simulator, ``SimPlant``) or
:meth:`PlantContract.for_robot_command` (a robot node: ``proxybench robot serve`` or your robot's bridge;
``proxybench robot check CMD`` on the command line).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from proxybench.agents.base import Observation
from proxybench.domain.lane_pose import LanePose
from proxybench.domain.params import DomainParams
from proxybench.protocol.process import NodeProcess
from proxybench.runner.robot_episode import RobotPlant
from proxybench.runner.rollout import Plant, PrivilegedAgentError
from proxybench.tasks.trajectory import TERMINATIONS, Event
from proxybench.testing.results import CheckFailed, Contract, describe_error, expect_node_failure, kill_node, release

__all__ = ["PlantContract"]

SAMPLE_COLUMNS = ("t", "x", "y", "theta", "v", "omega", "pwm_left", "pwm_right")
MIN_TRAVEL_M = 0.005  # [m] a robot must move this far in its first frames under a forward command


def _command(k: int) -> np.ndarray:
    """The commands every robot holds at frame ``k``: forward, weaving gently (so that turning is exercised)."""
    return np.array([0.35 + 0.1 * math.sin(k / 4.0), 0.35 + 0.1 * math.cos(k / 4.0)])


@dataclass
class Episode:
    """What a plant did in one episode: per robot its frames, samples and events, and what each frame showed."""

    steps: int
    frames: list[int]
    samples: list[np.ndarray]
    events: list[list[tuple[int, Any, Any]]]
    seen: list[dict[str, Any]] = field(default_factory=list)  # one per (frame, running robot)
    meta: list[Any] = field(default_factory=list)
    wheel_distance: list[Any] = field(default_factory=list)


def _seen(k: int, i: int, image: Any, obs: Any, plant_time: float) -> dict[str, Any]:
    out: dict[str, Any] = {"k": k, "i": i, "observation": isinstance(obs, Observation), "plant_time": plant_time}
    if isinstance(image, np.ndarray):
        out["image"] = (image.shape, str(image.dtype))
        out["digest"] = hashlib.sha1(np.ascontiguousarray(image).tobytes()).hexdigest()
    else:
        out["image"] = None if image is None else type(image).__name__
    if isinstance(obs, Observation):
        out.update(time=obs.time, odometry=obs.odometry, lane_pose=obs.lane_pose, route=obs.route, pose=obs.pose,
                   same_image=obs.camera is image or (image is None and obs.camera is None))
    return out


class PlantContract(Contract):
    """The plant contract over the plants ``factory`` makes (each call: a fresh plant).

    ``frame_rate`` [Hz]: the rate its frames must come at (None: the rate the plant says, ``plant.frame_rate``);
    ``seconds``: each test episode's length; ``seeds``:
    two different episode seeds; tolerances: start pose [m], [rad], times [s]; ``image_size``: (width, height)
    its frames must have (None: any one size); ``atol``: how far two runs' samples may differ and count as
    the same (0: bit for bit).
    """

    CHECKS = ("starts", "start-pose", "stepping", "observations", "determinism", "failure")
    title = "plant contract"

    def __init__(self, factory: Callable[[], Plant], *, name: str = "plant", frame_rate: float | None = None,
                 seconds: float = 1.0, seeds: tuple[int, int] = (1, 2), position_tolerance: float = 1e-3,
                 heading_tolerance: float = 1e-3, time_tolerance: float = 1e-6,
                 image_size: tuple[int, int] | None = None, atol: float = 0.0):
        super().__init__()
        if len(seeds) != 2 or seeds[0] == seeds[1]:
            raise ValueError(f"PlantContract: seeds must be two different seeds, got {seeds}")
        self.factory = factory
        self.subject = name
        self.expected_rate = None if frame_rate is None else float(frame_rate)
        self.seconds = float(seconds)
        self.seeds = tuple(int(s) for s in seeds)
        self.position_tolerance, self.heading_tolerance = position_tolerance, heading_tolerance
        self.time_tolerance = time_tolerance
        self.image_size = image_size
        self.atol = float(atol)

    @property
    def frame_rate(self) -> float:
        """[Hz] the rate frames must come at: the one asked for, else the one the plant says it runs at."""
        if self.expected_rate is not None:
            return self.expected_rate
        return float(self._started().frame_rate)

    # -- constructors -------------------------------------------------------------------------------
    @classmethod
    def for_simulator(cls, map_name: str = "loop_3x3", params: DomainParams | None = None, n: int = 2,
                      **kwargs: Any) -> PlantContract:
        """The batched simulator (``SimPlant`` of ``n`` robots, with the JPEG round trip agents see)."""
        from proxybench.runner.episode import sim_plant

        params = params or DomainParams(image_width=160, image_height=120)
        kwargs.setdefault("image_size", (params.image_width, params.image_height))
        return cls(lambda: sim_plant(map_name, params, n),
                   name=f"simulator plant ({n} robots on {map_name})", frame_rate=params.frame_rate, **kwargs)

    @classmethod
    def for_robot_command(cls, command: str | Sequence[str], map_name: str = "loop_3x3", options: Any = None,
                          frame_rate: float = 15.0, **kwargs: Any) -> PlantContract:
        """A robot node started with ``command`` (``proxybench robot serve``, your robot's bridge) and ``options``
        (:class:`~proxybench.protocol.options.RobotNodeOptions`), as :class:`RobotPlant` drives it on ``map_name``."""
        from proxybench.domain.maps import load_map
        from proxybench.protocol.options import RobotNodeOptions
        from proxybench.protocol.robot_process import RemoteRobot

        process_kwargs = (options or RobotNodeOptions()).process_kwargs()
        the_map = load_map(map_name)

        def start() -> Plant:
            robot = RemoteRobot(command, frame_rate=frame_rate, **process_kwargs)
            if robot.process.reflection_note is not None:  # it failed describe_protocol once: never ask again
                process_kwargs["reflection"] = False
            return _OwnedRobotPlant(robot, the_map)

        label = command if isinstance(command, str) else " ".join(map(str, command))
        return cls(start, name=f"robot node {label!r}", frame_rate=frame_rate, **kwargs)

    # -- driving ------------------------------------------------------------------------------------
    def _make(self) -> Plant:
        try:
            plant = self.factory()
        except Exception as exc:  # e.g. RobotFailure start-failed: named, with the node's words
            raise CheckFailed(f"could not make the plant: {describe_error(exc)}", exc) from None
        self._on_close(lambda: release(plant))
        return plant

    def _plant(self) -> Plant:
        """The plant most checks share (a plant is reused episode after episode, as the runner does)."""
        return self._memoised("plant", self._make)

    def _started(self, *, quote: bool = True) -> Plant:
        """The shared plant, once it has begun (and ended) an episode; else every check fails, naming why."""
        try:
            return self._memoised("started", self._begin_once)
        except CheckFailed as exc:
            if not quote:
                raise
            raise CheckFailed(f"not run: the plant did not start (see 'starts': {exc})", exc.error) from None

    def _begin_once(self) -> Plant:
        plant = self._plant()
        try:
            self._memo["steps"] = plant.begin([self.seeds[0] + i for i in range(plant.n)], [None] * plant.n,
                                              [None] * plant.n, self.seconds, False, [False] * plant.n)
            plant.end()
        except Exception as exc:  # e.g. a robot node that fails its episode setup: named, with its words
            raise CheckFailed(f"could not begin an episode: {describe_error(exc)}", exc) from None
        return plant

    def _drive(self, plant: Plant, seed: int, *, poses: Sequence[Any] | None = None, camera: bool = False,
               privileged: bool = False, seconds: float | None = None, kill_at: int | None = None) -> Episode:
        """One episode of every robot of ``plant`` from seeds ``seed``, ``seed + 1``, …, holding :func:`_command`."""
        n = plant.n
        seeds = [seed + i for i in range(n)]
        steps = plant.begin(seeds, list(poses) if poses is not None else [None] * n, [None] * n,
                            self.seconds if seconds is None else seconds, camera, [privileged] * n)
        ep = Episode(steps, [steps] * n, [], [[] for _ in range(n)])
        alive = np.ones(n, dtype=bool)
        for k in range(int(steps)):
            if not alive.any():
                break
            if kill_at == k:
                kill_node(_node_process(plant))
            images = plant.frames(alive)
            for i in np.flatnonzero(alive):
                image = None if images is None else images[i]
                ep.seen.append(_seen(k, int(i), image, plant.observation(int(i), image, privileged), plant.time(i)))
            commands = np.tile(_command(k), (n, 1))
            commands[~alive] = 0.0
            for item in plant.advance(commands, alive.copy(), k):
                i, event, final = item if isinstance(item, tuple) and len(item) == 3 else (None, item, None)
                if not (isinstance(i, int | np.integer) and 0 <= i < n):
                    raise CheckFailed(f"frame {k}: advance() answered {item!r}, not (robot, event, ends it)")
                ep.events[i].append((k, event, final))
                if final is True:
                    alive[i], ep.frames[i] = False, k + 1
        ep.samples = [np.asarray(plant.samples(i, ep.frames[i])) for i in range(n)]
        ep.meta = [plant.meta(i) for i in range(n)]
        ep.wheel_distance = [plant.wheel_distance(i) for i in range(n)]
        plant.end()
        return ep

    def _episode(self, key: str, seed: int, **kwargs: Any) -> Episode:
        return self._memoised(("episode", key), lambda: self._drive(self._started(), seed, **kwargs))

    # -- the checks ---------------------------------------------------------------------------------
    def check_starts(self) -> tuple[bool, str]:
        plant = self._started(quote=False)
        return True, f"{plant.n} robot(s) on {plant.map.name}: an episode of {self._memo['steps']} frames begins"

    def check_start_pose(self) -> tuple[bool, str]:
        from proxybench.domain.simulator import start_pose

        plant = self._started()
        poses = [start_pose(plant.map, self.seeds[0] + 1000 + i) for i in range(plant.n)]
        plant.begin([self.seeds[0] + i for i in range(plant.n)], poses, [None] * plant.n, self.seconds, False,
                    [False] * plant.n)
        rows = [np.asarray(plant.samples(i, 0)) for i in range(plant.n)]
        plant.end()
        worst = 0.0
        for i, (pose, row) in enumerate(zip(poses, rows, strict=True)):
            if row.ndim != 2 or row.shape[0] < 1 or row.shape[1] < 4:
                return False, f"robot {i}: samples(i, 0) has shape {row.shape}, not (m ≥ 1, 8)"
            t, x, y, th = (float(v) for v in row[0, :4])
            d = math.hypot(x - pose[0], y - pose[1])
            dth = abs((th - pose[2] + math.pi) % (2 * math.pi) - math.pi)
            if abs(t) > self.time_tolerance or d > self.position_tolerance or dth > self.heading_tolerance:
                return False, (f"robot {i} asked to start at ({pose[0]:.3f}, {pose[1]:.3f}, {pose[2]:.3f}) started at "
                               f"({x:.3f}, {y:.3f}, {th:.3f}), t = {t:g} s: {d:.4f} m and {dth:.4f} rad off "
                               f"(tolerance {self.position_tolerance:g} m, {self.heading_tolerance:g} rad)")
            worst = max(worst, d)
        return True, f"{plant.n} robot(s) started at the requested poses (within {worst:.2g} m, at t = 0)"

    def check_stepping(self) -> tuple[bool, str]:
        ep = self._episode("plain", self.seeds[0])
        said = getattr(self._started(), "frame_rate", None)
        if not (isinstance(said, int | float) and math.isclose(said, self.frame_rate, rel_tol=1e-9)):
            return False, f"the plant says it runs at {said!r} frames/s; expected {self.frame_rate:g} Hz"
        expected = max(1, round(self.seconds * self.frame_rate))
        if ep.steps != expected:
            return False, f"begin() said {ep.steps} frames for {self.seconds:g} s at {self.frame_rate:g} Hz " \
                          f"(expected {expected})"
        for i, events in enumerate(ep.events):
            for k, event, final in events:
                if not (isinstance(event, Event) and isinstance(event.kind, str) and isinstance(event.t, int | float)
                        and isinstance(final, bool)):
                    return False, f"robot {i}, frame {k}: advance() answered ({event!r}, {final!r}), not an Event " \
                                  "(with t and kind) and whether it ends the episode"
                if final and event.kind not in TERMINATIONS:
                    return False, f"robot {i}, frame {k}: an episode-ending event of kind {str(event.kind)!r}, not " \
                                  f"a Termination ({', '.join(TERMINATIONS)})"
        for i, rows in enumerate(ep.samples):
            problem = self._samples_problem(rows, ep.frames[i])
            if problem is not None:
                return False, f"robot {i}: {problem}"
            moved = float(np.hypot(*(rows[-1, 1:3] - rows[0, 1:3])))
            if ep.frames[i] >= 3 and moved < MIN_TRAVEL_M:
                return False, f"robot {i} moved {moved:.4f} m in {ep.frames[i]} frames of forward commands"
            meta = ep.meta[i]
            if not (isinstance(meta, dict) and isinstance(meta.get("source"), str) and "params" in meta):
                return False, f"robot {i}: meta() is {meta!r}, not a dict with 'source' and 'params'"
            if not (isinstance(ep.wheel_distance[i], int | float) and ep.wheel_distance[i] > 0):
                return False, f"robot {i}: wheel_distance() is {ep.wheel_distance[i]!r}"
        ended = [f"robot {i}: {events[-1][1].kind} at frame {ep.frames[i]}" for i, events in enumerate(ep.events)
                 if events and events[-1][2]]
        return True, (f"{len(ep.samples)} robot(s) × {ep.steps} frames: finite samples from t = 0 to the last frame, "
                      "robots moving" + (f"; ended: {', '.join(ended)}" if ended else ""))

    def _samples_problem(self, rows: np.ndarray, frames: int) -> str | None:
        if rows.ndim != 2 or rows.shape[1] != len(SAMPLE_COLUMNS) or rows.shape[0] < 2:
            return f"samples() has shape {rows.shape}, not (m ≥ 2, {len(SAMPLE_COLUMNS)}) ({', '.join(SAMPLE_COLUMNS)})"
        if not np.all(np.isfinite(rows)):
            bad = np.argwhere(~np.isfinite(rows))[0]
            return f"sample {bad[0]}, column {SAMPLE_COLUMNS[bad[1]]}: {rows[bad[0], bad[1]]} is not finite"
        t = rows[:, 0]
        if abs(t[0]) > self.time_tolerance or np.any(np.diff(t) <= 0):
            return f"sample times start at {t[0]:g} s and must rise from 0 (first non-rising: " \
                   f"{int(np.argmax(np.diff(t) <= 0)) + 1 if np.any(np.diff(t) <= 0) else '-'})"
        end = frames / self.frame_rate
        if abs(t[-1] - end) > self.time_tolerance + 1e-9 * end:
            return (f"the last sample is at t = {t[-1]:.6f} s; {frames} frames at {self.frame_rate:g} Hz end at "
                    f"{end:.6f} s")
        return None

    def check_observations(self) -> tuple[bool, str]:
        ep = self._episode("camera", self.seeds[0], camera=True)
        shapes = {s["image"] for s in ep.seen}
        if len(shapes) != 1 or not isinstance(next(iter(shapes)), tuple):
            return False, f"camera frames must all be one (H, W, 3) uint8 array shape; got {sorted(map(str, shapes))}"
        shape, dtype = next(iter(shapes))
        if len(shape) != 3 or shape[2] != 3 or dtype != "uint8":
            return False, f"camera frames are {shape} {dtype}, not (H, W, 3) uint8"
        if self.image_size is not None and (shape[1], shape[0]) != tuple(self.image_size):
            return False, f"camera frames are {shape[1]}×{shape[0]}; expected {self.image_size[0]}×{self.image_size[1]}"
        for s in ep.seen:
            problem = self._frame_problem(s, privileged=False)
            if problem is not None:
                return False, f"frame {s['k']}, robot {s['i']}: {problem}"
        truth = self._ground_truth()
        return True, (f"{shape[1]}×{shape[0]} RGB uint8 frames every 1/{self.frame_rate:g} s, observation times "
                      f"k/{self.frame_rate:g} s; camera agents get no ground truth; {truth}")

    def _frame_problem(self, s: dict[str, Any], privileged: bool) -> str | None:
        if not s["observation"]:
            return "observation() did not return an Observation"
        if not s["same_image"]:
            return "the observation's camera is not the frame frames() returned"
        want = s["k"] / self.frame_rate
        if not (isinstance(s["time"], int | float) and abs(s["time"] - want) <= self.time_tolerance):
            return f"observation time {s['time']!r} s, expected {want:.6f} s (frame k at k/{self.frame_rate:g} s)"
        if abs(float(s["plant_time"]) - s["time"]) > self.time_tolerance:
            return f"time() says {s['plant_time']} s, the observation {s['time']} s"
        odo = s["odometry"]
        if odo is not None and not (len(odo) == 2 and all(isinstance(v, float | int) and math.isfinite(v)
                                                          for v in odo)):
            return f"odometry {odo!r} is not two finite angles"
        if not privileged and (s["lane_pose"] is not None or s["route"] is not None or s["pose"] is not None):
            return "a camera agent's observation carries ground truth (lane_pose / route / pose)"
        if privileged and not isinstance(s["lane_pose"], LanePose):
            return f"a privileged agent's observation carries no true lane pose ({s['lane_pose']!r})"
        return None

    def _ground_truth(self) -> str:
        """Privileged observations: the true lane pose every frame (or a named refusal at begin)."""
        try:
            ep = self._drive(self._started(), self.seeds[0], privileged=True, seconds=min(self.seconds, 0.5))
        except PrivilegedAgentError as exc:
            return f"no ground truth for privileged agents ({describe_error(exc)})"
        for s in ep.seen:
            problem = self._frame_problem(s, privileged=True)
            if problem is not None:
                raise CheckFailed(f"privileged episode, frame {s['k']}, robot {s['i']}: {problem}")
        return "privileged agents get the true lane pose"

    def check_determinism(self) -> tuple[bool, str]:
        first = self._episode("camera", self.seeds[0], camera=True)
        plant = self._started()
        self._drive(plant, self.seeds[1], camera=True)
        again = self._drive(plant, self.seeds[0], camera=True)
        fresh = self._make()
        try:
            anew = self._drive(fresh, self.seeds[0], camera=True)
        finally:
            release(fresh)
        for label, other in (("after another episode on the same plant", again), ("on a fresh plant", anew)):
            diff = self._difference(first, other)
            if diff is not None:
                return False, f"seed {self.seeds[0]} again, {label}: {diff}"
        return True, f"seed {self.seeds[0]} again (after seed {self.seeds[1]}, and on a fresh plant): the same " \
                     f"samples, frames and events"

    def _difference(self, a: Episode, b: Episode) -> str | None:
        if a.frames != b.frames:
            return f"episodes of {a.frames} frames, then {b.frames}"
        for i, (x, y) in enumerate(zip(a.samples, b.samples, strict=True)):
            if x.shape != y.shape:
                return f"robot {i}: {x.shape[0]} samples, then {y.shape[0]}"
            close = np.isclose(x, y, rtol=0, atol=self.atol, equal_nan=True) if self.atol else \
                (x == y) | (np.isnan(x) & np.isnan(y))
            if not close.all():
                r, c = np.argwhere(~close)[0]
                return f"robot {i}, sample {r} (t = {x[r, 0]:.4f} s): {SAMPLE_COLUMNS[c]} {x[r, c]!r}, then {y[r, c]!r}"
        for s, t in zip(a.seen, b.seen, strict=False):
            if s.get("digest") != t.get("digest"):
                return f"robot {s['i']}'s camera frame {s['k']} differs"
        for i, (x, y) in enumerate(zip(a.events, b.events, strict=True)):
            if repr(x) != repr(y):
                return f"robot {i}'s events differ: {x!r}, then {y!r}"
        return None

    def check_failure(self) -> tuple[bool, str]:
        plant = self._started()  # the shared plant: a killed node is restarted for whatever comes next
        said = []
        self._drive(plant, self.seeds[0], seconds=min(self.seconds, 0.4))
        try:
            plant.end()
        except Exception as exc:
            raise CheckFailed(f"end() raised when called a second time: {describe_error(exc)}", exc) from None
        said.append("end() twice: fine")
        if _node_process(plant) is not None:
            said.append(self._node_dies(plant))
        else:
            ep = self._drive(plant, self.seeds[1], seconds=min(self.seconds, 0.4))
            said.append(f"begins again after end() ({ep.steps} frames)")
        return True, "; ".join(said)

    def _node_dies(self, plant: Plant) -> str:
        died = expect_node_failure("robot node",
                                   lambda: self._drive(plant, self.seeds[0], seconds=min(self.seconds, 0.4), kill_at=1))
        try:
            plant.end()
            plant.end()
        except Exception as exc:
            raise CheckFailed(f"{died}; then end() raised: {describe_error(exc)}", exc) from None
        ep = self._drive(plant, self.seeds[1], seconds=min(self.seconds, 0.4))
        return f"{died}; end() twice after it: fine; the next episode started a fresh node ({ep.steps} frames)"


def _node_process(plant: Any) -> NodeProcess | None:
    process = getattr(getattr(plant, "robot", None), "process", None)
    return process if isinstance(process, NodeProcess) else None


class _OwnedRobotPlant(RobotPlant):
    """A RobotPlant that owns its robot node, so the contract can end the node's process when it is done."""

    def close(self) -> None:
        self.robot.close()
