"""Domain randomisation for Gymnasium: a new θ from a ``ParamSpace`` at every reset, seeded.

>>> import gymnasium as gym
>>> import proxybench
>>> from proxybench.domain.params import ParamSpace
>>> env = DomainRandomization(
...     gym.make("proxybench/LaneFollowing-v0", observation="state"),
...     {"trim": {"uniform": [-0.1, 0.1]}, "command_delay": {"choice": [0.0, 0.1]}})
>>> _, info = env.reset(seed=3)
>>> theta = info["params"]
>>> sorted(theta)
['command_delay', 'trim']
>>> env.reset(seed=3)[1]["params"] == theta      # the same seed, the same θ and episode
True

θ is drawn from its own stream, derived from the reset seed (``SeedSequence([seed, THETA_STREAM])``), so
``reset(seed=s)`` always gives the same θ and episode, and the resets that follow without a seed draw a
reproducible sequence. Before any seeded reset the stream comes from the wrapper's ``seed``. The episode's
θ (the drawn fields) is in ``info["params"]``, the whole ``DomainParams`` in :attr:`params`.

For many robots use it through ``gymnasium.make_vec(..., vectorization_mode="sync" | "async",
wrappers=[...])``; the batched ``vector_entry_point`` env shares one θ family per call of ``set_params``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np

from proxybench.domain.params import STRUCTURAL_FIELDS, DomainParams, ParamSpace

__all__ = ["THETA_STREAM", "DomainRandomization"]

#: spawn key of θ draws: independent of the episode's own random streams for the same seed
THETA_STREAM = 0x7E7A


class DomainRandomization(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Draw θ ~ ``space`` before each episode of a proxybench env and run the episode in it.

    ``space``: a ``ParamSpace``, or its distributions as a mapping (then built on the env's own θ, so
    the fields not randomised keep the env's values). ``seed``: the θ stream before the first seeded reset.
    """

    def __init__(self, env: gym.Env, space: ParamSpace | Mapping[str, Any], seed: int | None = None):
        gym.utils.RecordConstructorArgs.__init__(self, space=space, seed=seed)  # so env.spec can remake it
        gym.Wrapper.__init__(self, env)
        base = env.unwrapped
        if not (hasattr(base, "set_params") and isinstance(getattr(base, "params", None), DomainParams)):
            raise TypeError(f"DomainRandomization needs a proxybench env (LaneFollowingEnv), got {type(base).__name__}")
        self.space = space if isinstance(space, ParamSpace) else ParamSpace(base.params, space)
        for name in STRUCTURAL_FIELDS:  # the spaces (image size) and the frame rate cannot change
            if getattr(self.space.base, name) != getattr(base.params, name):
                raise ValueError(
                    f"the space's base has {name}={getattr(self.space.base, name)}, the env "
                    f"{getattr(base.params, name)}: build it on the env's θ, ParamSpace(env.unwrapped.params, ...)"
                )
        self._rng = np.random.default_rng(seed)
        self.params: DomainParams = base.params

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self._rng = np.random.default_rng(np.random.SeedSequence([seed, THETA_STREAM]))
        self.params = self.space.sample(self._rng)
        self.env.unwrapped.set_params(self.params)
        obs, info = self.env.reset(seed=seed, options=options)
        info["params"] = {name: getattr(self.params, name) for name in sorted(self.space.dists)}
        return obs, info
