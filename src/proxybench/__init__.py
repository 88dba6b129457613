"""proxybench: develop, benchmark and measure the usefulness of simulators for Duckietown-style agents.

Importing the package registers the Gymnasium env ``proxybench/LaneFollowing-v0``.
"""

from gymnasium.envs.registration import register, registry

__version__ = "0.1.0"

if "proxybench/LaneFollowing-v0" not in registry:
    register(
        id="proxybench/LaneFollowing-v0",
        entry_point="proxybench.domain.env:LaneFollowingEnv",
        vector_entry_point="proxybench.domain.env:LaneFollowingVectorEnv",
    )
