"""Proxy usefulness: POD, PPV, PRPV, correlations and MMRV (predicting), PLV (teaching), proxy optimisation."""

from proxybench.usefulness.intervals import Usefulness, usefulness
from proxybench.usefulness.metrics import (
    Estimate,
    PairedResults,
    dominance,
    mmrv,
    ppv_agents,
    ppv_value,
    prpv_value,
    target_scale,
)
from proxybench.usefulness.pod import pod

__all__ = ["Estimate", "PairedResults", "Usefulness", "dominance", "mmrv", "pod", "ppv_agents", "ppv_value",
           "prpv_value", "target_scale", "usefulness"]
