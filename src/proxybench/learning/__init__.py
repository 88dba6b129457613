"""Learning agents and the proxy learning value (PLV): behaviour cloning from a privileged expert.

- ``domains``: where data comes from (a proxy θ, a randomised family Θ, the reality model);
- ``expert``, ``collection``, ``dataset``: batched expert driving with recovery data, NPZ shards + JSON;
- ``model``, ``training``, ``agent``: a PilotNet-style CNN, training / fine-tuning / checkpoints, ``BCAgent``;
- ``onpolicy``: DAgger, on-policy target samples labelled by the expert;
- ``evaluate``, ``value``, ``intervals``, ``experiment``, ``report``: PLV arithmetic, its bootstrap intervals over
  seeds and the PLV experiment (thesis Table 3.1, Figure 3.6); ``objective``: PLV of one proxy, for argmax-PLV.

Module names differ from the functions exported here (``collect``, ``train``, ``dagger``, ``plv``), so
``from proxybench.learning import train`` is always the function, whatever was imported before.

The modules that need PyTorch (the ``learning`` extra: ``pip install 'proxybench[learning]'``) are
imported on first use, so datasets can be written and read without it. Importing anything here sets
``OMP_WAIT_POLICY=PASSIVE`` unless it is set (and PyTorch not yet imported): with busy-waiting OpenMP
threads, training on a machine whose cores are shared with other work ran ~20× slower.
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__all__ = [
    "BCAgent", "CollectConfig", "DaggerConfig", "DataCost", "Dataset", "Domain", "EvalConfig", "ModelConfig",
    "PLVConfig", "PLVObjective", "PLVResult", "PilotNet", "TrainConfig", "build_model", "collect", "dagger",
    "evaluate_expert", "evaluate_policy", "expert_actions", "is_checkpoint", "load_checkpoint", "make_bc_agent",
    "parse_domain", "plv", "proxy_domain", "randomized_domain", "reality_domain", "run_plv", "save_checkpoint",
    "train", "write_report",
]

_WHERE = {
    "BCAgent": "agent", "make_bc_agent": "agent",
    "CollectConfig": "collection", "collect": "collection",
    "DaggerConfig": "onpolicy", "dagger": "onpolicy",
    "DataCost": "value", "plv": "value",
    "Dataset": "dataset",
    "Domain": "domains", "parse_domain": "domains", "proxy_domain": "domains", "randomized_domain": "domains",
    "reality_domain": "domains",
    "EvalConfig": "evaluate", "evaluate_expert": "evaluate", "evaluate_policy": "evaluate",
    "expert_actions": "expert",
    "ModelConfig": "model", "PilotNet": "model",
    "PLVConfig": "experiment", "PLVResult": "experiment", "run_plv": "experiment",
    "PLVObjective": "objective",
    "TrainConfig": "training", "build_model": "training", "load_checkpoint": "training",
    "save_checkpoint": "training", "train": "training",
    "write_report": "report",
}


def is_checkpoint(name: str | Path) -> bool:
    """Whether ``name`` is a path to a BC checkpoint (``X.pt`` with ``X.json`` beside it); needs no PyTorch.

    The agent zoo and the command line use it to accept a checkpoint wherever an agent name is taken.
    """
    p = Path(name)
    if p.suffix not in (".pt", ""):
        return False
    p = p.with_suffix(".pt")
    return p.is_file() and p.with_suffix(".json").is_file()


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(f"proxybench.learning.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'proxybench.learning' has no attribute {name!r}")
