"""gym-duckietown as the backend of a robot node: ``proxybench gym serve``.

:class:`GymRobot` is a :class:`~proxybench.protocol.robot_backend.RobotBackend` whose world is
gym-duckietown, running in its own environment as a child process (:mod:`proxybench.gym.bridge`, a script
run by gym's interpreter, over a private pipe). What the robot does is gym's: its OpenGL renderer, its DB18
dynamics with delay and trim, its collision and drivable-tile checks (its "invalid pose" ends the episode:
``collision`` when an object's box is hit, else ``off_road``). proxybench adds only the *true lane pose* a
privileged agent reads, computed by proxybench's lane geometry from gym's pose on the same map (gym's own
lane curves are Bézier curves; its ``get_lane_pos2`` raises outside a lane, so it cannot describe a robot
leaving the road), and the top-down picture of ``get_ui_image``.
"""

from __future__ import annotations

import json
import math
import mmap
import os
import struct
import subprocess
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from proxybench.domain.events import Event
from proxybench.domain.lane_pose import LanePose, lane_pose
from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import Map, MapError, MapObject, load_map, parse_map
from proxybench.domain.simulator import start_pose
from proxybench.domain.topdown import top_down
from proxybench.gym.environment import default_path
from proxybench.gym.params import GymParams
from proxybench.protocol.robot_backend import BackendState, FrameStep

__all__ = ["BRIDGE", "GymBridgeError", "GymRobot", "bridge_environment", "resolve_map"]

BRIDGE = Path(__file__).with_name("bridge.py")
#: DB18 wheel encoder: 135 ticks per turn (duckietown-world's DynamicModelParameters)
ENCODER_RESOLUTION = 2 * math.pi / 135
WHEEL_DISTANCE = 0.102  # gym's WHEEL_DIST [m]


class GymBridgeError(RuntimeError):
    """The gym-duckietown child failed (did not start, exited, or answered an error)."""


def resolve_map(name: str, venv: Path | None = None) -> Map:
    """A map by file path, proxybench built-in name, or the name of a duckietown-world map gym ships
    (``udem1``, ``ETHZ_loop``, ...: read from gym's environment). proxybench's names come first:
    gym's ``small_loop`` (3×3) is proxybench's ``loop_3x3``; proxybench's ``small_loop`` is a 2×2 loop."""
    try:
        return load_map(name)
    except (MapError, FileNotFoundError) as first:
        found = sorted((venv or default_path()).glob(f"lib/python3*/site-packages/duckietown_world/data/gd1/maps/"
                                                       f"{name}.yaml")) if "/" not in name else []
        if not found:
            raise MapError(f"{first}\n(nor is {name!r} a duckietown-world map of gym's environment)") from None
        return load_map(found[0])


def bridge_environment() -> dict[str, str]:
    """The environment gym's process runs in: ours, with one BLAS thread and Mesa's rasteriser in gym's own
    thread, unless the caller chose otherwise. gym's DB18 model inverts a 2×2 matrix at every physics step;
    OpenBLAS's thread pool made that ~4 ms of spinning CPU per step on a busy 2-core machine. llvmpipe's
    rasteriser threads (one per core by default) cost more than they save on gym's frames: gym alone made
    175 steps/s with them and 198 without at 160×120, 34.5 and 37.7 at 640×480 (2 cores beside a nice-10
    neighbour, blocks interleaved), and without them the node's own processes keep the other core. Neither
    changes a number or a pixel (checked: the bridge's frames with 0 and 2 rasteriser threads, domain
    randomisation on and off, are equal)."""
    env = dict(os.environ)
    for key in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(key, "1")
    env.setdefault("LP_NUM_THREADS", "0")
    return env


def _map_text(m: Map) -> str:
    path = Path(m.path)
    if not path.is_file():
        raise ValueError(f"map {m.name!r} has no source file to give gym-duckietown")
    return path.read_text(encoding="utf-8")


class GymRobot:
    """One gym-duckietown robot with θ ``params``, started in the environment at ``venv`` (default
    :func:`~proxybench.gym.environment.default_path`) on ``map_`` (see :func:`resolve_map`). Its camera
    frames come through a shared file (Linux's memfd) where there is one and ``shared_frames``, else through the
    pipe: the same pixels (tested), with fewer copies and system calls in gym's process."""

    def __init__(self, params: GymParams, map_: str = "loop_3x3", venv: Path | None = None,
                 stderr: Any = None, shared_frames: bool = True):
        self.params = params
        venv = Path(venv or default_path())
        python = venv / "bin" / "python"
        if not python.exists():
            raise GymBridgeError(f"no gym-duckietown environment at {venv}: run `proxybench gym setup`")
        m = resolve_map(map_, venv)
        self._maps: dict[str, tuple[Map, LaneNetwork]] = {}
        text = _map_text(m)
        self._maps[text] = (m, LaneNetwork(m))
        fd = _frame_file() if shared_frames else None
        try:
            self.proc = subprocess.Popen([str(python), "-u", str(BRIDGE)], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE, stderr=stderr, env=bridge_environment(),
                                         pass_fds=() if fd is None else (fd,))
            _widen(self.proc.stdout.fileno())  # room for the frames the bridge pushes ahead
            self._send({"op": "init", "params": _plain(params), "map": text, "frames_fd": fd})
            _warm(*self._maps[text])  # while gym starts (seconds): else the first episode pays it, ~1 s
            hello, _blob = self._receive()
            #: the frames gym's process pushes, when it writes them into the shared file (else through the pipe)
            self._slots = _frames(fd, hello.get("slots", 0), hello["camera"]) if fd is not None else None
        finally:
            if fd is not None:
                os.close(fd)  # the map (and gym's process) keep the file
        self.version = hello["version"]
        self.physics_rate = float(hello["frame_rate"])
        self.frame_skip = int(hello["frame_skip"])
        self.width, self.height = hello["camera"]
        self.frame_dt = self.frame_skip / self.physics_rate
        self.encoder_resolution = ENCODER_RESOLUTION
        self._text = text
        self._sent = text
        self._seq = 0  # pushes of the bridge's stream read since its last answer
        self._state: dict[str, Any] = {}
        self._end: Event | None = None

    # ------------------------------------------------------------------------------------- the pipe
    def _call(self, msg: dict[str, Any], blob: bool = False) -> Any:
        """Send ``msg`` and return its answer, skipping the stream's pushes the bridge sent before it read it."""
        self._send(msg)
        reply, payload = self._receive()
        while "seq" in reply:
            reply, payload = self._receive()
        self._seq = 0  # a stream goes on after any answer, numbered from 1 again
        return (reply, payload) if blob else reply

    def _send(self, msg: dict[str, Any]) -> None:
        data = json.dumps(msg).encode()
        try:
            self.proc.stdin.write(struct.pack(">I", len(data)) + data)
            self.proc.stdin.flush()
        except OSError as exc:
            self._failed(exc)

    def _receive(self) -> tuple[dict[str, Any], bytes]:
        """The bridge's next message (an answer or a push) and its blob; an error it reports raises."""
        try:
            head = self._read(4)
            (n,) = struct.unpack(">I", head)
            reply = json.loads(self._read(n))
            payload = self._read(reply["blob"]) if "blob" in reply else b""
        except (OSError, struct.error, ValueError) as exc:
            self._failed(exc)
        if not reply.get("ok"):
            raise GymBridgeError(f"gym-duckietown: {reply.get('error')}\n{reply.get('trace', '')}".rstrip())
        return reply, payload

    def _failed(self, exc: Exception) -> NoReturn:
        code = self.proc.poll()
        raise GymBridgeError(f"the gym-duckietown process failed ({type(exc).__name__}: {exc}; exit status "
                             f"{code}); its messages are above on stderr") from None

    def _read(self, n: int) -> bytes:
        buf = self.proc.stdout.read(n)
        if buf is None or len(buf) < n:
            raise OSError("the pipe closed")
        return buf

    def probe(self) -> dict[str, Any]:
        """gym's own view of the robot (its frame's ``cur_pos``, ``cur_angle``, the tile there): for checks."""
        return self._call({"op": "probe"})

    def close(self) -> None:
        """End the gym process (it ends on EOF too)."""
        if self.proc.poll() is None:
            try:
                self._call_quit()
            finally:
                try:
                    self.proc.wait(5)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()

    def _call_quit(self) -> None:
        data = json.dumps({"op": "quit"}).encode()
        try:
            self.proc.stdin.write(struct.pack(">I", len(data)) + data)
            self.proc.stdin.close()
        except OSError:
            pass
        self.proc.stdout.close()  # a push the bridge is writing now fails, and it reads the quit

    # ------------------------------------------------------------------------------- RobotBackend
    def set_map(self, text: str) -> None:
        if text not in self._maps:
            try:
                m = parse_map(text, path="<set_map.map_data>", name="set_map")
            except MapError as exc:
                raise ValueError(f"set_map: map_data is not a valid map:\n{exc}") from exc
            self._maps[text] = (m, LaneNetwork(m))
        if text != self._sent:
            self._call({"op": "set_map", "map": text})
            self._sent = text
        self._text = text

    def reset(self, seed: int, pose: tuple[float, float, float] | None, route: list[str] | None,
              objects: tuple[MapObject, ...], camera: bool = True) -> None:
        m, net = self._maps[self._text]
        if pose is None:
            pose = start_pose(m, seed, net=net)
        extra = [{"name": o.name or f"object{i}", "kind": o.kind, "x": o.x, "y": o.y, "theta": o.heading}
                 for i, o in enumerate(objects)]
        self._state = self._call({"op": "reset", "seed": int(seed), "pose": [float(v) for v in pose],
                                  "objects": extra})
        self._end = None
        self._frame: tuple[float, np.ndarray] | None = None
        self._call({"op": "stream", "render": camera})  # gym now computes periods ahead, pushing them with frames

    def step_frame(self, pwm: np.ndarray) -> FrameStep:
        """The command goes to the bridge without a round trip; the period it belongs to was (usually) pushed
        already, computed before the command came, which gym's delay allows (see the bridge's ``depth``)."""
        action = [min(max(float(v), -1.0), 1.0) for v in pwm[:2]]
        self._send({"op": "commit", "pwm": action})
        self._seq += 1
        reply, blob = self._receive()
        if reply.get("seq") != self._seq:
            raise GymBridgeError(f"gym-duckietown's bridge pushed period {reply.get('seq')}, expected {self._seq}")
        self._state = reply
        if "slot" in reply and self._slots is not None:
            self._frame = (reply["t"], self._slots[reply["slot"]].copy())  # gym rewrites the slot later
        elif blob:
            self._frame = (reply["t"], self._image(blob))
        if self._end is None and "end" in reply:
            self._end = Event.from_dict({"t": float(reply["t"]), **reply["end"]})
        trace = np.asarray(reply["trace"], dtype=np.float64).reshape(-1, 8)
        trace[:, 6:8] = action  # the command of this period (NaN where it was computed before it came)
        return FrameStep(trace)

    def time(self) -> float:
        return float(self._state["t"])

    def camera(self) -> np.ndarray:
        if self._frame is not None and self._frame[0] == self._state["t"]:
            return self._frame[1]
        _reply, blob = self._call({"op": "camera"}, blob=True)
        return self._image(blob)

    def _image(self, blob: bytes) -> np.ndarray:
        return np.frombuffer(blob, dtype=np.uint8).reshape(self.height, self.width, 3)

    def state(self) -> BackendState:
        x, y, th, v, w, left, right = self._state["motion"]
        kind = self._end.kind if self._end is not None else None
        return BackendState((x, y, th), v, w, (left, right), kind == "off_road", kind == "collision")

    def lane(self) -> tuple[LanePose, None]:
        _m, net = self._maps[self._text]
        x, y, th = self._state["motion"][:3]
        return lane_pose(net, x, y, th, WHEEL_DISTANCE), None

    def route_choices(self) -> None:
        return None

    def ending(self) -> Event | None:
        return self._end

    def info(self) -> dict[str, Any]:
        p = self.params
        return {"kind": "simulation", "frame_rate": 1.0 / self.frame_dt, "physics_rate": self.physics_rate,
                "wheel_distance": WHEEL_DISTANCE, "encoder_resolution": ENCODER_RESOLUTION,
                "image_width": self.width, "image_height": self.height, "params": p.public(),
                "simulator": {"name": "gym-duckietown", "package": "duckietown-gym-daffy", "version": self.version,
                              "hidden": p.hidden, "sha256": p.sha256,
                              "changed": None if p.hidden else _plain_values(p.changed)}}

    def description(self) -> str:
        theta = ("parameters HIDDEN (sha256 " + self.params.sha256[:16] + "…)" if self.params.hidden else
                 "parameters " + (", ".join(f"{k}={v}" for k, v in self.params.changed.items()) or "gym's defaults"))
        return (f"gym-duckietown {self.version} node: ONE SIMULATED Duckiebot (another simulator, not proxybench's "
                f"and not a real robot) behind AIDO's simulator protocol. Camera {self.width}x{self.height} at "
                f"{1.0 / self.frame_dt:g} Hz, DB18 dynamics at {self.physics_rate:g} Hz; {theta}.")

    def top_view(self, px_per_tile: int) -> np.ndarray:
        m, _net = self._maps[self._text]
        return top_down(m, np.array([self._state["motion"][:3]]), px_per_tile)


def _frame_file() -> int | None:
    """An anonymous shared file for the frames (Linux's memfd), or None where there is none (then the pipe)."""
    try:
        return os.memfd_create("proxybench-gym-frames")
    except (AttributeError, OSError):
        return None


def _frames(fd: int, slots: int, camera: list[int]) -> np.ndarray | None:
    """The shared frame file that gym's process sized: ``slots`` read-only frames (H, W, 3), or None (it has none)."""
    if slots <= 0:
        return None
    width, height = camera
    size = slots * height * width * 3
    if os.fstat(fd).st_size < size:
        raise GymBridgeError(f"gym's process sized the shared frame file {os.fstat(fd).st_size} bytes, not {size}")
    return np.frombuffer(mmap.mmap(fd, size, prot=mmap.PROT_READ), dtype=np.uint8).reshape(slots, height, width, 3)


def _warm(m: Map, net: LaneNetwork) -> None:
    """Load what the node's first frame would otherwise load: the lane pose's compiled code (Numba's cache,
    ~0.6 s of CPU on a 2-core machine, spread over the first episode's frames otherwise)."""
    lane_pose(net, *start_pose(m, 0, net=net), WHEEL_DISTANCE)


def _widen(fd: int, size: int = 1 << 20) -> None:
    """Make the pipe at ``fd`` hold ``size`` bytes where the system allows (Linux: up to
    /proc/sys/fs/pipe-max-size); elsewhere, or refused, it keeps its size and the bridge looks ahead less."""
    try:
        import fcntl

        limit = int(Path("/proc/sys/fs/pipe-max-size").read_text())
        fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, min(size, limit))
    except (ImportError, AttributeError, OSError, ValueError):
        pass


def _plain(params: GymParams) -> dict[str, Any]:
    """θ for the child (hidden or not: the child is ours)."""
    return _plain_values(params.values)


def _plain_values(values: dict[str, Any]) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in values.items()}
