"""Proxy usefulness, the thesis' measures as pure functions of paired tables: PPV, PRPV, correlations and MMRV
(predicting), POD's frame difference, PLV (teaching), their intervals and the target's noise floor.

Nothing here runs an episode: the studies (:mod:`proxybench.experiments`) ask the runner for results and
hand them to these functions.
"""

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
from proxybench.usefulness.pod import frame_difference

__all__ = ["Estimate", "PairedResults", "Usefulness", "dominance", "frame_difference", "mmrv", "ppv_agents",
           "ppv_value", "prpv_value", "target_scale", "usefulness"]
