"""The built-in agent zoo: named, parameterised agents with a real spread of quality.

Names are stable identifiers used in result tables, ``proxybench agent list`` and
``proxybench agent serve NAME``. Vision agents whose *assumed* camera differs from the Duckiebot's
are how simulator parameters (camera pitch, field of view, light) come to change the ranking.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from proxybench.agents.base import Agent
from proxybench.agents.calibration import CALIBRATION_DRIVES
from proxybench.agents.independent import INDEPENDENT
from proxybench.agents.pid import LanePIDAgent, PIDGains
from proxybench.agents.pursuit import PurePursuitAgent
from proxybench.agents.simple import BangBangAgent, RandomAgent, StraightAgent
from proxybench.agents.stopping import StopRule
from proxybench.agents.vision import AssumedCamera, LaneVisionAgent

__all__ = ["ZOO", "ZooEntry", "agent_names", "make_agent"]


@dataclass(frozen=True)
class ZooEntry:
    """A named agent: how to build it and a one-line description."""

    name: str
    factory: Callable[[], Agent]
    description: str
    privileged: bool


def _entry(name: str, factory: Callable[[], Agent], description: str) -> ZooEntry:
    probe = factory()
    return ZooEntry(name, factory, description, probe.privileged)


def _named(agent: Agent, name: str) -> Agent:
    agent.name = name
    return agent


ZOO: dict[str, ZooEntry] = {
    e.name: e
    for e in [
        _entry("random", lambda: _named(RandomAgent(), "random"), "uniform random PWM, re-drawn every 3 frames"),
        _entry("straight", lambda: _named(StraightAgent(0.5), "straight"), "open loop: PWM 0.5 on both wheels"),
        _entry("bang-bang", lambda: _named(BangBangAgent(), "bang-bang"),
               "full left/right turns on the sign of the true lane error"),
        _entry("pid", lambda: _named(LanePIDAgent(), "pid"), "PID on the true lane pose, 0.3 m/s"),
        _entry("pid-fast", lambda: _named(LanePIDAgent(PIDGains(speed=0.5)), "pid-fast"),
               "PID on the true lane pose, 0.5 m/s"),
        _entry("pid-sluggish", lambda: _named(LanePIDAgent(PIDGains(k_lateral=2.0, k_heading=1.0, k_integral=0.0)),
                                              "pid-sluggish"), "PID with low gains: drifts wide in curves"),
        _entry("pid-twitchy", lambda: _named(LanePIDAgent(PIDGains(k_lateral=40.0, k_heading=12.0)),
                                             "pid-twitchy"), "PID with high gains: oscillates, worse with delay"),
        _entry("pid-stop", lambda: _named(LanePIDAgent(stop=StopRule()), "pid-stop"),
               "PID on the true lane pose, 0.3 m/s, stopping 1 s at every stop line"),
        _entry("pure-pursuit", lambda: _named(PurePursuitAgent(), "pure-pursuit"),
               "pure pursuit on the true lane geometry, 0.35 m/s (the expert)"),
        _entry("pure-pursuit-fast", lambda: _named(PurePursuitAgent(speed=0.5, lookahead=0.3),
                                                   "pure-pursuit-fast"), "pure pursuit at 0.5 m/s"),
        _entry("pure-pursuit-stop", lambda: _named(PurePursuitAgent(stop=StopRule()), "pure-pursuit-stop"),
               "pure pursuit at 0.35 m/s, stopping 1 s at every stop line"),
        _entry("vision", lambda: _named(LaneVisionAgent(), "vision"),
               "camera only: colour segmentation, ground projection, line fit, PID"),
        _entry("vision-fast", lambda: _named(LaneVisionAgent(speed=0.4), "vision-fast"), "vision at 0.4 m/s"),
        _entry("vision-slow", lambda: _named(LaneVisionAgent(speed=0.15), "vision-slow"), "vision at 0.15 m/s"),
        _entry("vision-pitch15", lambda: _named(LaneVisionAgent(AssumedCamera(pitch=15.0)), "vision-pitch15"),
               "vision assuming the camera pitched 15° (true 19.15°)"),
        _entry("vision-pitch25", lambda: _named(LaneVisionAgent(AssumedCamera(pitch=25.0)), "vision-pitch25"),
               "vision assuming the camera pitched 25°"),
        _entry("vision-wide", lambda: _named(LaneVisionAgent(AssumedCamera(fov_y=90.0)), "vision-wide"),
               "vision assuming a 90° vertical field of view (true 75°)"),
        _entry("vision-twitchy", lambda: _named(LaneVisionAgent(k_lateral=20.0, k_heading=8.0, smoothing=0.0),
                                                "vision-twitchy"), "vision with high gains and no smoothing"),
        *(_entry(*spec) for spec in INDEPENDENT),
        *(_entry(*spec) for spec in CALIBRATION_DRIVES),
    ]
}


def agent_names() -> list[str]:
    return list(ZOO)


def make_agent(name: str) -> Agent:
    """A fresh instance of the zoo agent ``name``, or of an agent of a registered kind (a behaviour-cloning
    checkpoint path: :mod:`proxybench.agents.kinds`)."""
    if name not in ZOO:
        from proxybench.agents.kinds import find_kind

        kind = find_kind(name)
        if kind is not None:
            return kind.make(name)
    try:
        return ZOO[name].factory()
    except KeyError:
        raise KeyError(f"unknown agent {name!r}; known: {', '.join(ZOO)}") from None
