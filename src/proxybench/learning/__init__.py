"""Behaviour cloning: a learning agent trained from a privileged expert.

- ``domains``: where data comes from (a proxy θ, a randomised family Θ, the reality model, a robot node);
- ``expert``, ``dataset``: the vectorised privileged expert; NPZ shards + JSON of frames and commands;
- ``collection``, ``evaluation``: recording data (``collect``: the expert/learner mix, a batched policy, on the
  runner's auto-resetting plant) and scoring a network or the expert (``evaluate_policy``, ``evaluate_expert``);
- ``model``, ``training``, ``agent``: a PilotNet-style CNN, training / fine-tuning / checkpoints, ``BCAgent``.

Learning sits above the runner: it asks the runner's episode engine to drive robots (``runner.rollout.stream``
on a ``runner.autoreset.AutoResetPlant``; ``runner.policy_eval.score_episodes``), and the runner knows nothing of
it. The PLV arithmetic and its intervals are measures (:mod:`proxybench.usefulness.plv`,
:mod:`proxybench.usefulness.plv_intervals`); the PLV experiment, DAgger and argmax-PLV are studies
(:mod:`proxybench.experiments.plv.run`, ``dagger``, ``objective``).

Module names differ from the functions exported here (``train``), so
``from proxybench.learning import train`` is always the function, whatever was imported before.

The modules that need PyTorch (the ``learning`` extra: ``pip install 'proxybench[learning]'``) are
imported on first use, so datasets can be written and read without it. Importing anything here sets
``OMP_WAIT_POLICY=PASSIVE`` unless it is set (and PyTorch not yet imported): with busy-waiting OpenMP
threads, training on a machine whose cores are shared with other work ran ~20× slower.
"""

from __future__ import annotations

import hashlib
import importlib
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__all__ = [
    "CHECKPOINTS", "BCAgent", "CheckpointKind", "CollectConfig", "Dataset", "Domain", "EvalConfig", "ModelConfig",
    "PilotNet", "TrainConfig", "build_model", "collect", "evaluate_expert", "evaluate_policy", "expert_actions",
    "is_checkpoint", "load_checkpoint", "make_bc_agent", "parse_domain", "proxy_domain", "randomized_domain",
    "reality_domain", "robot_domain", "save_checkpoint", "train",
]

_WHERE = {
    "BCAgent": "agent", "make_bc_agent": "agent",
    "collect": "collection", "evaluate_expert": "evaluation", "evaluate_policy": "evaluation",
    "CollectConfig": "configs", "EvalConfig": "configs",
    "Dataset": "dataset",
    "Domain": "domains", "parse_domain": "domains", "proxy_domain": "domains", "randomized_domain": "domains",
    "reality_domain": "domains", "robot_domain": "domains",
    "expert_actions": "expert",
    "ModelConfig": "model", "PilotNet": "model",
    "TrainConfig": "training", "build_model": "training", "load_checkpoint": "training",
    "save_checkpoint": "training", "train": "training",
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


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


class CheckpointKind:
    """Behaviour-cloning checkpoints as an agent kind (:mod:`proxybench.agents.kinds`, entry point
    ``checkpoint``): a path ``X.pt`` with ``X.json`` beside it names a :class:`BCAgent`."""

    def claims(self, name: str) -> bool:
        return is_checkpoint(name)

    def make(self, name: str):
        from proxybench.learning.agent import make_bc_agent

        return make_bc_agent(name)

    def identity(self, name: str) -> str:
        """The content of both files, so that retraining into the same path invalidates cached episodes."""
        pt = Path(name).with_suffix(".pt")
        return _file_digest(pt) + _file_digest(pt.with_suffix(".json"))


CHECKPOINTS = CheckpointKind()


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(f"proxybench.learning.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'proxybench.learning' has no attribute {name!r}")
