"""The zoo's independently written controllers (issue 35 item 3): six concepts, each with honest variants.

Each concept lives in a module of its own and shares no code with the older agents beyond the nominal DB18
PWM inversion (:func:`proxybench.agents.pid.wheels_for`) that every agent uses; each variant changes a
parameter that changes how it drives (gain, horizon, speed, look-ahead, assumed camera), measured on
``loop_3x3`` by ``tests/test_agent_pool.py``. Privileged ones read the true lane pose; camera ones only the image.
:mod:`proxybench.agents.zoo` registers them; :mod:`proxybench.agents.families` names their families.
"""

from __future__ import annotations

from collections.abc import Callable

from proxybench.agents.base import Agent
from proxybench.agents.birdseye import BirdsEyeAgent, GroundCamera
from proxybench.agents.cautious import CautiousAgent
from proxybench.agents.hough import HoughLaneAgent
from proxybench.agents.lqr import LQRAgent
from proxybench.agents.mpc import ArcSamplerAgent
from proxybench.agents.stanley import StanleyAgent

__all__ = ["INDEPENDENT"]


def _named(factory: Callable[[], Agent], name: str) -> Callable[[], Agent]:
    def make() -> Agent:
        agent = factory()
        agent.name = name
        return agent

    return make


_SPECS: list[tuple[str, Callable[[], Agent], str]] = [
    ("stanley", StanleyAgent, "Stanley steering (front-axle error, atan law) on the true lane pose, 0.3 m/s"),
    ("stanley-gentle", lambda: StanleyAgent(gain=0.5), "Stanley with a low cross-track gain: slow to recentre"),
    ("stanley-fast", lambda: StanleyAgent(speed=0.5), "Stanley at 0.5 m/s"),
    ("lqr", LQRAgent, "LQR state feedback (Riccati gain) on the true lane pose, 0.3 m/s, no delay model"),
    ("lqr-soft", lambda: LQRAgent(max_turn=0.5), "LQR with a heavy turn-rate weight: gentle, wide in curves"),
    ("lqr-delay", lambda: LQRAgent(delay_frames=1), "LQR designed for a one-frame command delay"),
    ("mpc", ArcSamplerAgent, "sampling MPC: 25 constant arcs rolled out 0.8 s in the lane frame, cheapest first"),
    ("mpc-short", lambda: ArcSamplerAgent(horizon=0.2), "sampling MPC with a myopic 0.2 s horizon"),
    ("mpc-fast", lambda: ArcSamplerAgent(speeds=(0.2, 0.35, 0.5), progress_weight=20.0),
     "sampling MPC choosing its speed too (0.2–0.5 m/s), rewarded for progress"),
    ("cautious", CautiousAgent, "speed scheduled by curvature, own error and front range; bearing steering"),
    ("cautious-brisk", lambda: CautiousAgent(top_speed=0.5, caution=0.5),
     "cautious with 0.5 m/s top, half the caution"),
    ("hough", HoughLaneAgent, "camera only: HSV thresholds, Hough lines in the image, PD on the lane centre"),
    ("hough-far", lambda: HoughLaneAgent(lookahead_row=0.55), "hough aiming at a row further up the image"),
    ("hough-fast", lambda: HoughLaneAgent(speed=0.4), "hough at 0.4 m/s"),
    ("birdseye", BirdsEyeAgent, "camera only: bird's-eye warp, adaptive thresholds, histogram peaks, pursuit"),
    ("birdseye-far", lambda: BirdsEyeAgent(far=(0.3, 0.5)), "birdseye pursuing a point 0.3–0.5 m ahead"),
    ("birdseye-pitch25", lambda: BirdsEyeAgent(GroundCamera(pitch=25.0)),
     "birdseye assuming the camera pitched 25° (true 19.15°)"),
]

#: (name, factory, description) of every independently written zoo agent
INDEPENDENT: list[tuple[str, Callable[[], Agent], str]] = [(n, _named(f, n), d) for n, f, d in _SPECS]
