"""gym-duckietown behind a private pipe: the child half of ``proxybench gym serve``.

Run by gym-duckietown's own interpreter (its venv: numpy 1.23, pyglet 1.5), never imported by proxybench,
and it imports nothing of proxybench (whose numpy differs). It reads requests on stdin and writes answers on
stdout, each one message: a 4-byte big-endian length, that many bytes of JSON, then, when the JSON has
``"blob": N``, N raw bytes (a camera frame, H×W×3 uint8, C order). Floats travel as JSON numbers, which
round-trip exactly. Requests (``op``):

- ``init``: ``params`` (gym's names, already checked by the parent), ``map`` (YAML text) → the simulator
  built, gym's version, rates and camera size;
- ``set_map``: ``map`` (YAML text) → the map interpreted by gym (``Simulator._interpret_map``);
- ``reset``: ``seed``, ``pose`` (x, y, θ in the map frame), ``objects`` (parked robots and duckies, map
  frame) → gym's reset (domain randomisation drawn from ``seed``), then the robot placed at ``pose`` and
  its DB18 dynamics built as gym's reset builds them, with the given trim, delay and coefficients;
- ``step``: ``pwm`` → ``frame_skip`` physics updates of gym (``update_physics``), a trace row after each,
  and gym's own episode end (``_compute_done_reward``); with ``render``, the new camera frame too (the order
  of gym's own ``step``: physics, then ``render_obs``);
- ``camera`` → gym's rendered observation (``render_obs``) for now; ``probe`` → gym's own pose and tile;

After answering a step, the bridge computes the next period ahead (:meth:`Bridge.ahead`), so that gym works while
the caller's agent decides; any request but the next step first puts that back.
- ``quit``.

Every answer is ``{"ok": true, ...}`` or ``{"ok": false, "error": text}``. Poses go back in the map frame by
gym's own ``cartesian_from_weird`` (x, H·tile − z, angle).
"""

import json
import math
import os
import struct
import sys
import traceback

_OUT = sys.stdout.buffer
_IN = sys.stdin.buffer
sys.stdout = sys.stderr  # whatever gym prints must not reach the pipe


def _read():
    head = _IN.read(4)
    if len(head) < 4:
        return None
    (n,) = struct.unpack(">I", head)
    return json.loads(_IN.read(n))


def _write(msg, blob=b""):
    if blob:
        msg["blob"] = len(blob)
    data = json.dumps(msg).encode()
    _OUT.write(struct.pack(">I", len(data)) + data + blob)
    _OUT.flush()


class Bridge:
    """One gym-duckietown ``Simulator`` driven one camera period at a time."""

    def __init__(self, params, map_text):
        import pyglet

        pyglet.options["headless"] = True  # EGL through Mesa: no X server
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
        self._ahead = None  # (state before, answer, frame) of the next period, computed before its command came
        self.set_map(map_text, ())
        self.reset(0, [0.0, 0.0, 0.0], [])  # a first episode: the first one after gym's constructor renders apart
        self.camera()

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

    def step(self, pwm, render=False):
        """One camera period with ``pwm``: (answer, frame bytes or b""), from the step computed ahead when
        that one is valid (see :meth:`ahead`)."""
        np = self.gs.np
        action = np.clip(np.array(pwm, dtype=float), -1, 1)
        ahead, self._ahead = self._ahead, None
        if ahead is not None:
            saved, out, frame = ahead
            if np.isfinite(out["motion"]).all() and np.isfinite(self.env.cur_pos).all():
                self._command(action)  # the command was not used yet: write it where the stand-in stands
                for row in out["trace"]:
                    row[6:8] = [float(action[0]), float(action[1])]
                return out, frame if render else b""
            self._restore(saved)  # the stand-in was used (a delay too short): step again for real
        out = self._physics(action)
        return out, self.camera() if render else b""

    def _physics(self, action):
        env = self.env
        rows = []
        for _ in range(env.frame_skip):
            env.update_physics(action)
            self.ticks += 1
            m = self._motion()
            rows.append([self.ticks * self.dt, *m[:5], float(action[0]), float(action[1])])
        done = env._compute_done_reward()
        out = self.state()
        out["trace"] = rows
        if done.done:
            out["end"] = self._why(done.done_code)
        return out

    # ----------------------------------------------------------------------------- stepping ahead
    def ahead(self, render):
        """Compute the next camera period now, while the caller decides its command. Exact when gym's command
        delay is longer than the period: the command being decided acts only later, so the motion, the frame
        and the episode's end of the next period do not depend on it. It goes in as NaN, and is written in
        when it comes (a NaN that reached the motion shows in the pose: that step is undone and done again)."""
        env = self.env
        if not (self.p["delay"] >= (env.frame_skip + 0.5) * env.delta_time + 1e-9
                and all(getattr(o, "static", True) for o in env.objects)):
            return
        saved = self._save()
        nan = self.gs.np.full(2, float("nan"))
        out = self._physics(nan)
        self._ahead = (saved, out, self.camera() if render else b"")

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

    def undo_ahead(self):
        """Back to the state the caller knows (before anything but the next step)."""
        ahead, self._ahead = self._ahead, None
        if ahead is not None:
            self._restore(ahead[0])

    def _command(self, action):
        """Put ``action`` where the NaN stand-in went: gym's command history (the delay reads it later) and
        what gym reports of the last action."""
        env, np = self.env, self.gs.np
        cmds = env.state.commands
        for k, c in enumerate(cmds):
            if not np.isfinite(c.motor_left):
                cmds[k] = type(c)(motor_left=action[0], motor_right=action[1])
        env.last_action = action
        env.wheelVels = action * env.robot_speed

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


def main():
    bridge = None
    while True:
        req = _read()
        if req is None or req.get("op") == "quit":
            return 0
        try:
            op = req["op"]
            if bridge is not None and op != "step":
                bridge.undo_ahead()
            if op == "init":
                bridge = Bridge(req["params"], req["map"])
                env = bridge.env
                _write({"ok": True, "version": _version(), "frame_rate": env.frame_rate,
                        "frame_skip": env.frame_skip, "camera": [env.camera_width, env.camera_height],
                        "pid": os.getpid()})
            elif op == "set_map":
                bridge.set_map(req["map"], ())
                _write({"ok": True})
            elif op == "reset":
                _write({"ok": True, **bridge.reset(req["seed"], req["pose"], req.get("objects") or [])})
            elif op == "step":
                out, frame = bridge.step(req["pwm"], req.get("render", False))
                _write({"ok": True, **out}, frame)
                bridge.ahead(req.get("render", False))
            elif op == "probe":
                _write({"ok": True, **bridge.probe()})
            elif op == "camera":
                _write({"ok": True}, bridge.camera())
            else:
                _write({"ok": False, "error": f"unknown op {op!r}"})
        except Exception as exc:
            _write({"ok": False, "error": f"{type(exc).__name__}: {exc}", "trace": traceback.format_exc()})


if __name__ == "__main__":
    sys.exit(main())
