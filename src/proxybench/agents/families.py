"""Agent families: which agents share a concept, so that held-out agents can be more than siblings.

A *family* is a controller concept (a PID on the lane pose, pure pursuit, Stanley, a Hough-transform camera
agent, …); the variants within a family differ by a parameter. The validation study tunes θ on some agents and
judges it on others; when both sets hold variants of the same concept, "held-out" agents are siblings of the
tuning ones. Splitting by family (tune on some families, judge on the rest: :func:`proxybench.usefulness.
agent_resampling.family_splits`) removes that. Every zoo agent has a family in :data:`ZOO_FAMILIES`; any other
agent label gets one from a ``FAMILY:`` prefix (``lqr:my-lqr.pt``), else by its kind: a checkpoint (``….pt``) is
``learned``, an agent node (``NAME=COMMAND``) ``node`` unless its NAME is known, anything else ``other``.

>>> family_of("pid-fast"), family_of("hough"), family_of("runs/bc-3-0.pt"), family_of("mpc:runs/bc.pt")
('pid', 'hough', 'learned', 'mpc')
>>> family_of("vision-node={python} -m proxybench.protocol vision"), family_of("mine=python3 solution.py")
('vision', 'node')
>>> pool_families(["pid", "pid-fast", "hough", "straight"])
['hough', 'pid', 'trivial']
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from types import MappingProxyType

from proxybench.agents.calibration import CALIBRATION_DRIVES

__all__ = ["DEFAULT_FAMILY", "FAMILY_CONCEPTS", "ZOO_FAMILIES", "family_map", "family_of", "pool_families",
           "split_family_prefix"]

#: each family: the concept its members share (and whether they read the true lane pose or only the camera)
FAMILY_CONCEPTS: Mapping[str, str] = MappingProxyType({
    "trivial": "no feedback worth the name: random or open-loop commands (the calibration drives too)",
    "switching": "on/off steering on the sign of the true lane error",
    "pid": "PID on the true lane pose (agents/pid.py)",
    "pursuit": "pure pursuit of a look-ahead point on the true lane centre (agents/pursuit.py)",
    "vision": "camera: RGB thresholds, ground projection, line fit, PID (agents/vision.py), in-process or as a node",
    "stanley": "Stanley steering on the true lane pose (agents/stanley.py)",
    "lqr": "LQR state feedback on the true lane pose (agents/lqr.py)",
    "mpc": "sampling model-predictive control over arcs, true lane pose (agents/mpc.py)",
    "cautious": "speed scheduled by curvature, error and range; bearing steering, true lane pose (agents/cautious.py)",
    "hough": "camera: HSV thresholds, Hough lines in the image, PD (agents/hough.py)",
    "birdseye": "camera: bird's-eye warp, adaptive thresholds, histogram peaks, pursuit (agents/birdseye.py)",
    "learned": "networks cloned from an expert (behaviour-cloning checkpoints)",
    "node": "an agent node of unknown make, reached over the protocol",
    "other": "an agent of no declared family",
})

#: the family of every zoo agent
ZOO_FAMILIES: Mapping[str, str] = MappingProxyType({
    "random": "trivial", "straight": "trivial", "bang-bang": "switching",
    **{name: "trivial" for name, _factory, _description in CALIBRATION_DRIVES},
    **{n: "pid" for n in ("pid", "pid-fast", "pid-sluggish", "pid-twitchy", "pid-stop")},
    **{n: "pursuit" for n in ("pure-pursuit", "pure-pursuit-fast", "pure-pursuit-stop")},
    **{n: "vision" for n in ("vision", "vision-fast", "vision-slow", "vision-pitch15", "vision-pitch25",
                             "vision-wide", "vision-twitchy")},
    **{n: "stanley" for n in ("stanley", "stanley-gentle", "stanley-fast")},
    **{n: "lqr" for n in ("lqr", "lqr-soft", "lqr-delay")},
    **{n: "mpc" for n in ("mpc", "mpc-short", "mpc-fast")},
    **{n: "cautious" for n in ("cautious", "cautious-brisk")},
    **{n: "hough" for n in ("hough", "hough-far", "hough-fast")},
    **{n: "birdseye" for n in ("birdseye", "birdseye-far", "birdseye-pitch25")},
})

#: node labels whose make is known: ``vision-node`` is the vision agent behind the protocol, a sibling of ``vision``
_KNOWN_NODES: Mapping[str, str] = MappingProxyType({"vision-node": "vision"})

DEFAULT_FAMILY = "other"
_PREFIX = re.compile(r"^([a-z][a-z0-9_-]*):(?!//)(.+)$")


def split_family_prefix(label: str) -> tuple[str | None, str]:
    """(family, the rest) of ``FAMILY:AGENT``, or (None, label) when the label declares none.

    Only a lower-case word before the first ``:`` counts, and not where an ``=`` comes first (a node's command may
    hold colons), so ``package.module:Class`` and ``NAME=sdk[…]:CMD`` are left alone.
    """
    m = _PREFIX.match(label)
    if m is None or "=" in m.group(1):
        return None, label
    return m.group(1), m.group(2)


def family_of(label: str) -> str:
    """The family of an agent label of the pool (zoo name, ``FAMILY:…``, checkpoint, ``NAME=COMMAND``)."""
    if label in ZOO_FAMILIES:
        return ZOO_FAMILIES[label]
    declared, _ = split_family_prefix(label)
    if declared is not None:
        return declared
    name, sep, _command = label.partition("=")
    if sep:
        return _KNOWN_NODES.get(name, ZOO_FAMILIES.get(name, "node"))
    if label.endswith(".pt"):
        return "learned"
    return DEFAULT_FAMILY


def family_map(labels: Iterable[str]) -> dict[str, str]:
    """label → family for a pool, in the pool's order."""
    return {label: family_of(label) for label in labels}


def pool_families(labels: Iterable[str]) -> list[str]:
    """The distinct families of a pool, sorted."""
    return sorted(set(family_map(labels).values()))
