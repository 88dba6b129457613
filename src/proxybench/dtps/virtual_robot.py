"""A virtual DB21J served over DTPS: the bridge in its ``server`` role, fed one frame at a time.

The same object serves SDK agents run by proxybench (:class:`~.agent.SdkAgent`) and ``proxybench dtps
serve`` (an agent the user starts). One robot per port on this machine at a time (:class:`~.link.PortLock`):
an unchanged SDK agent always connects to ``127.0.0.1:7501``, so two episodes cannot share a machine's port.
"""

from __future__ import annotations

import math
import time
from typing import Any

from proxybench.agents.base import Observation
from proxybench.domain.maps import Map
from proxybench.dtps.link import PORT_LOCK_TIMEOUT_S, BridgeLink, PortLock
from proxybench.dtps.maplayer import map_layers
from proxybench.protocol import jpeg

__all__ = ["DEFAULT_NAME", "DEFAULT_PORT", "NETNS_USER", "TICKS_PER_TURN", "VirtualDB21J"]

DEFAULT_NAME = "map_0/vehicle_0"  # what an SDK agent names the Duckiematrix's first robot
DEFAULT_PORT = 7501  # duckietown-sdk's DEFAULT_DUCKIEMATRIX_PORT
TICKS_PER_TURN = 135  # duckietown-sdk's wheel encoder resolution
#: who a virtual robot in a namespace of its own runs as: neither root nor the agent user
NETNS_USER = "nobody"


class VirtualDB21J:
    """The virtual robot at ``http://host:port/robot/<name>/``; ``publish`` one frame, ``events`` what came back.

    ``lock``: wait for the port's lock (another proxybench episode of this user may be serving it) up to
    ``lock_timeout`` s, then :class:`~.link.PortLockError` naming the holder; ``start_timeout`` bounds the bridge's
    start.
    """

    def __init__(self, *, name: str = DEFAULT_NAME, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 python: str | None = None, start_timeout: float = 60.0, lock: bool = True, own_netns: bool = False,
                 lock_timeout: float = PORT_LOCK_TIMEOUT_S):
        self.name, self.host, self.port = name, host, port
        self.lock = PortLock(port)
        if lock and not own_netns:  # a namespace of its own has its own port 7501
            self.lock.acquire(lock_timeout)
        extra = ["--own-netns", "--drop-to", NETNS_USER] if own_netns else []
        try:
            self.link = BridgeLink(["server", "--host", host, "--port", str(port), "--name", name, *extra],
                                   python=python, start_timeout=start_timeout)
        except BaseException:
            self.lock.release()
            raise
        self.url = f"{self.link.ready['url']}{self.link.ready['prefix']}/"
        self.seq = -1
        #: where a sandbox joins the robot's network (``own_netns``): the bridge's namespace
        self.netns = f"/proc/{self.link.pid}/ns/net" if own_netns else None

    def publish_map(self, m: Map) -> None:
        """The map layer (``map/frames``, ``map/tiles``, ``map/tile_maps``) of ``m``."""
        self.link.send(op="map", **map_layers(m))

    def publish(self, obs: Observation, *, dt: float | None, nudge: bool = False) -> int:
        """One frame: camera JPEG (the very bytes an AIDO node gets), encoder ticks, ToF range, Δt and, where the
        observation carries it (privileged agents), the true pose. Returns the frame's sequence number."""
        self.seq += 1
        jpg = None
        if obs.camera is not None:
            jpg = jpeg.jpeg_of(obs.camera) or jpeg.encode(obs.camera)
        ticks = None
        if obs.odometry is not None:
            ticks = [round(a * TICKS_PER_TURN / (2 * math.pi)) for a in obs.odometry]
        self.link.send(op="frame", seq=self.seq, t=float(obs.time), jpeg=jpg, ticks=ticks, range=obs.front_range,
                       dt=dt, pose=None if obs.pose is None else [float(v) for v in obs.pose], nudge=nudge)
        return self.seq

    @property
    def alive(self) -> bool:
        """Whether the bridge (the robot's server) still runs."""
        return self.link.alive

    @property
    def exit_code(self) -> int | None:
        return self.link._os.returncode

    def events(self, deadline: float) -> list[dict[str, Any]]:
        """What the bridge reported by ``deadline`` (commands, resets, …); returns early when something came."""
        return self.link.poll(deadline)

    def drain(self) -> list[dict[str, Any]]:
        return self.link.poll(time.monotonic())

    def close(self) -> None:
        try:
            self.link.close()
        finally:
            self.lock.release()
