"""The ``npcs:`` entries of a benchmark file: NPC Duckiebots and pedestrians, validated strictly.

Each entry is a mapping with a ``kind``; unknown keys are errors, reported with their field path, the
kind included (e.g. ``aido_lfv.yaml: npcs.0.duckiebot.agent: unknown agent 'pdi' ...``)::

    npcs:
      - kind: duckiebot          # a Duckiebot driven by a zoo agent (privileged or camera)
        agent: pid
        start: random            # or {tile: [i, j]}, {pose: [x, y, theta]}, {ahead: 0.8} (m along the ego's lane)
        speed_scale: 0.8         # multiplies its wheel commands
      - kind: pedestrian         # a duckie walking waypoints [m] in the map frame
        path: [[0.9, 0.05], [0.9, 0.55]]
        speed: 0.15              # m/s
        delay: 2.0               # s before it sets off
        mode: back-and-forth     # or loop, once

Checks that need the map (tiles, poses on the road, waypoints on the map) are the benchmark's
(:meth:`proxybench.tasks.benchmark.Benchmark`); ``to_domain`` turns an entry into the domain's
``NpcRobot`` / ``Pedestrian``.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, field_validator, model_validator

from proxybench.domain.lane_pose import LP
from proxybench.domain.maps import Map
from proxybench.domain.npcs import PEDESTRIAN_MODES, NpcRobot, Pedestrian, Traffic

__all__ = ["DuckiebotNpc", "NpcEntry", "NpcStart", "PedestrianNpc", "npc_issues", "traffic_of"]

FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class NpcStart(_Strict):
    """Where an NPC robot starts: at most one of ``tile``, ``pose``, ``ahead``; none (or ``random``) draws a
    lane point of the whole map from the episode seed."""

    tile: tuple[int, int] | None = Field(None, description="a lane point of this tile (i, j), drawn from the seed")
    pose: tuple[FiniteFloat, FiniteFloat, FiniteFloat] | None = Field(None, description="[x m, y m, θ rad]")
    ahead: float | None = Field(None, gt=0.0, le=20.0, description="this far [m] ahead of the ego along its lane")

    @model_validator(mode="after")
    def _one_rule(self) -> NpcStart:
        given = [k for k in ("tile", "pose", "ahead") if getattr(self, k) is not None]
        if len(given) > 1:
            raise ValueError(f"give one of tile, pose or ahead, not {' and '.join(given)}")
        return self


class DuckiebotNpc(_Strict):
    """An NPC Duckiebot driven by a zoo agent; it stops for good if it leaves the road or hits anything."""

    kind: Literal["duckiebot"]
    agent: str = Field("pid", description="zoo agent that drives it (see `proxybench agent list`)")
    start: NpcStart = Field(default_factory=NpcStart, description="random, {tile}, {pose} or {ahead}")
    speed_scale: float = Field(1.0, ge=0.0, le=3.0, description="multiplies its wheel commands [-]")

    @field_validator("start", mode="before")
    @classmethod
    def _random(cls, v: Any) -> Any:
        if isinstance(v, str):
            if v != "random":
                raise ValueError(f"{v!r}: use random, or a mapping with tile, pose or ahead")
            return {}
        return v

    @field_validator("agent")
    @classmethod
    def _known_agent(cls, name: str) -> str:
        from proxybench.agents.zoo import ZOO

        if name not in ZOO:
            raise ValueError(f"unknown agent {name!r} (one of {', '.join(ZOO)})")
        return name

    def to_domain(self) -> NpcRobot:
        s = self.start
        return NpcRobot(self.agent, s.pose, s.tile, s.ahead, self.speed_scale)


class PedestrianNpc(_Strict):
    """A duckie walking ``path`` (waypoints [x m, y m], map frame) at ``speed`` from ``delay`` on."""

    kind: Literal["pedestrian"]
    path: list[tuple[FiniteFloat, FiniteFloat]] = Field(min_length=1, description="waypoints [[x, y], ...] [m]")
    speed: float = Field(0.2, ge=0.0, le=2.0, allow_inf_nan=False, description="walking speed [m/s]")
    delay: float = Field(0.0, ge=0.0, allow_inf_nan=False, description="time before it sets off [s]")
    mode: Literal["loop", "back-and-forth", "once"] = Field("back-and-forth", description="what it does at the end")

    def to_domain(self) -> Pedestrian:
        assert self.mode in PEDESTRIAN_MODES
        return Pedestrian(tuple((float(x), float(y)) for x, y in self.path), self.speed, self.delay, self.mode)


def _kind(v: Any) -> Any:
    return v.get("kind") if isinstance(v, dict) else getattr(v, "kind", None)


NpcEntry = Annotated[
    Annotated[DuckiebotNpc, Tag("duckiebot")] | Annotated[PedestrianNpc, Tag("pedestrian")],
    Discriminator(_kind, custom_error_type="npc_kind",
                  custom_error_message="an NPC needs a 'kind': duckiebot or pedestrian"),
]


def traffic_of(entries: list[DuckiebotNpc | PedestrianNpc]) -> Traffic | None:
    """The domain's ``Traffic`` of a benchmark's ``npcs`` (None if there are none)."""
    if not entries:
        return None
    return Traffic(tuple(e.to_domain() for e in entries if isinstance(e, DuckiebotNpc)),
                   tuple(e.to_domain() for e in entries if isinstance(e, PedestrianNpc)))


def npc_issues(entries: list[DuckiebotNpc | PedestrianNpc], m: Map) -> list[tuple[str, str]]:
    """(field path, message) of every NPC entry the map ``m`` cannot hold: a start tile without lanes, a
    start pose off the road, a waypoint more than a tile beyond the map's edge (a typo, or tiles for metres)."""
    from proxybench.domain.lane_pose import lane_poses
    from proxybench.domain.lanes import LaneNetwork

    if not entries:
        return []
    net = LaneNetwork(m)
    w, h = m.size_m
    e = m.tile_size
    issues = []
    for k, entry in enumerate(entries):
        start = entry.start if isinstance(entry, DuckiebotNpc) else None
        if start is not None and start.tile is not None and not net.by_tile.get(tuple(start.tile)):
            tile = m.tile(*start.tile)
            what = f"a {tile.kind} tile" if tile is not None else f"not on the {m.width}×{m.height} map"
            issues.append((f"npcs.{k}.duckiebot.start.tile", f"{list(start.tile)} has no lanes ({what})"))
        if start is not None and start.pose is not None:
            row = lane_poses(net, np.array([start.pose]))[0]
            if row[LP.VALID] < 0.5 or row[LP.ON_ROAD] < 0.5:
                issues.append((f"npcs.{k}.duckiebot.start.pose",
                               f"{list(start.pose)} is not on the road of map {m.name!r}"))
        if isinstance(entry, PedestrianNpc):
            issues += [(f"npcs.{k}.pedestrian.path.{p}",
                        f"({x:g}, {y:g}) m is more than a tile off the map ({w:g} × {h:g} m)")
                       for p, (x, y) in enumerate(entry.path) if not (-e <= x <= w + e and -e <= y <= h + e)]
    return issues
