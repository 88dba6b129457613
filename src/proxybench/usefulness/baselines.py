"""What a proxy must beat to be worth running: predictors of the target's order that use no simulator.

A proxy's PRPV means little alone: a rule a researcher could write down without simulating anything
("every camera agent ties, ahead of the agents that do not look") may order the target's agents as well,
and the target's own episodes already predict themselves to within their noise. Both are turned into
*results tables* here, so that every usefulness figure and interval (:func:`~.intervals.usefulness`) scores
them exactly like a proxy:

- :func:`class_predictor`: each agent's class rank (a rule the caller states) as a constant score on every
  metric and episode: agents of a class tie, classes are ordered;
- :func:`half_split`: the target's first half of episodes per agent as the "proxy" of its second half (the
  answer of doing no simulation at all, from half the data).

>>> import numpy as np
>>> target = {"a": np.array([[3.0], [3.2]]), "b": np.array([[1.0], [1.1]])}
>>> class_predictor(target, {"a": 1, "b": 0}, (True,))["a"].tolist()
[[1.0], [1.0]]
>>> first, second = half_split(target)
>>> first["a"].tolist(), second["a"].tolist()
([[3.0]], [[3.2]])
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

__all__ = ["class_predictor", "half_split"]

Results = Mapping[str, np.ndarray]


def class_predictor(target: Results, ranks: Mapping[str, int], higher: Sequence[bool]) -> dict[str, np.ndarray]:
    """A table shaped like ``target`` whose every value is the agent's class rank (higher rank: better on every
    metric, whatever its direction), so that agents of one class tie and classes keep their order."""
    sign = np.where(np.asarray(higher, bool), 1.0, -1.0)
    return {a: np.broadcast_to(sign * float(ranks[a]), np.shape(v)).copy() for a, v in target.items()}


def half_split(target: Results) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(first half, second half) of every agent's episodes, in episode order (an odd count: the middle one
    goes to the second half). Agents with fewer than two episodes cannot be split: a ValueError names them."""
    short = [a for a, v in target.items() if len(v) < 2]
    if short:
        raise ValueError(f"a half split needs two episodes per agent; {', '.join(short)} have fewer")
    first = {a: np.asarray(v, float)[: len(v) // 2] for a, v in target.items()}
    second = {a: np.asarray(v, float)[len(v) // 2:] for a, v in target.items()}
    return first, second
