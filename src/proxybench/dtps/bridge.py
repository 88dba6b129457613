"""The DTPS bridge: a process of proxybench's run by the SDK environment's interpreter (never importing proxybench).

duckietown-sdk and dtps-http pin their own dependencies (pydantic 2.10.6 exactly), so they live in an
environment of their own (``proxybench dtps setup``) and proxybench talks to them through this process, over
its stdin/stdout in the format of ``pipe.py`` (loaded by path). Two roles:

``server``  a virtual DB21J: a dtps-http server on HOST:PORT with every queue an SDK agent uses, under
            ``<prefix>/<name>/`` (the Duckiematrix's addressing: ``robot/map_0/vehicle_0/...``), and the map
            layer at ``map/{frames,tiles,tile_maps}``. proxybench sends frames (``op: frame``: camera JPEG,
            encoder ticks, ToF range, pose, Δt) and the map; the bridge publishes them and sends back every
            wheel command (``ev: cmd``, from ``pwm_filtered`` and ``pwm``), reset request and lights pattern.
            With ``nudge`` it pings the agent's websockets until a command answers the frame: the SDK's
            publisher sits on a queue its event loop only looks at when a packet wakes it, so a blocking
            ``capture(); set_pwm()`` agent's command otherwise waits for the next camera frame.
``client``  a DTPS robot (a Duckiebot, a Duckiematrix robot) at ``--url``, its topics under ``--name``:
            subscribes to its camera, encoders and a pose topic (the robot's ``state/pose``, or a
            localisation system's, ``--pose /PATH`` on ``--pose-url``), forwards them (``ev:
            camera|ticks|pose``), publishes the wheel command in force (``op: cmd``) on its PWM topic,
            re-sending it on every reconnection of the publisher, publishes ``state/reset`` (``op: reset``),
            and sends (0, 0) when no command came for ``--watchdog`` seconds, on ``op: stop``, and at its
            end (``op: quit``, end of input, SIGTERM), trying for ``--stop-grace`` s to deliver it.

**The robot policy** (role ``server``): the HTTP server answers what a robot answers, nothing else. Once the
robot's queues exist, a client may read (GET, HEAD, OPTIONS: sensors, the map, the index, subscriptions) and
write (POST, or a ``:push`` stream) only the topics a robot takes commands on (``WRITABLE_TOPICS``); DELETE,
PATCH (creating or removing queues), PUT and any other method get 405, a write elsewhere 403, and a handler's
unexpected error a 400 of one line on stderr (never a traceback): one ``curl -X DELETE`` killed the bridge
before (issue 38). A connection's request headers must be complete ``--header-timeout`` s after it opened, and a
kept-alive connection may idle ``--idle-timeout`` s (:class:`HeaderDeadline`), so a client that sends half a
header and stalls (a slow-loris) holds nothing.

With ``--own-netns`` (root; the evaluator's agent packages) the server moves into a network namespace of its
own before it listens, and with ``--drop-to USER`` runs on as that user: the package's sandbox joins that
namespace, so the agent reaches the robot on 127.0.0.1:7501 and nothing else, and cannot reach this process.

Run: ``<sdk python> -I bridge.py server --port 7501 --name map_0/vehicle_0`` (docs/dtps.md, "The bridge").
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import importlib.util
import logging
import math
import os
import signal
import time
import weakref
from pathlib import Path

_spec = importlib.util.spec_from_file_location("proxybench_dtps_pipe", Path(__file__).with_name("pipe.py"))
pipe = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(pipe)

#: robot topics of a DB21J under <prefix>/<name>/ (what duckietown-sdk 0.2.0's DB21J subscribes or publishes to)
ROBOT_TOPICS = ("sensor/camera/front_center/jpeg", "sensor/wheel_encoder/left/ticks",
                "sensor/wheel_encoder/right/ticks", "sensor/time_of_flight/front_center/range", "sensor/delta_t",
                "state/pose", "state/reset", "actuator/wheels/base/pwm_filtered", "actuator/wheels/base/pwm",
                "actuator/lights/base/pattern")
#: the map layer, at the server's root
MAP_TOPICS = ("map/frames", "map/tiles", "map/tile_maps")
_COMMAND_TOPICS = ("actuator/wheels/base/pwm_filtered", "actuator/wheels/base/pwm")
#: the topics under the robot's path a client may write to: its commands, what the SDK publishes
WRITABLE_TOPICS = (*_COMMAND_TOPICS, "state/reset", "actuator/lights/base/pattern")
_READ_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
_PUSH_SUFFIX = ":push"
_NUDGE_EVERY = 0.002  # [s] between websocket pings while a lock-step frame waits for its command


class Out:
    """Events to proxybench on fd 1 (blocking writes: a reader that stalls holds the bridge back)."""

    def __init__(self) -> None:
        self.fd = os.dup(1)
        os.dup2(2, 1)  # a stray print of a library goes to stderr, never into the pipe

    def send(self, **message) -> None:
        data = memoryview(pipe.pack(message))
        while data:
            data = data[os.write(self.fd, data):]


class LatestOut:
    """Events to proxybench that never block the bridge's loop (role ``client``): a proxybench that stops reading
    (a slow agent, a pause) must not stall the watchdog or the publisher. Sensor messages (``latest``) keep only
    the newest of each kind while the pipe is full; other events are all kept, in order."""

    def __init__(self, out: Out) -> None:
        self.fd = out.fd
        os.set_blocking(self.fd, False)
        self.buf = bytearray()
        self.latest: dict[str, dict] = {}
        self.waiting = False
        self.gone = False

    def send(self, **message) -> None:
        self.buf += pipe.pack(message)
        self._flush()

    def sensor(self, key: str, **message) -> None:
        self.latest[key] = message
        self._flush()

    def _flush(self) -> None:
        if not self.buf:  # one generation of sensor messages at a time: the newest
            for message in self.latest.values():
                self.buf += pipe.pack(message)
            self.latest.clear()
        while self.buf and not self.gone:
            try:
                n = os.write(self.fd, self.buf)
            except BlockingIOError:
                break
            except OSError:  # proxybench is gone: the end of input ends the bridge
                self.gone = True
                self.buf.clear()
                break
            del self.buf[:n]
            if not self.buf and self.latest:
                self._flush()
                return
        loop = asyncio.get_running_loop()
        if self.buf and not self.gone and not self.waiting:
            loop.add_writer(self.fd, self._writable)
            self.waiting = True

    def _writable(self) -> None:
        asyncio.get_running_loop().remove_writer(self.fd)
        self.waiting = False
        self._flush()

    def finish(self, timeout: float = 5.0) -> None:
        """Write what is left, waiting up to ``timeout`` s for proxybench to read it (at the bridge's end)."""
        deadline = time.monotonic() + timeout
        while (self.buf or self.latest) and not self.gone and time.monotonic() < deadline:
            self._flush()
            if self.buf:
                time.sleep(0.01)


class In:
    """Requests from proxybench on fd 0, as an async iterator; ends at EOF."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.reader = pipe.Reader()
        self.queue: asyncio.Queue = asyncio.Queue()
        os.set_blocking(0, False)
        loop.add_reader(0, self._readable)

    def _readable(self) -> None:
        if self.reader.read_from(0) == 0:
            asyncio.get_running_loop().remove_reader(0)
        while (msg := self.reader.next()) is not None:
            self.queue.put_nowait(msg)
        if self.reader.eof:
            self.queue.put_nowait(None)

    def __aiter__(self):
        return self

    async def __anext__(self) -> dict:
        msg = await self.queue.get()
        if msg is None:
            raise StopAsyncIteration
        return msg


def _header(stamp: float | None = None) -> dict:
    return {"version": "1.0", "frame": None, "txt": None, "timestamp": time.time() if stamp is None else stamp}


def _quaternion(theta: float) -> dict:
    """A yaw about +z as the (w, x, y, z) quaternion of duckietown-messages' Transformation."""
    return {"header": _header(), "w": math.cos(theta / 2), "x": 0.0, "y": 0.0, "z": math.sin(theta / 2)}


def _track_websockets() -> weakref.WeakSet:
    """Every websocket the dtps-http server opens, so that lock-step frames can ping them (see the docstring)."""
    from aiohttp import web

    live: weakref.WeakSet = weakref.WeakSet()
    base = web.WebSocketResponse

    class Tracked(base):
        async def prepare(self, request):
            out = await super().prepare(request)
            live.add(self)
            return out

    web.WebSocketResponse = Tracked
    return live


class RobotPolicy:
    """What clients may ask of the virtual robot's HTTP server (see the module docstring): an aiohttp middleware
    put in front of every handler of the dtps-http server (installed before the server exists), enforcing
    nothing until ``arm`` (the bridge creates its own queues first)."""

    def __init__(self, robot_path: str) -> None:
        self.writable = frozenset(f"{robot_path.strip('/')}/{t}" for t in WRITABLE_TOPICS)
        self.armed = False
        self.refused = 0
        self.log = logging.getLogger("proxybench.bridge")

    def verdict(self, method: str, path: str) -> tuple[int, str] | None:
        """(status, why) for a request to refuse, None for one to serve."""
        topic = path.strip("/")
        if method in _READ_METHODS:
            if topic.endswith(_PUSH_SUFFIX) and topic[:-len(_PUSH_SUFFIX)].rstrip("/") not in self.writable:
                return 403, "only the robot's command topics take writes"
            return None
        if method == "POST":
            return None if topic in self.writable else (403, "only the robot's command topics take writes")
        return 405, f"{method[:16]} is not allowed: a robot's topics are read, and its commands written"

    def install(self) -> None:
        """Put the policy in front of every aiohttp application created from now on in this process."""
        from aiohttp import web

        policy = self

        @web.middleware
        async def middleware(request, handler):
            if policy.armed:
                refusal = policy.verdict(request.method, request.path)
                if refusal is not None:
                    policy.refused += 1
                    status, why = refusal
                    return web.Response(status=status, text=why + "\n", headers={"Allow": "GET, HEAD, OPTIONS, POST"})
            try:
                return await handler(request)
            except (web.HTTPException, asyncio.CancelledError):
                raise
            except Exception as exc:  # a hostile request that broke a handler: one line, never a traceback
                policy.log.warning("refused %s %s: %s", request.method[:16], request.path[:120],
                                   type(exc).__name__)
                return web.Response(status=400, text=f"bad request ({type(exc).__name__})\n")

        original = web.Application.__init__

        def init(app, *args, middlewares=(), **kwargs) -> None:
            original(app, *args, middlewares=[middleware, *middlewares], **kwargs)

        web.Application.__init__ = init


class HeaderDeadline:
    """A deadline on each connection's request headers, and a shorter idle time between kept-alive requests, in
    front of the dtps-http server (aiohttp has none: a client that sends half a request line and stalls held its
    connection for good; issue 38, a slow-loris). aiohttp's request handler is patched before the server exists:
    a connection whose first request's headers are not complete ``header_s`` after it opened is closed, and the
    keep-alive timer (which also ends a half-sent next request) is at most ``idle_s``. A websocket or a request
    whose headers arrived is never touched."""

    def __init__(self, header_s: float, idle_s: float) -> None:
        self.header_s, self.idle_s = header_s, idle_s
        self.closed = 0
        self.log = logging.getLogger("proxybench.bridge")
        self._timers: dict[int, asyncio.TimerHandle] = {}

    def _too_slow(self, handler) -> None:
        self._timers.pop(id(handler), None)
        if not handler._request_count:  # still no complete request line and headers
            self.closed += 1
            self.log.warning("closed a connection whose request headers did not arrive within %g s", self.header_s)
            handler.force_close()

    def _disarm(self, handler) -> None:
        timer = self._timers.pop(id(handler), None)
        if timer is not None:
            timer.cancel()

    def install(self) -> None:
        """Patch aiohttp's request handler in this process (before the server is created)."""
        from aiohttp import web_protocol

        deadline, handler_class = self, web_protocol.RequestHandler
        made, received, lost = handler_class.connection_made, handler_class.data_received, handler_class.connection_lost

        def connection_made(handler, transport) -> None:
            handler._keepalive_timeout = min(handler._keepalive_timeout, deadline.idle_s)  # read by start()
            made(handler, transport)
            deadline._timers[id(handler)] = handler._loop.call_later(deadline.header_s, deadline._too_slow, handler)

        def data_received(handler, data: bytes) -> None:
            received(handler, data)
            if handler._request_count:
                deadline._disarm(handler)

        def connection_lost(handler, exc) -> None:
            deadline._disarm(handler)
            lost(handler, exc)

        handler_class.connection_made = connection_made
        handler_class.data_received = data_received
        handler_class.connection_lost = connection_lost


class Server:
    """The virtual DB21J (role ``server``)."""

    def __init__(self, args: argparse.Namespace, out: Out) -> None:
        self.args, self.out = args, out
        self.queues: dict[str, object] = {}
        self.seq = -1
        self.answered = True
        self.count = 0  # commands since the last frame

    async def start(self) -> None:
        from dtps import context

        self.live = _track_websockets()
        self.policy = RobotPolicy(f"{self.args.prefix}/{self.args.name}")
        self.policy.install()
        self.deadline = HeaderDeadline(self.args.header_timeout, self.args.idle_timeout)
        self.deadline.install()
        url = f"http://{self.args.host}:{self.args.port}/"
        try:
            self.ctx = await context("pbserver", urls=["create:" + url])
        except OSError as exc:
            self.out.send(ev="error", detail=f"cannot serve on {url}: {exc.strerror or exc}")
            raise SystemExit(2) from None
        base = self.ctx.navigate(*self.args.prefix.split("/"), self.args.name)
        for topic in ROBOT_TOPICS:
            self.queues[topic] = await base.navigate(topic).queue_create()
        for topic in MAP_TOPICS:
            self.queues[topic] = await self.ctx.navigate(topic).queue_create()
        for topic in _COMMAND_TOPICS:
            await self.queues[topic].subscribe(self._on_command(topic))
        await self.queues["state/reset"].subscribe(self._on_reset)
        await self.queues["actuator/lights/base/pattern"].subscribe(self._on_lights)
        self.policy.armed = True  # from now on clients get what a robot gives: reads, and command writes
        if getattr(self.args, "drop_to", ""):
            _drop_to(self.args.drop_to)
        self.out.send(ev="ready", url=url, prefix=f"{self.args.prefix}/{self.args.name}".strip("/"),
                      topics=list(ROBOT_TOPICS) + list(MAP_TOPICS))

    def _on_command(self, topic: str):
        async def on_data(rd) -> None:
            try:
                left, right = _wheels(rd.get_as_native_object())
            except Exception as exc:
                self.out.send(ev="bad", topic=topic, detail=f"{type(exc).__name__}: {exc}"[:500])
                return
            self.count += 1
            self.answered = True
            self.out.send(ev="cmd", topic=topic, left=left, right=right, seq=self.seq, n=self.count,
                          wall=time.time())
        return on_data

    async def _on_reset(self, rd) -> None:
        try:
            flag = bool(rd.get_as_native_object().get("data", True))
        except Exception:
            flag = True
        if flag:
            self.out.send(ev="reset", wall=time.time())

    async def _on_lights(self, rd) -> None:
        self.out.send(ev="lights", wall=time.time())

    async def _publish(self, topic: str, obj: dict) -> None:
        from dtps_http import RawData

        await self.queues[topic].publish(RawData.cbor_from_native_object(obj))

    async def frame(self, m: dict) -> None:
        stamp = float(m.get("t", 0.0))
        self.seq, self.count, self.answered = int(m["seq"]), 0, False
        h = _header()
        if m.get("ticks") is not None:
            for side, ticks in zip(("left", "right"), m["ticks"], strict=True):
                await self._publish(f"sensor/wheel_encoder/{side}/ticks", {"header": h, "data": int(ticks)})
        await self._publish("sensor/time_of_flight/front_center/range", {"header": h, "data": m.get("range")})
        if m.get("dt") is not None:
            await self._publish("sensor/delta_t", {"header": h, "data": float(m["dt"])})
        if m.get("pose") is not None:
            x, y, theta = m["pose"]
            await self._publish("state/pose", {
                "header": h, "source": "map_0", "target": self.args.name,
                "position": {"header": h, "x": float(x), "y": float(y), "z": 0.0}, "rotation": _quaternion(theta)})
        if m.get("jpeg"):  # the camera last: an agent reacting to it finds the other sensors of this frame
            h = _header()
            h["txt"] = {"sim_time": stamp, "seq": self.seq}
            await self._publish("sensor/camera/front_center/jpeg", {"header": h, "format": "jpeg", "data": m["jpeg"]})
        if m.get("nudge"):
            asyncio.get_running_loop().create_task(self._nudge(self.seq))

    async def _nudge(self, seq: int) -> None:
        """Ping the agent's websockets until a command answers frame ``seq`` (or the next frame comes)."""
        deadline = time.monotonic() + 30.0
        await asyncio.sleep(_NUDGE_EVERY)
        while not self.answered and self.seq == seq and time.monotonic() < deadline:
            for ws in list(self.live):
                if not ws.closed:
                    with contextlib.suppress(Exception):  # a closing socket
                        await ws.ping()
            await asyncio.sleep(_NUDGE_EVERY)

    async def map(self, m: dict) -> None:
        h = _header()
        for layer in ("frames", "tiles", "tile_maps"):
            await self._publish(f"map/{layer}", {"header": h, "data": m[layer]})

    async def listeners(self) -> None:
        info = self.queues["sensor/camera/front_center/jpeg"].get_listener_info()
        self.out.send(ev="listeners", camera=0 if info is None else int(info.num_listeners))

    async def run(self, requests: In) -> None:
        await self.start()
        async for m in requests:
            op = m.get("op")
            if op == "frame":
                await self.frame(m)
            elif op == "map":
                await self.map(m)
            elif op == "listeners":
                await self.listeners()
            elif op == "quit":
                break
            else:
                self.out.send(ev="error", detail=f"unknown request {op!r}")
        await self.ctx.aclose()


class Client:
    """A DTPS robot (role ``client``): its sensors forwarded, the latest wheel command published.

    The publisher re-sends the command in force whenever it (re)connects, so after a lost connection the
    robot hears the current command (after a stop or the watchdog: (0, 0)) as soon as it is back; a stop whose
    publish failed (a link slow beyond 2 s on a loaded machine) is sent first even when a newer command came
    meanwhile, so the robot never misses a stop. On exit
    (``op: quit``, end of input, SIGTERM) the bridge publishes (0, 0) and waits up to ``--stop-grace`` s for
    it to be delivered, reconnecting meanwhile, and says whether it was (``ev: stopped``).
    """

    def __init__(self, args: argparse.Namespace, out: Out) -> None:
        self.args, self.out = args, LatestOut(out)
        self.last_command = time.monotonic()
        self.latest = (0.0, 0.0)
        self.dirty = asyncio.Event()
        self.zero_delivered = asyncio.Event()

    def _topic(self, ctx, path: str):
        if path.startswith("/"):  # a full path from the server's root (e.g. a localisation system's topic)
            return ctx.navigate(*path.strip("/").split("/"))
        return ctx.navigate(*self.args.name.strip("/").split("/"), *path.split("/"))

    async def start(self) -> None:
        from dtps import context

        self.ctx = await context("pbclient", urls=[self.args.url])
        self.pose_ctx = self.ctx if not self.args.pose_url else await context("pblocal", urls=[self.args.pose_url])
        if getattr(self.args, "observe", False):  # an Autolab's record of a robot someone else drives
            for topic in _COMMAND_TOPICS:
                await self._topic(self.ctx, topic).subscribe(self._observed(topic))
        else:
            await self._topic(self.ctx, "sensor/camera/front_center/jpeg").subscribe(self._forward("camera"))
            for side in ("left", "right"):
                await self._topic(self.ctx, f"sensor/wheel_encoder/{side}/ticks").subscribe(
                    self._forward("ticks", side))
        if self.args.pose:
            await self._topic(self.pose_ctx, self.args.pose).subscribe(self._forward("pose"))
        loop = asyncio.get_running_loop()
        self.tasks = [loop.create_task(self._watchdog())]
        if not getattr(self.args, "observe", False):  # an observer publishes only when told to stop the robot
            self.tasks.append(loop.create_task(self._publisher()))
        self.out.send(ev="ready", url=self.args.url, prefix=self.args.name.strip("/"))

    def _observed(self, topic: str):
        """Forward every wheel command published on ``topic`` (``--observe``: all kept, in order, with when the
        bridge heard it)."""
        async def on_data(rd) -> None:
            try:
                msg = rd.get_as_native_object()
                left, right = _wheels(msg)
                stamp = (msg.get("header") or {}).get("timestamp")
                self.out.send(ev="command", topic=topic, left=left, right=right,
                              stamp=stamp if isinstance(stamp, float) else None, wall=time.time())
            except Exception as exc:
                self.out.send(ev="bad", topic=topic, detail=f"{type(exc).__name__}: {exc}"[:500])
        return on_data

    def _forward(self, kind: str, side: str | None = None):
        async def on_data(rd) -> None:
            try:
                msg = rd.get_as_native_object()
                stamp = (msg.get("header") or {}).get("timestamp")
                if kind == "camera":
                    self.out.sensor(kind, ev=kind, jpeg=bytes(msg["data"]), stamp=stamp, wall=time.time())
                elif kind == "ticks":
                    self.out.sensor(f"ticks/{side}", ev=kind, side=side, ticks=int(msg["data"]), stamp=stamp,
                                    wall=time.time())
                else:
                    self.out.sensor(kind, ev=kind, pose=_pose_of(msg), stamp=stamp, wall=time.time())
            except Exception as exc:
                self.out.send(ev="bad", topic=kind, detail=f"{type(exc).__name__}: {exc}"[:500])
        return on_data

    async def _publisher(self) -> None:
        """Publish the command in force whenever it changes, and again on every (re)connection; on any failure
        (a publish unanswered for 2 s included) reconnect with backoff (0.1 … 2 s), telling proxybench."""
        from dtps_http import RawData

        backoff = 0.1
        stop_unsure = False  # a (0, 0) whose publish failed: the robot may not have heard the stop
        while True:
            try:
                async with _within(5.0, self._topic(self.ctx, self.args.pwm).publisher_context()) as pub:
                    self.out.send(ev="link", state="ok", detail="publisher connected")
                    backoff = 0.1
                    if stop_unsure and self.latest != (0.0, 0.0):  # a stop is never dropped: it goes first
                        await self._publish(pub, RawData, (0.0, 0.0))
                    stop_unsure = False
                    self.dirty.set()  # the robot hears the command in force at once
                    while True:
                        await self.dirty.wait()
                        self.dirty.clear()
                        left, right = self.latest
                        stop_unsure = (left, right) == (0.0, 0.0)
                        await self._publish(pub, RawData, (left, right))
                        stop_unsure = False
                        if (left, right) == (0.0, 0.0) and self.latest == (0.0, 0.0):
                            self.zero_delivered.set()
            except asyncio.CancelledError:
                raise
            except Exception as exc:
                self.out.send(ev="link", state="lost", detail=f"{type(exc).__name__}: {exc}"[:300])
                await asyncio.sleep(backoff)
                backoff = min(2.0, backoff * 2)

    @staticmethod
    async def _publish(pub, raw_data, command: tuple[float, float]) -> None:
        """One wheel command, answered within 2 s or the link counts as lost."""
        left, right = command
        await asyncio.wait_for(pub.publish(raw_data.cbor_from_native_object(
            {"header": _header(), "left": left, "right": right})), 2.0)

    def command(self, left: float, right: float) -> None:
        """The command in force from now on (only the latest matters)."""
        if len(self.tasks) == 1:  # an observer's first command (a stop): its publisher starts now
            self.tasks.append(asyncio.get_running_loop().create_task(self._publisher()))
        self.latest = (left, right)
        if (left, right) != (0.0, 0.0):
            self.zero_delivered.clear()
        self.dirty.set()

    async def _watchdog(self) -> None:
        while True:
            await asyncio.sleep(self.args.watchdog / 4)
            if time.monotonic() - self.last_command > self.args.watchdog:
                self.last_command = time.monotonic()
                if self.latest != (0.0, 0.0):
                    self.command(0.0, 0.0)
                    self.out.send(ev="watchdog", wall=time.time())

    async def reset(self) -> None:
        """Publish ``state/reset`` (a Duckiematrix robot goes back to its start), telling proxybench when done."""
        from dtps_http import RawData

        try:
            await asyncio.wait_for(self._topic(self.ctx, "state/reset").publish(
                RawData.cbor_from_native_object({"header": _header(), "data": True})), 5.0)
            self.out.send(ev="reset-sent", wall=time.time())
        except Exception as exc:
            self.out.send(ev="reset-failed", detail=f"{type(exc).__name__}: {exc}"[:300])

    async def run(self, requests: In) -> None:
        await self.start()
        try:
            async for m in requests:
                op = m.get("op")
                if op == "cmd":
                    self.last_command = time.monotonic()
                    self.command(float(m["left"]), float(m["right"]))
                elif op == "stop":
                    self.last_command = time.monotonic()
                    self.command(0.0, 0.0)
                elif op == "reset":
                    await self.reset()
                elif op == "quit":
                    break
        finally:
            self.command(0.0, 0.0)
            delivered = True
            try:
                await asyncio.wait_for(self.zero_delivered.wait(), self.args.stop_grace)
            except TimeoutError:
                delivered = False
            self.out.send(ev="stopped", delivered=delivered, wall=time.time())
            self.out.finish()


@contextlib.asynccontextmanager
async def _within(seconds: float, cm):
    """Enter the async context manager ``cm`` within ``seconds`` (a server that accepts and never answers)."""
    value = await asyncio.wait_for(cm.__aenter__(), seconds)
    try:
        yield value
    except BaseException as exc:
        if not await cm.__aexit__(type(exc), exc, exc.__traceback__):
            raise
    else:
        await cm.__aexit__(None, None, None)


def _pose_of(msg: dict) -> list[float]:
    """(x, y, θ) of a Transformation (position + quaternion) or of a plain {x, y, theta|yaw} map."""
    if "position" in msg:
        p, q = msg["position"], msg["rotation"]
        w, x, y, z = (float(q[k]) for k in "wxyz")
        return [float(p["x"]), float(p["y"]), math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))]
    return [float(msg["x"]), float(msg["y"]), float(msg.get("theta", msg.get("yaw", 0.0)))]


def _wheels(msg: dict) -> tuple[float, float]:
    """(left, right) of a wheel command (a WheelsCmd message); TypeError/KeyError when they are not numbers."""
    left, right = msg["left"], msg["right"]
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in (left, right)):
        raise TypeError(f"left/right are {type(left).__name__}/{type(right).__name__}, not numbers")
    return float(left), float(right)


def _own_network() -> None:
    """Move this process into a network namespace of its own, its loopback up (needs root): the virtual robot
    of an agent package serves there, and only that package's sandbox joins it."""
    import ctypes
    import fcntl
    import socket
    import struct

    libc = ctypes.CDLL(None, use_errno=True)
    if libc.unshare(0x40000000) != 0:  # CLONE_NEWNET
        err = ctypes.get_errno()
        raise OSError(err, f"unshare(CLONE_NEWNET): {os.strerror(err)} (a namespace of its own needs root)")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        flags = struct.unpack("16sH14x", fcntl.ioctl(s, 0x8913, struct.pack("16sH14x", b"lo", 0)))[1]  # SIOCGIFFLAGS
        fcntl.ioctl(s, 0x8914, struct.pack("16sH14x", b"lo", flags | 1))  # SIOCSIFFLAGS: IFF_UP


def _drop_to(user: str) -> None:
    """Run on as ``user`` (no groups): the server parses what a stranger's agent sends, so it gets no rights to
    lose. Called once the server listens; every module it may still import is imported first, while the SDK
    environment (in root's home, say) is still readable."""
    import importlib
    import pkgutil
    import pwd

    for name in ("dtps", "dtps_http", "aiohttp", "cbor2", "multidict", "yarl"):
        package = importlib.import_module(name)
        for info in pkgutil.walk_packages(getattr(package, "__path__", []), name + "."):
            with contextlib.suppress(Exception):  # an optional part without its dependency
                importlib.import_module(info.name)
    importlib.import_module("encodings.idna")
    pw = pwd.getpwnam(user)
    os.setgroups([])
    os.setgid(pw.pw_gid)
    os.setuid(pw.pw_uid)


def _one_line(record: logging.LogRecord) -> bool:
    """A log record as one line of at most 300 characters: an exception's type and first line, not its traceback
    (the server's log must not fill with tracebacks a hostile client provokes at will)."""
    text = record.getMessage()
    if record.exc_info and record.exc_info[1] is not None:
        exc = record.exc_info[1]
        text = f"{text}: {type(exc).__name__}: {str(exc).strip()}"
    first = text.strip().splitlines()[0] if text.strip() else ""
    record.msg, record.args = first[:300] + ("…" if len(first) > 300 else ""), None
    record.exc_info, record.exc_text, record.stack_info = None, None, None
    return True


def quiet_logging(*, one_line: bool) -> None:
    """Log warnings and worse only (dtps sets its loggers to DEBUG when imported: filter at the handlers), each
    record as one line (:func:`_one_line`, never a traceback) when ``one_line``."""
    logging.basicConfig()
    for handler in logging.getLogger().handlers:
        handler.setLevel(logging.WARNING)
        if one_line:
            handler.addFilter(_one_line)


def serve_role(make, args: argparse.Namespace, out: Out) -> None:
    """Run a role (``make(args, out)``, built inside the event loop) on this process's stdin requests until its
    end: the end of input, ``op: quit``, SIGTERM (which ends it as the end of input does) or Ctrl-C."""

    async def run() -> None:
        loop = asyncio.get_running_loop()
        role = make(args, out)
        requests = In(loop)
        loop.add_signal_handler(signal.SIGTERM, requests.queue.put_nowait, None)  # ends like the end of input
        await role.run(requests)

    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(run())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="role", required=True)
    srv = sub.add_parser("server")
    srv.add_argument("--host", default="127.0.0.1")
    srv.add_argument("--port", type=int, default=7501)
    srv.add_argument("--name", default="map_0/vehicle_0")
    srv.add_argument("--prefix", default="robot")
    srv.add_argument("--own-netns", action="store_true", help="serve in a network namespace of its own (root)")
    srv.add_argument("--drop-to", default="", help="once listening, run on as this user")
    srv.add_argument("--header-timeout", type=float, default=10.0,
                     help="close a connection whose request headers are not complete this long after it opened [s]")
    srv.add_argument("--idle-timeout", type=float, default=15.0,
                     help="close a kept-alive connection idle this long between requests [s]")
    cli = sub.add_parser("client")
    cli.add_argument("--url", required=True)
    cli.add_argument("--name", required=True, help="the robot's path on the server (a real DB21: its name; the "
                     "Duckiematrix: robot/map_0/vehicle_0)")
    cli.add_argument("--pwm", default="actuator/wheels/base/pwm")
    cli.add_argument("--pose", default="state/pose", help="pose topic under the robot, or /PATH from the root")
    cli.add_argument("--pose-url", default="", help="the localisation server's URL, when not the robot's")
    cli.add_argument("--watchdog", type=float, default=0.5)
    cli.add_argument("--stop-grace", type=float, default=3.0, help="how long to try to deliver (0, 0) on exit [s]")
    cli.add_argument("--observe", action="store_true", help="forward the wheel commands others publish (not the "
                     "camera or encoders); publish only stops (op: stop, and on exit)")
    args = parser.parse_args()
    quiet_logging(one_line=args.role == "server")  # what a stranger's request provokes is one line
    out = Out()
    if getattr(args, "own_netns", False):
        try:
            _own_network()
        except OSError as exc:
            out.send(ev="error", detail=f"cannot serve in a network namespace of its own: {exc}")
            raise SystemExit(2) from None
    serve_role(Server if args.role == "server" else Client, args, out)


if __name__ == "__main__":
    main()
