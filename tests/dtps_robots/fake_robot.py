"""A fake DTPS robot for proxybench's tests, on dtps-http's own server classes (run by the SDK environment).

A kinematic robot at ``http://127.0.0.1:PORT/NAME/``: it publishes ``state/pose`` (a Transformation) at
``--pose-hz``, a fixed camera JPEG (``--jpeg``) on ``sensor/camera/front_center/jpeg`` at ``--camera-hz``,
its wheel encoders, and drives by what arrives on ``actuator/wheels/base/pwm`` (v = gain·(l + r)/2,
ω = gain·(r − l)/wheel_base). ``state/reset`` puts it back at ``--start``. Every command received is
appended to ``--log`` (JSON lines: wall time, left, right, which server incarnation). A line
``place X Y THETA`` on its stdin puts it there (what an operator does by hand). ``--blackout-after S``:
S seconds after the first moving command, the network goes away for ``--blackout-for`` seconds (every
connection dropped, none accepted) and comes back, as a robot's Wi-Fi drops: the server itself listens on
``--internal-port`` behind a small TCP relay on ``--port`` that the blackout closes. The robot keeps driving
with the last command it heard meanwhile, as a real one would.
"""
import argparse
import asyncio
import contextlib
import json
import math
import sys
import time

from dtps import context
from dtps_http import RawData

TOPICS = ("sensor/camera/front_center/jpeg", "sensor/wheel_encoder/left/ticks", "sensor/wheel_encoder/right/ticks",
          "state/pose", "state/reset", "actuator/wheels/base/pwm")


def header():
    return {"version": "1.0", "frame": None, "txt": None, "timestamp": time.time()}


class Robot:
    def __init__(self, args):
        self.args = args
        self.pose = list(args.start)
        self.cmd = (0.0, 0.0)
        self.wheels = [0.0, 0.0]
        self.incarnation = 0
        self.first_move = None
        self.log = open(args.log, "a")  # noqa: SIM115 (the robot's life long)
        with open(args.jpeg, "rb") as f:
            self.jpeg = f.read()

    async def serve(self):
        self.ctx = await context("fakebot", urls=[f"create:http://127.0.0.1:{self.args.internal_port}/"])
        self.q = {}
        for t in TOPICS:
            self.q[t] = await self.ctx.navigate(*self.args.name.split("/"), *t.split("/")).queue_create()
        await self.q["actuator/wheels/base/pwm"].subscribe(self.on_pwm)
        await self.q["state/reset"].subscribe(self.on_reset)
        await self.relay_up()

    async def relay_up(self):
        self.links = set()
        self.relay = await asyncio.start_server(self.on_client, "127.0.0.1", self.args.port, reuse_address=True)
        self.incarnation += 1
        print(f"serving {self.incarnation}", flush=True)

    async def relay_down(self):
        self.relay.close()
        for writer in list(self.links):
            writer.transport.abort()
        await self.relay.wait_closed()

    async def on_client(self, reader, writer):
        up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.args.internal_port)
        self.links |= {writer, up_writer}

        async def pipe(src, dst):
            try:
                while data := await src.read(65536):
                    dst.write(data)
                    await dst.drain()
            except (ConnectionError, OSError):
                pass
            finally:
                dst.transport.abort()

        await asyncio.gather(pipe(reader, up_writer), pipe(up_reader, writer))

    async def on_pwm(self, rd):
        m = rd.get_as_native_object()
        self.cmd = (float(m["left"]), float(m["right"]))
        self.log.write(json.dumps({"wall": time.time(), "left": self.cmd[0], "right": self.cmd[1],
                                   "incarnation": self.incarnation}) + "\n")
        self.log.flush()
        if self.first_move is None and self.cmd != (0.0, 0.0):
            self.first_move = time.monotonic()

    async def on_reset(self, rd):
        if rd.get_as_native_object().get("data", True):
            self.pose, self.cmd = list(self.args.start), (0.0, 0.0)

    async def publish(self, topic, obj):
        await self.q[topic].publish(RawData.cbor_from_native_object(obj))

    async def run(self):
        await self.serve()
        with contextlib.suppress(PermissionError):  # stdin a file (/dev/null): nobody places the robot
            asyncio.get_running_loop().add_reader(sys.stdin.fileno(), self.on_stdin)
        dt = 1.0 / self.args.pose_hz
        every = max(1, round(self.args.pose_hz / self.args.camera_hz))
        k = 0
        blacked_out = False
        while True:
            await asyncio.sleep(dt)
            self.step(dt)
            if (self.args.blackout_after is not None and not blacked_out and self.first_move is not None
                    and time.monotonic() - self.first_move > self.args.blackout_after):
                blacked_out = True
                await self.relay_down()
                print("blackout", flush=True)
                await asyncio.sleep(self.args.blackout_for)
                await self.relay_up()
                continue
            x, y, th = self.pose
            h = header()
            await self.publish("state/pose", {
                "header": h, "source": "map_0", "target": self.args.name,
                "position": {"header": h, "x": x, "y": y, "z": 0.0},
                "rotation": {"header": h, "w": math.cos(th / 2), "x": 0.0, "y": 0.0, "z": math.sin(th / 2)}})
            for side, angle in zip(("left", "right"), self.wheels, strict=True):
                await self.publish(f"sensor/wheel_encoder/{side}/ticks",
                                   {"header": h, "data": round(angle * 135 / (2 * math.pi))})
            if k % every == 0:
                await self.publish("sensor/camera/front_center/jpeg",
                                   {"header": h, "format": "jpeg", "data": self.jpeg})
            k += 1

    def step(self, dt):
        left, right = self.cmd
        v = self.args.gain * (left + right) / 2
        w = self.args.gain * (right - left) / self.args.wheel_base
        x, y, th = self.pose
        self.pose = [x + v * math.cos(th) * dt, y + v * math.sin(th) * dt, th + w * dt]
        self.wheels = [self.wheels[0] + self.args.gain * left * dt / 0.0318,
                       self.wheels[1] + self.args.gain * right * dt / 0.0318]

    def on_stdin(self):
        line = sys.stdin.readline()
        if not line:
            asyncio.get_running_loop().remove_reader(sys.stdin.fileno())
            return
        words = line.split()
        if words[:1] == ["place"]:
            self.pose = [float(v) for v in words[1:4]]
            self.cmd = (0.0, 0.0)
            print("placed", flush=True)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--internal-port", type=int, required=True)
    p.add_argument("--name", default="fakebot")
    p.add_argument("--jpeg", required=True)
    p.add_argument("--log", required=True)
    p.add_argument("--start", type=float, nargs=3, default=(0.9, 0.3, 0.0))
    p.add_argument("--pose-hz", type=float, default=30.0)
    p.add_argument("--camera-hz", type=float, default=15.0)
    p.add_argument("--gain", type=float, default=0.6)
    p.add_argument("--wheel-base", type=float, default=0.1)
    p.add_argument("--blackout-after", type=float, default=None)
    p.add_argument("--blackout-for", type=float, default=2.0)
    args = p.parse_args()
    import logging
    logging.basicConfig()
    for handler in logging.getLogger().handlers:
        handler.setLevel(logging.WARNING)
    asyncio.run(Robot(args).run())


if __name__ == "__main__":
    main()
