"""Where a learning agent gets its data and is scored: one proxy instance θ, a family Θ, or the target.

A ``Domain`` is a named source of θ: a fixed instance (a proxy, or the reality model, which is a
*simulated* stand-in for a real Duckiebot) or a ``ParamSpace`` that is sampled once per episode
(domain randomisation). Every domain of one experiment shares the image size, since a network's input
size is fixed.

>>> d = parse_domain("proxy:camera_pitch=3", 80, 60)
>>> d.name, d.sample(np.random.default_rng(0)).camera_pitch
('proxy:camera_pitch=3', 3.0)
>>> parse_domain("reality", 80, 60).kind
'reality-model'
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.domain.params import DomainParams, ParamSpace
from proxybench.domain.reality import TRUTH, reality_params

__all__ = ["DEFAULT_RANDOMIZATION", "Domain", "parse_domain", "proxy_domain", "randomized_domain", "reality_domain",
           "robot_domain"]

#: the default domain-randomisation family around the calibrated proxy: dynamics, camera mounting,
#: light, sensor and surface appearance (the lens distortion and slip of the reality model are *not* in it)
DEFAULT_RANDOMIZATION: dict[str, dict[str, list[float]]] = {
    "trim": {"uniform": [-0.1, 0.1]},
    "gain": {"uniform": [0.85, 1.15]},
    "command_delay": {"uniform": [0.05, 0.15]},
    "blur_time": {"uniform": [0.0, 0.08]},
    "camera_pitch": {"uniform": [15.0, 23.0]},
    "camera_height": {"uniform": [0.10, 0.116]},
    "light_rgb": {"uniform": [0.8, 1.2]},
    "brightness": {"uniform": [-20.0, 20.0]},
    "contrast": {"uniform": [0.8, 1.2]},
    "noise_std": {"uniform": [0.0, 6.0]},
    "vignetting": {"uniform": [0.0, 0.2]},
    "texture_seed": {"choice": [0, 1, 2, 3, 4, 5, 6, 8, 9]},
}


@dataclass(frozen=True)
class Domain:
    """A named source of domain parameters: ``params`` (one θ) or ``space`` (a family, drawn per episode)."""

    name: str
    kind: str  # "simulation", "family", "reality-model" or "robot"
    params: DomainParams | None = None
    space: ParamSpace | None = None
    command: str | None = None  # a robot node's command (kind "robot"); params then only give the image size
    frame_rate: float = 15.0  # [Hz] what a robot node is asked to step at

    def __post_init__(self) -> None:
        if (self.params is None) == (self.space is None):
            raise ValueError(f"domain {self.name!r}: give exactly one of params (θ) or space (Θ)")
        if (self.kind == "robot") != bool(self.command and self.command.strip()):
            raise ValueError(f"domain {self.name!r}: a robot domain needs the node's command, and only it has one")

    @property
    def base(self) -> DomainParams:
        """θ, or the family's base instance (its structural fields are those of every draw)."""
        return self.params if self.params is not None else self.space.base  # type: ignore[union-attr]

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) [px]."""
        return self.base.image_width, self.base.image_height

    def sample(self, rng: np.random.Generator) -> DomainParams:
        """θ for one episode: the fixed instance, or a draw from the family."""
        return self.params if self.params is not None else self.space.sample(rng)  # type: ignore[union-attr]

    def describe(self) -> dict[str, Any]:
        """JSON-able record of the domain, stored beside datasets, checkpoints and results."""
        out: dict[str, Any] = {"name": self.name, "kind": self.kind}
        if self.command is not None:
            return out | {"command": self.command, "frame_rate": self.frame_rate,
                          "image_size": list(self.image_size)}
        if self.params is not None:
            out["params"] = self.params.model_dump(mode="json")
        else:
            out["base"] = self.base.model_dump(mode="json")
            out["space"] = self.space.to_dict()  # type: ignore[union-attr]
        return out

    @classmethod
    def from_description(cls, d: dict[str, Any]) -> Domain:
        """The inverse of :meth:`describe`."""
        if "command" in d:
            return robot_domain(d["command"], *d["image_size"], frame_rate=d.get("frame_rate", 15.0))
        if "params" in d:
            return cls(d["name"], d["kind"], params=DomainParams.model_validate(d["params"]))
        return cls(d["name"], d["kind"], space=ParamSpace(DomainParams.model_validate(d["base"]), d["space"]))


def reality_domain(width: int, height: int) -> Domain:
    """The target: the reality model (a simulated stand-in for a real Duckiebot) at this image size."""
    return Domain("reality", "reality-model", params=reality_params(image_width=width, image_height=height))


def robot_domain(command: str, width: int, height: int, *, frame_rate: float = 15.0) -> Domain:
    """A robot node as a domain (a physical robot's bridge, another simulator, ``proxybench robot serve``): its θ is
    its own; ``width`` × ``height`` is the size its camera frames are brought to for the network."""
    return Domain(f"robot:{command}", "robot", params=DomainParams(image_width=width, image_height=height),
                  command=command, frame_rate=frame_rate)


def proxy_domain(width: int, height: int, name: str | None = None, **changes: Any) -> Domain:
    """A proxy instance: the plain simulator at the target's calibrated values ``TRUTH``, with ``changes``."""
    p = DomainParams(image_width=width, image_height=height, **{**TRUTH, **changes})
    label = name or ("proxy" + (":" + ",".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
                                               for k, v in changes.items()) if changes else ""))
    return Domain(label, "simulation", params=p)


def randomized_domain(width: int, height: int, dists: dict[str, Any] | None = None,
                      name: str = "randomized") -> Domain:
    """A domain-randomised family around the calibrated proxy (``DEFAULT_RANDOMIZATION`` unless given)."""
    base = DomainParams(image_width=width, image_height=height, **TRUTH)
    return Domain(name, "family", space=ParamSpace(base, dists or DEFAULT_RANDOMIZATION))


def _value(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def parse_domain(spec: str, width: int, height: int) -> Domain:
    """A domain from a short spec, as the command line takes it.

    ``reality`` (the target), ``proxy`` or ``proxy:NAME=VALUE,...`` (the calibrated simulator with changes),
    ``randomized`` (the default family), a ``.json`` / ``.yaml`` file holding a ``ParamSpace`` mapping, or
    ``robot:COMMAND`` (a robot node: a target, whose samples are collected on the node).
    """
    if spec == "reality":
        return reality_domain(width, height)
    if spec == "randomized":
        return randomized_domain(width, height)
    if spec.startswith("robot:"):
        command = spec.removeprefix("robot:").strip()
        if not command:
            raise ValueError(f"{spec!r}: expected robot:COMMAND (the robot node to start)")
        return robot_domain(command, width, height)
    if spec == "proxy" or spec.startswith("proxy:"):
        changes = {}
        for item in filter(None, spec.partition(":")[2].split(",")):
            key, sep, val = item.partition("=")
            if not sep:
                raise ValueError(f"{spec!r}: expected proxy:NAME=VALUE,..., got {item!r}")
            changes[key.strip()] = _value(val.strip())
        return proxy_domain(width, height, name=spec, **changes)
    path = Path(spec)
    if path.suffix in (".json", ".yaml", ".yml") and path.exists():
        from proxybench.untrusted import load_yaml_file, read_text_file

        dists = load_yaml_file(path, max_depth=16) if path.suffix != ".json" else json.loads(read_text_file(path))
        return randomized_domain(width, height, dists, name=path.stem)
    raise ValueError(f"unknown domain {spec!r}: use reality, proxy[:NAME=VALUE,...], randomized, a family file or "
                     "robot:COMMAND")
