"""A lab's shared world (issue 36 item 3): one simulator stepping every virtual robot of an Autolab in lock-step.

The robots of one lab share one floor: each sees the others in its camera, can hit them, and the lab's watchtowers
see every robot under its own roof tag. One :class:`LabWorld` holds them all in one shared
:class:`~proxybench.domain.simulator.Simulator` (``shared=True``), and each job's worker drives *its* robot through a
:class:`LabWorldPlant` (a plant of the episode engine, like :class:`~.robot_episode.RobotPlant`) connected to the
world's server (:func:`serve`, a process of the evaluator's, reached over a Unix socket in the evaluator's private
folder with a key of its own). The SDK agent of each job still finds its robot at 127.0.0.1:7501 inside its own
sandbox: its worker's virtual DB21J publishes the frames this world renders.

**Each job on its own clock.** A robot's episode begins when its job asks (``begin``: θ, start pose; the robot is
teleported there, nobody else moves) and ends when its job says (``end``) or the world ends it; between episodes
the robot stands where it stopped, an obstacle; a robot whose job left is parked off the map. A start pose taken by
a robot that is driving waits until it is clear (at most ``start_wait_s``; then the job's robot failed); an idle
robot standing there is parked (an operator would lift it away).

**Lock-step with a deadline.** A world step waits for the command of every robot whose episode runs and whose agent
has answered its first frame (an SDK program takes seconds to start; the others do not wait for that, and the robot
stands still meanwhile); a robot that sends no command within ``step_deadline_s`` of the others' is dropped (its
episode ends as the agent's failure), so that one agent can never stall another's robot for good. Idle robots get
(0, 0). Each running robot's frames advance on its own counter, so its trajectory, camera and watchtower streams are
on its episode's clock.

**Collisions between robots** (docs/autolab.md): at contact, the robot moving towards the other is at fault
(``domain.worlds.robot_contacts``) and its episode ends as a ``collision`` with the robot; the other's episode gets a
``robot_contact`` event and goes on: the run is invalid (the lab's fault as far as its agent is concerned) and the
Autolab evaluator re-runs it, unless it was at fault too (head-on: both ``collision``).

The watchtowers (:class:`~.streams.StreamSpec`, files) are recorded per running episode into the folder the job
asked for, on that episode's clock, all from one rig: what they see is the whole floor.
"""

from __future__ import annotations

import contextlib
import math
import queue
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Client, Connection, Listener, wait
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.agents.base import Observation
from proxybench.domain.dynamics import ST, TRACE_FIELDS, wheel_ticks
from proxybench.domain.episode_end import end_event
from proxybench.domain.events import Event, Termination
from proxybench.domain.lane_pose import LanePose
from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import Map, load_map
from proxybench.domain.objects import ROBOT_MARGIN
from proxybench.domain.params import STRUCTURAL_FIELDS, DomainParams
from proxybench.domain.range_sensor import front_range
from proxybench.domain.simulator import Simulator
from proxybench.protocol.failures import RobotFailure
from proxybench.runner.streams import StreamRecorder, StreamSpec, with_fixtures

__all__ = ["CONTACT_EVENT", "LabWorld", "LabWorldAddress", "LabWorldPlant", "LabWorldSpec", "connect", "serve"]

#: the event of a robot another ran into (not at fault): its run is invalid, re-run by the Autolab evaluator
CONTACT_EVENT = "robot_contact"
#: [m] a start pose this close to another robot's centre is taken (two robots' margins)
START_CLEARANCE = 2 * ROBOT_MARGIN
_PARK_Y = -30.0  # [m] parked robots stand in a row this far off the map (no camera or watchtower sees them)


@dataclass(frozen=True)
class LabWorldSpec:
    """What a lab world is: the lab's map, its robots (names, roof tags), its simulated watchtowers (``streams``:
    files, or None), the per-step deadline and how long a blocked start waits [s]."""

    map: str
    robots: tuple[str, ...]
    roof_tags: tuple[int, ...]
    streams: StreamSpec | None = None
    step_deadline_s: float = 30.0
    start_wait_s: float = 120.0

    def __post_init__(self) -> None:
        if len(self.robots) != len(self.roof_tags) or len(set(self.robots)) != len(self.robots) or not self.robots:
            raise ValueError("a lab world needs robots with distinct names, one roof tag each")
        if len(set(self.roof_tags)) != len(self.roof_tags):
            raise ValueError(f"lab world: roof tags {list(self.roof_tags)} are not distinct")
        if self.step_deadline_s <= 0 or self.start_wait_s <= 0:
            raise ValueError("lab world: step_deadline_s and start_wait_s must be positive")
        if self.streams is not None and self.streams.sink is not None:
            raise ValueError("lab world: its watchtowers are recorded to files (a stream sink is not supported)")


@dataclass(frozen=True)
class LabWorldAddress:
    """Where a lab world's server listens (a Unix socket path) and the key a worker proves itself with."""

    path: str
    authkey: bytes


@dataclass
class _Robot:
    """One robot of the world: its row, whether its episode runs (``running``), joined the lock-step (``stepping``),
    its own frame counter, its recorder, why the world ended its episode (``ended``), the contact it reported."""

    index: int
    name: str
    running: bool = False
    stepping: bool = False
    frames: int = 0
    camera: bool = True
    recorder: StreamRecorder | None = None
    ended: Event | None = None
    reported: bool = False
    connected: bool = False


@dataclass
class StepReply:
    """One frame of a robot's episode as its plant needs it: the physics trace (substeps, 8: t, x, y, θ, v, ω,
    pwm_left, pwm_right), the state and lane rows after it, the camera frame (raw RGB; None: not asked), the front
    range, the route's lanes before the step, and what happened (events; ``ended``: the one that ends it)."""

    trace: np.ndarray
    state: np.ndarray
    lane: np.ndarray
    route: Any
    camera: np.ndarray | None
    range: float | None
    lanes: tuple[int, int]
    t: float
    events: list[Event] = field(default_factory=list)
    ended: Event | None = None


class LabWorld:
    """The shared world itself, without sockets (see the module): ``begin``, ``command``, ``step``, ``end``,
    ``park``, driven by :func:`serve`'s loop (or a test)."""

    def __init__(self, spec: LabWorldSpec, params: DomainParams | None = None):
        self.spec = spec
        self.robots = {name: _Robot(i, name) for i, name in enumerate(spec.robots)}
        self.map = with_fixtures(load_map(spec.map), spec.streams.fixtures if spec.streams is not None else ())
        self.sim: Simulator | None = None
        self.rig = None
        self.pending: dict[str, np.ndarray] = {}
        self.round_start: float | None = None
        self._build(params or DomainParams())
        for r in self.robots.values():
            self.park(r.name)

    # -- the world -----------------------------------------------------------------------------------

    def _build(self, params: DomainParams) -> None:
        """A shared simulator of every robot at θ ``params`` (robots keep their poses when it is rebuilt)."""
        from proxybench.domain.fixed_cameras import FixedCameraRig

        old = None if self.sim is None else self.sim.state[:, :3].copy()
        n = len(self.spec.robots)
        self.sim = Simulator(self.map, params, n=n, shared=True, roof_tags=self.spec.roof_tags)
        self.trace = np.zeros((n, self.sim.substeps, len(TRACE_FIELDS)))
        streams = self.spec.streams
        self.rig = FixedCameraRig(self.sim, streams.cameras) if streams is not None and streams.cameras else None
        if old is not None:
            for i in range(n):
                self.sim.reset(i, 0, tuple(old[i]))

    @property
    def frame_dt(self) -> float:
        return self.sim.frame_dt

    def park(self, name: str) -> None:
        """Robot ``name`` lifted off the floor (its job left, or it stood on another's start): idle, off the map."""
        r = self.robots[name]
        self._stop_recording(r)
        r.running = r.stepping = False
        self.pending.pop(name, None)
        self.sim.reset(r.index, 0, (-5.0 - 0.5 * r.index, _PARK_Y, 0.0))

    def _structural(self, params: DomainParams) -> list[str]:
        """The fields of θ the shared simulator cannot change per robot on which ``params`` differs from it."""
        now = self.sim.params[0]
        return [f for f in STRUCTURAL_FIELDS if getattr(params, f) != getattr(now, f)]

    def blocker(self, name: str, pose: tuple[float, float, float]) -> str | None:
        """The robot standing within ``START_CLEARANCE`` of ``pose`` (other than ``name``), if any."""
        for other in self.robots.values():
            if other.name != name:
                x, y = self.sim.state[other.index, :2]
                if math.hypot(x - pose[0], y - pose[1]) < START_CLEARANCE:
                    return other.name
        return None

    def begin(self, name: str, params: DomainParams, seed: int, pose: tuple[float, float, float] | None,
              route: Sequence[str] | None, camera: bool, streams: str | None) -> StepReply | str:
        """Start robot ``name``'s episode: teleported to ``pose`` (None: drawn from ``seed``), nobody else moves.
        Returns its first frame, or the name of the driving robot standing on the start (try again later).
        ``ValueError``: θ the world cannot take now (another robot drives at other rates or image size)."""
        r = self.robots[name]
        differs = self._structural(params)
        if differs:
            busy = [o.name for o in self.robots.values() if o.running and o.name != name]
            if busy:
                now = self.sim.params[0]
                raise ValueError("the lab's shared world runs " + ", ".join(
                    f"{f} {getattr(now, f):g}" for f in differs) + f" for robot(s) {', '.join(busy)} now; this "
                    "episode asks " + ", ".join(f"{f} {getattr(params, f):g}" for f in differs))
            self._build(params)
        if pose is None:
            pose = self.sim.sample_start(np.random.default_rng(seed))
        pose = (float(pose[0]), float(pose[1]), float(pose[2]))
        other = self.blocker(name, pose)
        if other is not None:
            if self.robots[other].running:
                return other
            self.park(other)
        self._stop_recording(r)
        self.sim.set_params(r.index, params)
        self.sim.reset(r.index, int(seed), pose, route)
        r.running, r.stepping, r.frames, r.camera = True, False, 0, camera
        r.ended, r.reported = None, False
        self.pending.pop(name, None)
        if streams is not None and self.spec.streams is not None:
            r.recorder = StreamRecorder(self.sim, self.spec.streams, streams, rig=self.rig)
            r.recorder.frame(0.0)
        return self._reply(r, None, camera)

    def command(self, name: str, pwm: np.ndarray) -> None:
        """Robot ``name``'s wheel command for the next world step (it joins the lock-step with its first)."""
        r = self.robots[name]
        if not r.running:
            raise ValueError(f"robot {name!r} has no episode running")
        if not self.pending and self.round_start is None:
            self.round_start = time.monotonic()
        self.pending[name] = np.clip(np.asarray(pwm, dtype=np.float64).reshape(2), -1.0, 1.0)
        r.stepping = True

    def waiting_for(self) -> list[str]:
        """The robots in lock-step whose command for this step has not come."""
        return [r.name for r in self.robots.values() if r.stepping and r.ended is None and r.name not in self.pending]

    def due(self, now: float | None = None) -> bool:
        """Whether to step now: every stepping robot has its command, or the deadline passed for the others."""
        if not self.pending:
            return False
        if not self.waiting_for():
            return True
        now = time.monotonic() if now is None else now
        return self.round_start is not None and now - self.round_start > self.spec.step_deadline_s

    def step(self) -> dict[str, StepReply]:
        """One frame of the world: every robot with a command moves by it, the rest hold still (those that missed
        the deadline are dropped); returns each commanded robot's frame."""
        for name in self.waiting_for():
            r = self.robots[name]
            r.ended = Event(r.frames * self.frame_dt, Termination.AGENT_FAILURE,
                            f"no wheel command within the lab world's step deadline of {self.spec.step_deadline_s:g} s "
                            "(the other robots went on)", reason="timeout")
            self._idle(r)
        sim = self.sim
        commands = np.zeros((sim.n, 2))
        moved = [self.robots[name] for name in self.pending]
        for r in moved:
            commands[r.index] = self.pending[r.name]
        lanes = {r.name: (int(sim.routes.pin[r.index]), int(sim.routes.next[r.index])) for r in moved}
        sim.step(commands, self.trace)
        idle = [r.index for r in self.robots.values() if r not in moved]
        sim.frame_index[idle] -= 1  # a robot that did not move stays at its own frame: each episode on its own clock
        self.pending.clear()
        self.round_start = None
        frames = self._render([r for r in moved if r.camera])
        out = {}
        for r in moved:
            r.frames += 1
            if r.recorder is not None:
                r.recorder.frame(r.frames * self.frame_dt)
            out[r.name] = self._reply(r, lanes[r.name], r.camera, frames.get(r.index))
        return out

    def _render(self, robots: list[_Robot]) -> dict[int, np.ndarray]:
        if not robots:
            return {}
        active = np.zeros(self.sim.n, dtype=bool)
        active[[r.index for r in robots]] = True
        images = self.sim.render(active=active)
        return {r.index: images[r.index].copy() for r in robots}

    def _reply(self, r: _Robot, lanes: tuple[int, int] | None, camera: bool,
               image: np.ndarray | None = None) -> StepReply:
        sim, i = self.sim, r.index
        t = r.frames * self.frame_dt
        dt = sim.params[i].physics_dt
        trace = np.empty((0 if lanes is None else sim.substeps, 8))
        if lanes is not None:
            trace[:, 0] = t - self.frame_dt + dt * np.arange(1, sim.substeps + 1)
            trace[:, 1:] = self.trace[i, :, :7]
        if camera and image is None:
            image = self._render([r])[i]
        others = np.delete(sim.state[:, :3], i, axis=0)
        s = sim.state[i]
        reply = StepReply(trace, s.copy(), sim.lane[i].copy(), sim.routes.info(i, sim.lane[i]),
                          image if camera else None, front_range(sim.objects.colliders, others, s[ST.X], s[ST.Y],
                                                                 s[ST.THETA]),
                          lanes or (-1, -1), t)
        self._rules(r, reply)
        return reply

    def _rules(self, r: _Robot, reply: StepReply) -> None:
        """The lab's ending rules on robot ``r`` now: the domain's (collision at fault, off the road), a contact it
        suffered (an event, once), the world's own (the deadline)."""
        sim, i = self.sim, r.index
        other = int(sim.contact[i])
        if r.ended is not None:
            reply.ended = r.ended
        elif sim.collided[i] or sim.off_road[i]:
            event = end_event(sim, i)
            if sim.collided[i] and other >= 0 and sim.hit_kind[i] == 4:
                event = Event(reply.t, Termination.COLLISION, f"the robot ran into robot {self.spec.robots[other]!r} "
                              "(it was moving towards it: at fault)", with_="robot")
            reply.ended = Event(reply.t, event.kind, event.message, with_=event.with_)
        if other >= 0 and not sim.contact_fault[i] and not r.reported:
            r.reported = True
            reply.events.append(Event(reply.t, CONTACT_EVENT, f"robot {self.spec.robots[other]!r} ran into this "
                                      "robot, which was not moving towards it: the run is invalid (the lab's fault)",
                                      with_="robot"))
        if reply.ended is not None:
            self._idle(r)

    def _idle(self, r: _Robot) -> None:
        """Robot ``r``'s episode is over for the world: it stands still where it is, an obstacle."""
        r.stepping = False
        self.pending.pop(r.name, None)

    def end(self, name: str) -> None:
        """Robot ``name``'s job ended its episode: it stands where it is; its watchtower streams are written."""
        r = self.robots[name]
        self._stop_recording(r)
        r.running = r.stepping = False
        self.pending.pop(name, None)

    def _stop_recording(self, r: _Robot) -> None:
        if r.recorder is not None:
            r.recorder.close()
            r.recorder = None


# -- the server ----------------------------------------------------------------------------------------------------

def serve(spec: LabWorldSpec, address: LabWorldAddress, ready: Any = None, stop: threading.Event | None = None,
          ) -> None:
    """Serve ``spec``'s world at ``address`` until ``stop`` is set (or the process is ended); ``ready``: an event
    set once it listens. One connection per robot (the first message names it); a job that leaves parks it."""
    world = LabWorld(spec)
    listener = Listener(address.path, "AF_UNIX", authkey=address.authkey)
    incoming: queue.Queue[Connection] = queue.Queue()

    def accept() -> None:
        while True:
            try:
                incoming.put(listener.accept())
            except OSError:
                return
            except Exception:  # a peer without the key: refused, go on
                continue

    threading.Thread(target=accept, daemon=True, name="lab-world-accept").start()
    if ready is not None:
        ready.set()
    conns: dict[Connection, str | None] = {}
    blocked: dict[str, tuple[Connection, dict, float]] = {}
    try:
        while stop is None or not stop.is_set():
            while not incoming.empty():
                conns[incoming.get()] = None
            for conn in wait(list(conns), timeout=0.05):
                _handle(world, conns, blocked, conn)
            for conn, msg, since in list(blocked.values()):
                _start(world, conns, blocked, conn, msg, since)
            if world.due():
                for name, reply in world.step().items():
                    conn = next((c for c, n in conns.items() if n == name), None)
                    if conn is not None:
                        _send(conn, {"ok": True, "frame": reply})
    finally:
        listener.close()
        for conn in conns:
            conn.close()


def _send(conn: Connection, message: dict) -> None:
    with contextlib.suppress(OSError, ValueError):
        conn.send(message)


def _handle(world: LabWorld, conns: dict[Connection, str | None], blocked: dict, conn: Connection) -> None:
    """One message from a worker's plant (or its end of the connection)."""
    name = conns[conn]
    try:
        msg = conn.recv()
    except (EOFError, OSError):
        conns.pop(conn)
        conn.close()
        if name is not None:
            blocked.pop(name, None)
            world.robots[name].connected = False
            world.park(name)
        return
    op = msg.get("op") if isinstance(msg, dict) else None
    try:
        if op == "hello":
            robot = world.robots.get(msg.get("robot"))
            if robot is None or robot.connected:
                raise ValueError(f"robot {msg.get('robot')!r}: " + ("not a robot of this lab (it has "
                                 + ", ".join(world.spec.robots) + ")" if robot is None else "already driven by a job"))
            robot.connected = True
            conns[conn] = robot.name
            _send(conn, {"ok": True})
        elif name is None:
            raise ValueError("say hello (which robot) first")
        elif op == "begin":
            _start(world, conns, blocked, conn, msg, time.monotonic())
        elif op == "step":
            r = world.robots[name]
            if r.ended is not None:  # the world ended it (the deadline) while its agent thought
                _send(conn, {"ok": True, "frame": world._reply(r, None, False)})  # no physics: it did not move
            else:
                world.command(name, msg["pwm"])
        elif op == "end":
            world.end(name)
            _send(conn, {"ok": True})
        else:
            raise ValueError(f"unknown op {op!r}")
    except (ValueError, KeyError, TypeError) as exc:
        _send(conn, {"ok": False, "error": str(exc)})


def _start(world: LabWorld, conns: dict, blocked: dict, conn: Connection, msg: dict, since: float) -> None:
    """Begin a robot's episode, or keep it waiting while a driving robot stands on its start (up to a limit)."""
    name = conns.get(conn)
    if name is None:
        blocked.pop(next((n for n, v in blocked.items() if v[0] is conn), ""), None)
        return
    try:
        out = world.begin(name, msg["params"], msg["seed"], msg["pose"], msg["route"], msg["camera"], msg["streams"])
    except (ValueError, KeyError, TypeError) as exc:
        blocked.pop(name, None)
        _send(conn, {"ok": False, "error": str(exc)})
        return
    if isinstance(out, str):
        if time.monotonic() - since > world.spec.start_wait_s:
            blocked.pop(name, None)
            _send(conn, {"ok": False, "error": f"its start stayed blocked by robot {out!r} (driving) for "
                                               f"{world.spec.start_wait_s:g} s"})
        else:
            blocked[name] = (conn, msg, since)
        return
    blocked.pop(name, None)
    _send(conn, {"ok": True, "frame": out, "substeps": world.sim.substeps, "frame_rate": 1.0 / world.frame_dt})


# -- the worker's side -------------------------------------------------------------------------------------------

def connect(address: LabWorldAddress, robot: str) -> Connection:
    """A connection to the lab world's server that drives ``robot``; :class:`RobotFailure` when it cannot be had."""
    try:
        conn = Client(address.path, "AF_UNIX", authkey=address.authkey)
    except (OSError, EOFError) as exc:
        raise RobotFailure("start-failed", f"cannot reach the lab's shared world at {address.path}: {exc}") from None
    _ask(conn, {"op": "hello", "robot": robot}, robot)
    return conn


def _ask(conn: Connection, message: dict, robot: str, timeout: float | None = None) -> dict:
    """Send ``message`` and wait for the world's answer (``timeout`` [s], None: as long as it takes)."""
    try:
        conn.send(message)
        if timeout is not None and not conn.poll(timeout):
            raise RobotFailure("step-timeout", f"the lab's shared world did not answer robot {robot!r} within "
                                               f"{timeout:g} s")
        reply = conn.recv()
    except (OSError, EOFError) as exc:
        raise RobotFailure("connection-lost", f"robot {robot!r}: the lab's shared world is gone ({exc})") from None
    if not reply.get("ok"):
        raise RobotFailure("not-understood", f"robot {robot!r}: the lab's shared world refused: {reply.get('error')}")
    return reply


class LabWorldPlant:
    """Robot ``robot`` of a lab's shared world as a plant of one robot (see the module): θ ``params`` for its
    episodes, ``streams``: a folder under which each episode's watchtower streams are written (``<k>/``, the k-th
    episode begun by this plant; None: none recorded). ``image_filter``: what its camera frames pass (the JPEG
    round trip camera agents see)."""

    n = 1

    def __init__(self, conn: Connection, robot: str, map_: Map | str, params: DomainParams,
                 streams: str | Path | None = None, image_filter: Any = None, timeout: float | None = None):
        self.conn, self.robot, self.params = conn, robot, params
        self.map = load_map(map_) if isinstance(map_, str) else map_
        self.streams = None if streams is None else Path(streams)
        self.image_filter = image_filter
        self.timeout = timeout
        self.begun = 0
        self.folder: Path | None = None
        self._graph = None

    @property
    def frame_rate(self) -> float:
        return self.params.frame_rate

    def begin(self, seeds: Sequence[int], poses: Sequence[Any], routes: Sequence[Any], seconds: float,
              camera: bool, privileged: Sequence[bool]) -> int:
        self.folder = None if self.streams is None else self.streams / str(self.begun)
        self.begun += 1
        pose = None if poses[0] is None else tuple(float(v) for v in poses[0])
        reply = _ask(self.conn, {"op": "begin", "params": self.params, "seed": int(seeds[0]), "pose": pose,
                                 "route": None if routes[0] is None else list(routes[0]), "camera": camera,
                                 "streams": None if self.folder is None else str(self.folder)}, self.robot)
        first: StepReply = reply["frame"]
        self.substeps = int(reply["substeps"])
        s = first.state
        self.rows = [np.array([[0.0, s[ST.X], s[ST.Y], s[ST.THETA], s[ST.V], s[ST.OMEGA], 0.0, 0.0]])]
        self.lanes: list[tuple[int, int]] = []
        self.last = first
        self.open = True
        return max(1, round(seconds * self.params.frame_rate))

    def frames(self, alive: np.ndarray) -> list[np.ndarray | None]:
        image = self.last.camera
        if image is None or not alive[0]:
            return [None]
        return [self.image_filter(image) if self.image_filter is not None else image]

    def observation(self, i: int, image: np.ndarray | None, privileged: bool) -> Observation:
        s, res = self.last.state, self.params.encoder_resolution
        ticks = wheel_ticks(s[[ST.WHEEL_L, ST.WHEEL_R]], res)
        if not privileged:
            return Observation(image, self.last.t, (float(ticks[0] * res), float(ticks[1] * res)), res,
                               range_reader=lambda: self.last.range)
        return Observation(image, self.last.t, (float(ticks[0] * res), float(ticks[1] * res)), res,
                           LanePose.from_row(self.last.lane), self.last.route,
                           (float(s[ST.X]), float(s[ST.Y]), float(s[ST.THETA])), lambda: self.last.range)

    def time(self, i: int) -> float:
        return self.last.t

    def advance(self, commands: np.ndarray, alive: np.ndarray, k: int) -> list[tuple[int, Event, bool]]:
        reply = _ask(self.conn, {"op": "step", "pwm": np.asarray(commands[0], dtype=np.float64)}, self.robot,
                     self.timeout)
        self.last = frame = reply["frame"]
        if frame.trace.shape[0]:
            self.rows.append(frame.trace)
            self.lanes.append(frame.lanes)
        out = [(0, e, False) for e in frame.events]
        if frame.ended is not None:
            out.append((0, frame.ended, True))
        return out

    def samples(self, i: int, frames: int) -> np.ndarray:
        return np.vstack(self.rows)

    def route_lanes(self, i: int, frames: int) -> tuple[Any, np.ndarray, np.ndarray, int, list] | None:
        if not self.lanes or self.last.route is None:
            return None
        from proxybench.domain.routes import RouteGraph

        if self._graph is None:
            self._graph = RouteGraph(LaneNetwork(self.map))
        pins = np.array([p for p, _ in self.lanes], dtype=np.int64)
        nexts = np.array([q for _, q in self.lanes], dtype=np.int64)
        return self._graph, pins, nexts, self.substeps, []

    def meta(self, i: int) -> dict[str, Any]:
        from proxybench.domain.kinds import DomainKind

        return {"source": DomainKind.SIMULATION, "params": self.params.model_dump(mode="json"),
                "lab_world": {"robot": self.robot, "streams": None if self.folder is None else str(self.folder)}}

    def wheel_distance(self, i: int) -> float:
        return self.params.wheel_distance

    def end(self) -> None:
        if self.open:
            self.open = False
            _ask(self.conn, {"op": "end"}, self.robot, self.timeout)
