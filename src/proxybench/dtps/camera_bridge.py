"""The watchtowers' DTPS bridge: run by the SDK environment's interpreter, never importing proxybench.

A lab's watchtower on DTPS is a Duckietown device serving its camera as a Duckiebot does (duckiebot-interface):
under ``<name>/sensor/camera/front_center/`` the topics ``jpeg`` (duckietown-messages ``CompressedImage``, its
``header.timestamp`` the camera's clock at exposure), ``parameters`` (``CameraIntrinsicCalibration``: K, D, P, R
and the distortion model, ROS ``camera_info``'s fields) and ``info`` (``Camera``: width, height, field of view,
frequency). This script speaks to proxybench over stdin/stdout in the format of ``pipe.py`` (loaded by path), in
one of two roles:

``towers``  simulated watchtowers: one dtps-http server on HOST:PORT with those three topics for every
            ``--name``; proxybench sends ``op: info`` (a watchtower's ``parameters`` and ``info``, published once
            and kept) and ``op: frame`` (``name, jpeg, stamp, t, seq``); read-only for clients (every write is
            refused, as the robot's server refuses writes outside its commands), with the robot server's header
            and idle deadlines.
``watch``   a reader of any lab's watchtowers: subscribes to each ``--source NAME URL PATH`` (a camera's ``jpeg``
            topic) and forwards every frame (``ev: frame``: ``name, data, format, stamp, wall``); a message that
            is not a compressed image of at most ``--max-bytes`` is ``ev: bad`` with one line saying why, never
            forwarded. A source that cannot be reached within ``--timeout`` is ``ev: error`` naming it.

Run: ``<sdk python> -I camera_bridge.py towers --port 7510 --name wt01 --name wt02`` (docs/dtps.md).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import importlib.util
import math
import time
from pathlib import Path

_spec = importlib.util.spec_from_file_location("proxybench_dtps_bridge", Path(__file__).with_name("bridge.py"))
bridge = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bridge)

#: where a Duckietown device serves its camera, under its name
CAMERA_PATH = ("sensor", "camera", "front_center")
CAMERA_TOPICS = ("jpeg", "parameters", "info")
_FORMATS = ("jpeg", "png")


def _one_line(exc: BaseException, limit: int = 300) -> str:
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return "".join(c if c.isprintable() else "?" for c in text)[:limit]


class Towers:
    """Simulated watchtowers served as a lab's are (role ``towers``)."""

    def __init__(self, args: argparse.Namespace, out) -> None:
        self.args, self.out = args, out
        self.queues: dict[tuple[str, str], object] = {}

    async def start(self) -> None:
        from dtps import context

        policy = bridge.RobotPolicy("")
        policy.writable = frozenset()  # a camera takes no writes
        policy.install()
        bridge.HeaderDeadline(self.args.header_timeout, self.args.idle_timeout).install()
        url = f"http://{self.args.host}:{self.args.port}/"
        try:
            self.ctx = await context("pbtowers", urls=["create:" + url])
        except OSError as exc:
            self.out.send(ev="error", detail=f"cannot serve on {url}: {exc.strerror or exc}")
            raise SystemExit(2) from None
        for name in self.args.name:
            for topic in CAMERA_TOPICS:
                self.queues[(name, topic)] = await self.ctx.navigate(name, *CAMERA_PATH, topic).queue_create()
        policy.armed = True
        self.out.send(ev="ready", url=url, names=list(self.args.name))

    async def _publish(self, name: str, topic: str, obj: dict) -> None:
        from dtps_http import RawData

        await self.queues[(name, topic)].publish(RawData.cbor_from_native_object(obj))

    async def info(self, m: dict) -> None:
        name = m["name"]
        h = {"version": "1.0", "frame": name, "txt": None, "timestamp": time.time()}
        await self._publish(name, "parameters", {"header": h, "K": m["K"], "D": m["D"], "P": m["P"], "R": m["R"],
                                                 "distortion_model": m["distortion_model"]})
        await self._publish(name, "info", {"header": h, "name": "front_center", "type": "camera", "simulated": True,
                                           "description": f"watchtower {name}", "frame_id": name,
                                           "frequency": m["frequency"], "width": m["width"], "height": m["height"],
                                           "fov": m["fov"]})

    async def frame(self, m: dict) -> None:
        name = m["name"]
        h = {"version": "1.0", "frame": name, "txt": {"sim_time": m.get("t"), "seq": m.get("seq")},
             "timestamp": float(m["stamp"])}
        await self._publish(name, "jpeg", {"header": h, "format": "jpeg", "data": m["jpeg"]})

    async def run(self, requests) -> None:
        await self.start()
        async for m in requests:
            op = m.get("op")
            try:
                if op == "frame":
                    await self.frame(m)
                elif op == "info":
                    await self.info(m)
                elif op == "quit":
                    break
                else:
                    self.out.send(ev="error", detail=f"unknown request {op!r}")
            except KeyError as exc:  # proxybench's own request, malformed: say so, serve on
                self.out.send(ev="error", detail=f"request {op!r} lacks {exc}")
        await self.ctx.aclose()


class Watch:
    """A reader of a lab's watchtower streams (role ``watch``)."""

    def __init__(self, args: argparse.Namespace, out) -> None:
        self.args, self.out = args, out

    async def start(self) -> None:
        from dtps import context

        contexts: dict[str, object] = {}
        for k, (name, url, path) in enumerate(self.args.source):
            try:
                if url not in contexts:
                    contexts[url] = await asyncio.wait_for(context(f"pbwatch{k}", urls=[url]), self.args.timeout)
                topic = contexts[url].navigate(*path.strip("/").split("/"))
                if not await asyncio.wait_for(topic.exists(), self.args.timeout):
                    raise LookupError(f"no topic {path} there")
                await asyncio.wait_for(topic.subscribe(self._forward(name), queue_size=self.args.queue),
                                       self.args.timeout)
            except Exception as exc:
                self.out.send(ev="error", detail=f"watchtower {name}: cannot subscribe to {url}{path.strip('/')}: "
                                                 f"{_one_line(exc)}")
                raise SystemExit(2) from None
        self.contexts = list(contexts.values())
        self.out.send(ev="ready", names=[s[0] for s in self.args.source])

    def _forward(self, name: str):
        limit = self.args.max_bytes

        async def on_data(rd) -> None:
            wall = time.time()
            try:
                size = len(rd.content)
                if size > limit:
                    raise ValueError(f"a message of {size} bytes (at most {limit})")
                msg = rd.get_as_native_object()
                if not isinstance(msg, dict):
                    raise TypeError(f"a {type(msg).__name__}, not a CompressedImage map")
                data, fmt, header = msg.get("data"), msg.get("format"), msg.get("header")
                if not isinstance(data, bytes) or not data:
                    raise TypeError(f"data is {type(data).__name__}, not image bytes")
                if fmt not in _FORMATS:
                    raise ValueError(f"format {str(fmt)[:20]!r} is not jpeg or png")
                stamp = header.get("timestamp") if isinstance(header, dict) else None
                if stamp is not None and (isinstance(stamp, bool) or not isinstance(stamp, int | float)
                                          or not math.isfinite(stamp)):
                    raise ValueError("header.timestamp is not a finite number")
            except Exception as exc:
                self.out.send(ev="bad", name=name, detail=_one_line(exc), wall=wall)
                return
            self.out.send(ev="frame", name=name, data=data, format=fmt,
                          stamp=None if stamp is None else float(stamp), wall=wall)
        return on_data

    async def run(self, requests) -> None:
        await self.start()
        async for m in requests:
            if m.get("op") == "quit":
                break
        for ctx in self.contexts:
            with contextlib.suppress(Exception):
                await ctx.aclose()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="role", required=True)
    srv = sub.add_parser("towers")
    srv.add_argument("--host", default="127.0.0.1")
    srv.add_argument("--port", type=int, default=7510)
    srv.add_argument("--name", action="append", required=True, help="a watchtower (repeat)")
    srv.add_argument("--header-timeout", type=float, default=10.0)
    srv.add_argument("--idle-timeout", type=float, default=15.0)
    rd = sub.add_parser("watch")
    rd.add_argument("--source", nargs=3, action="append", required=True, metavar=("NAME", "URL", "PATH"),
                    help="a watchtower's camera topic: its name, its server's URL, the jpeg topic's path (repeat)")
    rd.add_argument("--max-bytes", type=int, default=8 << 20, help="the largest message forwarded [bytes]")
    rd.add_argument("--timeout", type=float, default=20.0, help="to reach each source and subscribe [s]")
    rd.add_argument("--queue", type=int, default=256, help="messages held per source while the pipe is busy")
    args = parser.parse_args()
    bridge.quiet_logging(one_line=True)
    bridge.serve_role(Towers if args.role == "towers" else Watch, args, bridge.Out())


if __name__ == "__main__":
    main()
