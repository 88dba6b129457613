"""Proxy usefulness: POD, PPV, PRPV, SRCC (predicting) and PLV (teaching), and proxy optimisation."""

from proxybench.usefulness.metrics import Estimate, PairedResults, dominance, mmrv, ppv_value, prpv_value, usefulness
from proxybench.usefulness.pod import pod

__all__ = ["Estimate", "PairedResults", "dominance", "mmrv", "pod", "ppv_value", "prpv_value", "usefulness"]
