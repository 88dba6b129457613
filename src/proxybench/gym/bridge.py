"""gym-duckietown behind a private pipe: the child half of ``proxybench gym serve``.

Run by gym-duckietown's own interpreter (its venv: numpy 1.23, pyglet 1.5), never imported by proxybench,
and it imports nothing of proxybench (whose numpy differs). It reads requests on stdin and writes answers on
stdout, each one message: a 4-byte big-endian length, that many bytes of JSON, then, when the JSON has
``"blob": N``, N raw bytes (a camera frame, H×W×3 uint8, C order). Floats travel as JSON numbers, which
round-trip exactly. A pushed frame goes instead, where the parent gave a shared file (``frames_fd``), into
slot ``"slot": i`` of it (frame ``i`` at byte ``i·H·W·3``): the frames of a stream then cost gym's process
one copy, not three and a pipe's worth of system calls. Requests (``op``):

- ``init``: ``params`` (gym's names, already checked by the parent), ``map`` (YAML text), optionally
  ``frames_fd`` (an inherited file descriptor, sized here) → the simulator built, gym's version, rates,
  camera size and ``slots`` (the frames the shared file holds, 0 without one);
- ``set_map``: ``map`` (YAML text) → the map interpreted by gym (``Simulator._interpret_map``);
- ``reset``: ``seed``, ``pose`` (x, y, θ in the map frame), ``objects`` (parked robots and duckies, map
  frame) → gym's reset (domain randomisation drawn from ``seed``), then the robot placed at ``pose`` and
  its DB18 dynamics built as gym's reset builds them, with the given trim, delay and coefficients;
- ``stream``: ``render`` → ``ok``; from then on, until the next ``reset`` or ``set_map``, the bridge *pushes*
  camera periods, ``{"ok": true, "seq": k, "t", "motion", "trace", ["end"]}`` and, with ``render``, the frame:
  each period is ``frame_skip`` physics updates of gym (``update_physics``), a trace row after each, gym's own
  episode end (``_compute_done_reward``), then ``render_obs`` (the order of gym's own ``step``); as many
  periods ahead of their commands as gym's command delay allows (see :meth:`Bridge.depth`), the commands NaN
  in their trace;
- ``commit``: ``pwm`` → no answer: the command of the oldest period not yet committed, written where the stand-in
  stood (a period that could not be computed ahead is computed now and pushed). The parent reads one push per
  command, so its reading never waits on a round trip, and gym works while the caller's agent decides. Any other
  request first puts the state back to the last committed period; the stream goes on after the answer with its
  pushes numbered from 1 again (those sent before the answer are stale: the parent skips them);
- ``camera`` → gym's rendered observation (``render_obs``) for now; ``probe`` → gym's own pose and tile;
- ``quit``.

Every answer is ``{"ok": true, ...}`` or ``{"ok": false, "error": text}``. Poses go back in the map frame by
gym's own ``cartesian_from_weird`` (x, H·tile − z, angle).
"""

import json
import math
import os
import select
import struct
import sys
import traceback

_OUT = sys.stdout.buffer
sys.stdout = sys.stderr  # whatever gym prints must not reach the pipe
#: the most camera periods computed ahead of their commands (fewer where gym's delay or the pipe allows fewer)
MAX_AHEAD = 3
#: slots of the shared frame file: a push may be read while the look-ahead writes the periods after it
SLOTS = MAX_AHEAD + 2


class _Requests:
    """Requests from fd 0, unbuffered by Python, so that :meth:`waiting` sees a request already read."""

    def __init__(self):
        self.buf = bytearray()

    def _message(self):
        if len(self.buf) < 4:
            return None
        (n,) = struct.unpack(">I", self.buf[:4])
        if len(self.buf) < 4 + n:
            return None
        msg = json.loads(bytes(self.buf[4:4 + n]))
        del self.buf[:4 + n]
        return msg

    def waiting(self):
        """Is a request there to read (without blocking)?"""
        return len(self.buf) >= 4 or bool(select.select([0], [], [], 0)[0])

    def read(self):
        """The next request (blocking), None at EOF."""
        while True:
            msg = self._message()
            if msg is not None:
                return msg
            data = os.read(0, 1 << 16)
            if not data:
                return None
            self.buf += data


_IN = _Requests()


def _write(msg, blob=b""):
    if blob:
        msg["blob"] = len(blob)
    data = json.dumps(msg).encode()
    _OUT.write(struct.pack(">I", len(data)) + data + blob)
    _OUT.flush()


class Bridge:
    """One gym-duckietown ``Simulator`` driven one camera period at a time."""

    def __init__(self, params, map_text, frames_fd=None):
        import pyglet

        pyglet.options["headless"] = True  # EGL through Mesa: no X server
        pyglet.options["debug_gl"] = False  # pyglet asks glGetError after each of ~280 GL calls a frame otherwise
        import logging

        import yaml
        from duckietown_world.world_duckietown import pwm_dynamics
        from gym_duckietown import simulator as gs

        for name in ("gym-duckietown", "duckietown_world", "zuper"):  # their INFO/DEBUG lines, per reset
            logging.getLogger(name).setLevel(logging.WARNING)

        self.gs, self.dyn, self.yaml = gs, pwm_dynamics, yaml
        self.p = dict(params)
        ctor = {k: self.p[k] for k in CTOR if self.p.get(k) is not None}
        ctor.setdefault("max_steps", 10**9)  # none given: the caller's episode length is the only limit
        self.env = gs.Simulator(map_name="small_loop", **ctor)
        self._map_key = None
        self._queue = []  # periods computed ahead of their commands: (state before, first command stamp, stamp after)
        self._stream = None  # the render flag while streaming, else None
        self._depth = self._limit = 0  # periods that may be ahead: by gym's delay and the pipe; now
        self._seq = 0  # pushes sent in this stream
        self._slots, self._pushed = self._share(frames_fd), 0
        self.set_map(map_text, ())
        self.reset(0, [0.0, 0.0, 0.0], [])  # a first episode: the first one after gym's constructor renders apart
        self.camera()

    def _share(self, fd):
        """The shared frame file as SLOTS arrays of one frame each, or None (no file: frames in the pipe)."""
        if fd is None:
            return None
        import mmap

        shape = (SLOTS, self.env.camera_height, self.env.camera_width, 3)
        size = shape[0] * shape[1] * shape[2] * 3
        os.ftruncate(fd, size)
        self._mmap = mmap.mmap(fd, size)
        os.close(fd)
        return self.gs.np.frombuffer(self._mmap, dtype=self.gs.np.uint8).reshape(shape)

    # ------------------------------------------------------------------------------------------ map
    def set_map(self, text, objects):
        key = (text, tuple(tuple(sorted(o.items())) for o in objects))
        if key == self._map_key:
            return
        data = self.yaml.safe_load(text)
        if objects:
            data = dict(data)
            extra = data.get("objects") or {}
            extra = dict(extra) if isinstance(extra, dict) else {f"ob{i:02d}": o for i, o in enumerate(extra)}
            for o in objects:
                extra[o["name"]] = {"kind": o["kind"], "height": 0.12 if o["kind"] == "duckiebot" else 0.08,
                                    "pose": {"~SE2Transform": {"p": [o["x"], o["y"]],
                                                               "theta_deg": math.degrees(o["theta"])}}}
            data["objects"] = extra
        self.env._interpret_map(data)
        self.env.map_data = data
        self._map_key = key

    # ------------------------------------------------------------------------------------- episodes
    def reset(self, seed, pose, objects):
        env, p = self.env, self.p
        if objects or self._map_key[1]:
            self.set_map(self._map_key[0], objects)
        env.seed(p["seed"] if p.get("seed") is not None else seed)
        gl = self.gs.gl  # gym's reset places the light under the matrices its last frame left: an episode's
        for mode in (gl.GL_MODELVIEW, gl.GL_PROJECTION):  # light would depend on where the one before ended
            gl.glMatrixMode(mode)
            gl.glLoadIdentity()
        env.reset()
        for k in ("cam_height", "cam_fov_y"):  # gym's reset sets them (and randomises them): ours on top
            if k in p:
                setattr(env, k, p[k] * (env.randomization_settings[f"camera_{k[4:]}"] if self._cam_rand() else 1))
        if "cam_angle" in p:
            scale = env.randomization_settings["camera_angle"] if self._cam_rand() else 1
            env.cam_angle = [p["cam_angle"] * scale, 0, 0]
        pos, angle = env.weird_from_cartesian(self.gs.geometry.SE2_from_translation_angle(pose[:2], pose[2]))
        env.cur_pos, env.cur_angle = self.gs.np.asarray(pos, dtype=float), float(angle)
        trim = p["trim"] + (float(env.randomization_settings["trim"][0]) if env.dynamics_rand else 0.0)
        model = self.dyn.DynamicModelParameters(
            u1=p["u1"], u2=p["u2"], u3=p["u3"], w1=p["w1"], w2=p["w2"], w3=p["w3"], uar=p["uar"], ual=p["ual"],
            war=p["war"] * (1.0 + trim), wal=p["wal"] * (1.0 - trim))
        # gym's delay applies the command stamped nearest to t − delay; under one physics step that is the command
        # just given, which gym-duckietown 6.1.34 fails to find (IndexError): the undelayed model is that rule
        delayed = p["delay"] > env.delta_time + 1e-9
        factory = self.dyn.ApplyDelay(model, p["delay"], self.dyn.PWMCommands(0, 0)) if delayed else model
        q = env.cartesian_from_weird(env.cur_pos, env.cur_angle)
        v0 = self.gs.geometry.se2_from_linear_angular(self.gs.np.array([0, 0]), 0)
        env.state = factory.initialize(c0=(q, v0), t0=0)
        self.ticks = 0
        self.dt = env.delta_time
        self._ended = None  # (tick, reason) of gym's end, while it lasts
        return self.state()

    def _cam_rand(self):
        return self.env.domain_rand or self.env.camera_rand

    def _motion(self):
        """[x, y, θ, v, ω, left wheel angle, right wheel angle]: the pose by gym's ``cartesian_from_weird``
        (map frame), the body velocity and wheel angles of its DB18 state."""
        env, geometry = self.env, self.gs.geometry
        (x, y), theta = geometry.translation_angle_from_SE2(env.cartesian_from_weird(env.cur_pos, env.cur_angle))
        inner = getattr(env.state, "state", env.state)  # ApplyDelay wraps the DB18 model
        (lin, _lat), omega = geometry.linear_angular_from_se2(inner.v0)
        return [float(x), float(y), float(theta), float(lin), float(omega), float(inner.axis_left_rad),
                float(inner.axis_right_rad)]

    def state(self):
        return {"motion": self._motion(), "t": self.ticks * self.dt}

    def _action(self, pwm):
        np = self.gs.np
        return np.clip(np.array(pwm, dtype=float), -1, 1)

    def _physics(self, action):
        env = self.env
        rows = []
        for _ in range(env.frame_skip):
            env.update_physics(action)
            self.ticks += 1
            m = self._motion()
            rows.append([self.ticks * self.dt, *m[:5], float(action[0]), float(action[1])])
        done = env._compute_done_reward()
        out = {"motion": m, "t": self.ticks * self.dt, "trace": rows}  # the state after the last update
        if done.done:
            out["end"] = self._end_reason(done.done_code)
        else:
            self._ended = None
        return out

    def _end_reason(self, code):
        """Why gym ends the episode, computed where its end begins and kept while gym goes on saying done (the
        collision test costs ~0.2 ms a period, some 5 % of gym's own step)."""
        if self._ended is None:
            self._ended = (self.ticks, self._why(code))
        return self._ended[1]

    # ----------------------------------------------------------------------------- stepping ahead
    def depth(self):
        """How many periods may be computed before their commands: exact while gym's command delay is longer
        than them (a command acts only ``delay`` later, and gym takes the command stamped nearest to t − delay),
        objects are static, and the pipe holds the frames; 0 turns look-ahead off."""
        env, dt = self.env, self.env.delta_time
        if not all(getattr(o, "static", True) for o in env.objects):
            return 0
        by_delay = int((self.p["delay"] - 0.5 * dt - 1e-9) // (env.frame_skip * dt))
        frame = env.camera_width * env.camera_height * 3 if self._stream and self._slots is None else 0
        try:
            import fcntl

            pipe = fcntl.fcntl(_OUT.fileno(), fcntl.F_GETPIPE_SZ)
        except (ImportError, AttributeError, OSError):  # not Linux, or not a pipe: the default size
            pipe = 1 << 16
        return max(0, min(MAX_AHEAD, by_delay, max(1, pipe // (frame + 4096))))

    def start_stream(self, render):
        self.undo_ahead()
        self._stream = bool(render)
        self._depth = self._limit = self.depth()

    def end_stream(self):
        self._stream = None

    def can_advance(self):
        return self._stream is not None and len(self._queue) < self._limit

    def advance(self):
        """Compute the next period ahead with NaN commands: (answer, frame) to push, or None when the stand-in
        reached the motion (then that period waits for its command)."""
        st = self.env.state
        saved, first = self._save(), st.t
        nan = self.gs.np.full(2, float("nan"))
        out = self._physics(nan)
        if not (self.gs.np.isfinite(out["motion"]).all() and self.gs.np.isfinite(self.env.cur_pos).all()):
            self._restore(saved)
            self._limit = len(self._queue)  # not further until a command comes
            return None
        self._queue.append((saved, first, self.env.state.t))
        return self._push(out)

    def commit(self, pwm):
        """The command of the oldest uncommitted period: written in, or that period computed now. Returns what
        to push (a period computed now), else None."""
        action = self._action(pwm)
        if not self._queue:
            self._limit = self._depth  # a stand-in that reached the motion stopped the look-ahead until now
            return self._push(self._physics(action))
        _saved, first, after = self._queue.pop(0)
        states = [self.env.state] + [q[0][0] for q in self._queue]
        for st in states:  # each state holds its own copy of the command history
            self._command(st, first, after, action)
        self.env.last_action, self.env.wheelVels = action, action * self.env.robot_speed
        return None

    def _push(self, out):
        """A period to push: its answer and, streaming with the camera, its frame (as a blob, or in a slot)."""
        self._seq += 1
        msg, frame = {"ok": True, **out, "seq": self._seq}, b""
        if self._stream and self._slots is not None:
            msg["slot"] = self._pushed % SLOTS  # never reset: a slot is rewritten only SLOTS pushes later
            self._pushed += 1
            self._slots[msg["slot"]] = self.env.render_obs()
        elif self._stream:
            frame = self.camera()
        return msg, frame

    def _save(self):
        env = self.env
        st = env.state
        return (st, st.t, len(st.commands), len(st.timestamps), env.cur_pos, env.cur_angle, env.step_count,
                env.timestamp, env.speed, env.last_action, env.wheelVels, self.ticks)

    def _restore(self, saved):
        env = self.env
        st, t, n_cmd, n_ts, *rest = saved
        del st.commands[n_cmd:], st.timestamps[n_ts:]  # what the step appended to the state it started from
        st.t = t
        env.state = st
        (env.cur_pos, env.cur_angle, env.step_count, env.timestamp, env.speed, env.last_action, env.wheelVels,
         self.ticks) = rest
        if self._ended is not None and self._ended[0] > self.ticks:
            self._ended = None  # back before the end began: it is found again

    def undo_ahead(self):
        """Back to the last committed period (before any request but a commit); a stream goes on after the
        answer, its pushes numbered from 1 again."""
        if self._queue:
            self._restore(self._queue[0][0])
        self._queue.clear()
        self._seq = 0

    @staticmethod
    def _command(st, first, after, action):
        """Put ``action`` where the NaN stand-in went in ``st``'s command history: the entries stamped in
        [first, after) (a state without a delay has no history: nothing to write)."""
        stamps, cmds = getattr(st, "timestamps", ()), getattr(st, "commands", ())
        for k, t in enumerate(stamps):
            if first - 1e-9 <= t < after - 1e-9 and cmds[k].motor_left != cmds[k].motor_left:  # NaN
                cmds[k] = type(cmds[k])(motor_left=action[0], motor_right=action[1])

    def _why(self, code):
        env, gs = self.env, self.gs
        if code == "invalid-pose":
            centre = gs._actual_center(env.cur_pos, env.cur_angle)
            if env._collision(gs.get_agent_corners(centre, env.cur_angle)):
                return {"kind": "collision", "message": "gym-duckietown: invalid pose (collision with an object)",
                        "with": "map object"}
            return {"kind": "off_road", "message": "gym-duckietown: invalid pose (not on a drivable tile)"}
        return {"kind": "timeout", "message": f"gym-duckietown: {code} (max_steps = {env.max_steps})"}

    def probe(self):
        """Gym's own view of where the robot is: its frame's position and angle, and the tile there."""
        env = self.env
        i, j = env.get_grid_coords(env.cur_pos)
        tile = env._get_tile(i, j)
        return {"cur_pos": [float(v) for v in env.cur_pos], "cur_angle": float(env.cur_angle), "tile": [int(i), int(j)],
                "kind": None if tile is None else tile["kind"], "grid": [env.grid_width, env.grid_height],
                "tile_size": float(env.road_tile_size)}

    def camera(self):
        img = self.env.render_obs()
        return self.gs.np.ascontiguousarray(img, dtype=self.gs.np.uint8).tobytes()


#: Simulator constructor arguments the parent may pass (the rest are DB18 / camera settings applied at reset)
CTOR = ("max_steps", "draw_curve", "draw_bbox", "domain_rand", "frame_rate", "frame_skip", "camera_width",
        "camera_height", "robot_speed", "accept_start_angle_deg", "full_transparency", "distortion",
        "dynamics_rand", "camera_rand", "num_tris_distractors", "color_ground", "color_sky", "style", "enable_leds")


def _version():
    try:
        from importlib.metadata import version

        return version("duckietown-gym-daffy")
    except Exception:
        return "unknown"


def _answer(bridge, req):
    """The answer to one request (a ``commit`` has none of its own: None, or the period it computed now)."""
    op = req["op"]
    if op == "commit":
        return bridge.commit(req["pwm"])
    if bridge is not None:
        bridge.undo_ahead()
    if op == "stream":
        bridge.start_stream(req.get("render", False))
        return {"ok": True}, b""
    if op == "set_map":
        bridge.end_stream()  # a new episode streams when the parent asks
        bridge.set_map(req["map"], ())
        return {"ok": True}, b""
    if op == "reset":
        bridge.end_stream()
        return {"ok": True, **bridge.reset(req["seed"], req["pose"], req.get("objects") or [])}, b""
    if op == "probe":
        return {"ok": True, **bridge.probe()}, b""
    if op == "camera":
        return {"ok": True}, bridge.camera()
    return {"ok": False, "error": f"unknown op {op!r}"}, b""


def main():
    try:
        return _serve()
    except BrokenPipeError:  # the parent closed our pipe (it quit, or died): nothing left to answer
        os.dup2(os.open(os.devnull, os.O_WRONLY), _OUT.fileno())
        return 0


def _serve():
    bridge = None
    while True:
        try:
            if bridge is not None and bridge.can_advance() and not _IN.waiting():
                pushed = bridge.advance()  # gym works ahead while the caller decides
                if pushed is not None:
                    _write(*pushed)
                continue
            req = _IN.read()
            if req is None or req.get("op") == "quit":
                return 0
            if req.get("op") == "init":
                bridge = Bridge(req["params"], req["map"], req.get("frames_fd"))
                env = bridge.env
                _write({"ok": True, "version": _version(), "frame_rate": env.frame_rate,
                        "frame_skip": env.frame_skip, "camera": [env.camera_width, env.camera_height],
                        "pid": os.getpid(), "slots": 0 if bridge._slots is None else SLOTS})
                continue
            answer = _answer(bridge, req)
            if answer is not None:
                _write(*answer)
        except BrokenPipeError:
            raise
        except Exception as exc:
            if bridge is not None:
                bridge.end_stream()  # a failed stream is over: the parent reads this answer instead of a push
            _write({"ok": False, "error": f"{type(exc).__name__}: {exc}", "trace": traceback.format_exc()})


if __name__ == "__main__":
    sys.exit(main())
