"""The drivers of NPC robots: one zoo agent per NPC Duckiebot of a simulator, playing beside the egos.

The domain steps the NPC robots (``Simulator.npc_*``) and stops one for good when it leaves the road or
touches anything; who drives them is decided here, above the domain: ``NpcRobot.driver`` names a zoo
agent. Privileged drivers read their true lane pose; camera drivers get their own camera frame (rendered
in the same call as the egos', through the same JPEG round trip). A driver that raises stops its robot
(it gets no more commands) without ending the ego's episode; every stop is an event of the ego's run.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.domain.dynamics import ST, wheel_ticks
from proxybench.domain.events import Event
from proxybench.domain.lane_pose import LanePose
from proxybench.domain.simulator import Simulator
from proxybench.domain.worlds import HIT_KINDS

__all__ = ["NpcDrivers", "npc_seed"]


def npc_seed(seed: int, j: int) -> int:
    """Seed handed to the driver of world-local NPC robot ``j`` in the episode of ``seed``."""
    return int(np.random.SeedSequence([seed & ((1 << 64) - 1), 0x44525652, j]).generate_state(1)[0])


class NpcDrivers:
    """One agent per NPC robot of ``sim``; ``act`` gives their wheel commands for a frame."""

    def __init__(self, sim: Simulator, image_filter: Callable[[np.ndarray], np.ndarray] | None = None,
                 make: Callable[[str], Agent] | None = None):
        if make is None:
            from proxybench.agents import make_agent as make
        self.sim = sim
        self.agents = [make(spec.driver) for spec in sim.worlds.robot_specs]
        self.camera = np.array([not a.privileged for a in self.agents], dtype=bool)
        self.failed = np.zeros(len(self.agents), dtype=bool)
        self._reported = np.zeros(len(self.agents), dtype=bool)
        self.image_filter = image_filter
        w = sim.worlds
        self.local = np.arange(w.k) - (w.robot_lo[w.robot_world] - sim.n)  # index within its world

    def reset(self, seeds: np.ndarray | list[int]) -> None:
        """New episodes: world w's drivers are reset from ``seeds[w]``."""
        self.failed[:] = False
        self._reported[:] = False
        for j, a in enumerate(self.agents):
            try:
                a.reset(npc_seed(int(seeds[self.sim.npc_world[j]]), int(self.local[j])))
            except Exception:  # a broken driver stops its robot, never the run
                self.failed[j] = True

    def wants_camera(self, alive: np.ndarray) -> np.ndarray | None:
        """(K,) which NPC cameras to render this frame (camera drivers of running worlds), or None."""
        need = self.camera & ~self.failed & alive[self.sim.npc_world] & ~self.sim.npc_stopped
        return need if need.any() else None

    def _observation(self, j: int, image: np.ndarray | None, privileged: bool) -> Observation:
        sim = self.sim
        w = int(sim.npc_world[j])
        s = sim.npc_state[j]
        res = sim.params[w].encoder_resolution
        ticks = wheel_ticks(s[[ST.WHEEL_L, ST.WHEEL_R]], res)
        lane = sim.npc_lane[j]
        lp = LanePose.from_row(lane) if privileged else None
        route = sim.routes.info(sim.n + j, lane) if privileged else None
        return Observation(image, float(sim.time[w]), (float(ticks[0] * res), float(ticks[1] * res)), res, lp, route)

    def act(self, alive: np.ndarray) -> np.ndarray:
        """(K, 2) wheel PWM of the NPC robots of running worlds (zero for the others and stopped ones)."""
        sim = self.sim
        out = np.zeros((len(self.agents), 2))
        frames = getattr(sim, "npc_frames", None)
        for j in np.flatnonzero(alive[sim.npc_world] & ~self.failed & ~sim.npc_stopped):
            image = None
            if self.camera[j] and frames is not None:
                image = self.image_filter(frames[j]) if self.image_filter is not None else frames[j]
            try:
                cmd = np.asarray(self.agents[j].act(self._observation(j, image, self.agents[j].privileged)),
                                 dtype=np.float64)
                if cmd.shape != (2,) or not np.all(np.isfinite(cmd)):
                    raise ValueError(f"driver returned {cmd!r}, expected 2 finite wheel PWM values")
                out[j] = cmd
            except Exception:  # likewise
                self.failed[j] = True
        return out

    def events(self) -> list[tuple[int, Event]]:
        """(world, event) for every NPC robot that stopped since the last call."""
        sim = self.sim
        new = (self.failed | sim.npc_stopped) & ~self._reported
        self._reported |= new
        out = []
        for j in np.flatnonzero(new):
            w = int(sim.npc_world[j])
            if self.failed[j]:
                why = "its driver failed"
            elif sim.npc_hit_kind[j]:
                why = f"it hit {_a(HIT_KINDS[int(sim.npc_hit_kind[j])])}"
            else:
                why = "it left the road"
            out.append((w, Event(float(sim.time[w]), "npc_stopped", npc=int(self.local[j]),
                                 message=f"NPC robot {int(self.local[j])} ({self.agents[j].name}) stopped: {why}")))
        return out

    def close(self) -> None:
        for a in self.agents:
            getattr(a, "close", lambda: None)()


def _a(what: str) -> str:
    return "an " + what if what[:1] in "aeiou" else "a " + what
