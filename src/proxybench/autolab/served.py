"""Simulated watchtowers served as a lab's own cameras, for a stand-in lab (``proxybench dtps serve --watchtowers``).

An Autolab evaluator reads a real lab's watchtowers from DTPS camera topics, each frame stamped by its camera's
clock at exposure, and drives a robot it does not simulate. To stand in for such a lab on one machine, the virtual
DB21J of ``proxybench dtps serve`` renders the lab's layout in its own world every episode and publishes each
frame here, stamped with the **wall clock** when it was rendered (plus the watchtower's drawn clock error), as a
camera would: nothing in the stamps refers to the simulator's episode, so the evaluator must find the episode's
origin itself (the robot's first command), exactly as in a real lab.

A **robot node** stand-in (``proxybench robot serve --watchtowers``) is stepped by its caller frame by frame, at
no pace of the wall clock: there each episode's recording begins at the robot's first step (its first command) and
every frame is stamped with that wall time plus the world's time, which is what a camera would stamp were the world
real-time (:class:`NodeServedTowers`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from proxybench.autolab.calibration import stream_spec
from proxybench.autolab.live import _served
from proxybench.autolab.watchtowers import Layout
from proxybench.dtps.cameras import WatchtowerServer

__all__ = ["NodeServedTowers", "ServedTowers", "served_towers"]


@dataclass
class ServedTowers:
    """The runner's stream sink that publishes every watchtower frame on :attr:`server`, stamped by the wall clock."""

    server: WatchtowerServer
    kind: str = "dtps-served"

    def begin(self, out: Path) -> None:
        self.server.take_counts()

    def frame(self, camera: str, jpeg: bytes, stamp: float, t: float) -> None:
        self.server.publish(camera, jpeg, time.time() + (stamp - t), t)  # stamp - t: the tower's clock error

    def end(self) -> None:
        self.server.take_counts()


@dataclass
class NodeServedTowers(ServedTowers):
    """:class:`ServedTowers` of a world stepped at its caller's pace (a robot node): the recording begins at the
    episode's first step, and each frame is stamped with that wall time plus the world's time (and the tower's clock
    error), so the stamps are a real-time world's however fast or slow the node steps."""

    origin: float = 0.0

    def begin(self, out: Path) -> None:
        super().begin(out)
        self.origin = time.time()

    def frame(self, camera: str, jpeg: bytes, stamp: float, t: float) -> None:
        self.server.publish(camera, jpeg, self.origin + stamp, t)


def served_towers(layout: Layout, *, port: int | None = None, node: bool = False):
    """(the runner's stream spec, the sink with its server) for ``layout``'s watchtowers served over DTPS on
    ``port`` of 127.0.0.1 (None: a free one; ``sink.server.address(name)``); ``node``: stamped for a robot node
    (:class:`NodeServedTowers`); close ``sink.server`` when done."""
    from proxybench.runner.streams import StreamSpec

    server, _ = _served(layout, port)
    sink = (NodeServedTowers if node else ServedTowers)(server)
    base = stream_spec(layout)
    return StreamSpec(base.cameras, base.rates, base.clock_offsets, base.fixtures, sink=sink), sink
