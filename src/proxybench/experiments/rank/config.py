"""What ``proxybench rank`` is told: the experiment file, the level, the proxy θ and the sequential budget."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, field_validator

from proxybench.experiments.config import ConfigError, ExperimentConfig
from proxybench.experiments.study import Cli

__all__ = ["RankConfig", "proxy_theta"]


class RankConfig(ExperimentConfig):
    """The experiment file, and how the ranking decides."""

    alpha: float = Field(0.05, gt=0.0, lt=1.0)
    """the chance that any decision is wrong, at most (family-wise over every pair and metric)"""
    param: Annotated[dict[str, Any], Cli("--param", metavar="NAME=VALUE")] = Field(default_factory=dict)
    """the proxy's θ on top of the nominal calibration (repeat for more parameters)"""
    proxy_from: Path | None = None
    """an `optimize` run's summary.json: its recovered θ (the tied set's median) is the proxy's"""
    proxy_episodes: int | None = Field(None, ge=0, le=1_000_000)
    """proxy-only episodes per agent (besides replaying the target's); 0: the target alone"""
    tolerance: Annotated[dict[str, float], Cli("--tolerance", default="AIDO's semiorder tolerances scaled to the "
                                               "episode length")] = Field(default_factory=dict)
    """ε of a metric: pairs within it are ties (NAME=0: strict order)"""
    sequential: bool = False
    """anytime-valid: run target episodes one at a time where they settle most, stop when every pair is decided
    (live targets; a recorded one is replayed in that order)"""
    budget: int | None = Field(None, ge=1, le=1_000_000)
    """sequential: target episodes it may run after the pilot (--episodes per agent)"""

    @field_validator("proxy_from")
    @classmethod
    def _summary(cls, v: Path | None) -> Path | None:
        if v is not None and not Path(v).is_file():
            raise ValueError(f"{str(v)!r} is not a file (an optimize run's summary.json)")
        return v

    @field_validator("tolerance")
    @classmethod
    def _tolerances(cls, v: dict[str, float]) -> dict[str, float]:
        bad = [k for k, x in v.items() if not (math.isfinite(x) and x >= 0)]
        if bad:
            raise ValueError(f"{', '.join(bad)}: a tolerance is a number >= 0")
        return v


def proxy_theta(cfg: RankConfig) -> tuple[dict[str, Any], str]:
    """The proxy's θ on top of the nominal and where it came from (``--param`` wins over ``--proxy-from``)."""
    if cfg.param or cfg.proxy_from is None:
        return dict(cfg.param), "--param" if cfg.param else "the nominal calibration"
    try:
        summary = json.loads(Path(cfg.proxy_from).read_text())
        theta = summary.get("recovered") or summary["best_params"]
    except (OSError, ValueError, KeyError, AttributeError) as exc:
        raise ConfigError(f"proxy_from: {cfg.proxy_from}: not an optimize summary.json ({type(exc).__name__}: "
                          f"{exc})") from None
    if not isinstance(theta, dict) or not all(isinstance(v, int | float) for v in theta.values()):
        raise ConfigError(f"proxy_from: {cfg.proxy_from}: its 'recovered' θ is not a mapping of numbers")
    return dict(theta), f"the recovered θ of {cfg.proxy_from}"
