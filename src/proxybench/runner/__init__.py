"""Running agents in domains: episodes → trajectories.

The names below load on first use (:mod:`proxybench.lazy`): importing a light module of the runner (``jobs``, a
config's seam type) must not load the agent zoo and its compiled kernels, so ``--help`` stays quick.
"""

from proxybench.lazy import lazy_exports

__getattr__ = lazy_exports(__name__, {"PrivilegedAgentError": "proxybench.runner.episode",
                                      "run_episode": "proxybench.runner.episode"})

__all__ = ["PrivilegedAgentError", "run_episode"]
