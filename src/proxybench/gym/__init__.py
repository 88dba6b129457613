"""gym-duckietown as a target: an independent simulator behind proxybench's robot protocol.

- :mod:`~proxybench.gym.environment`: gym's own virtual environment (``proxybench gym setup`` / ``check``);
- :mod:`~proxybench.gym.params`: its parameters θ under gym's own names, checked; hidden θ and its hash;
- :mod:`~proxybench.gym.backend`: :class:`GymRobot`, the robot node's backend (``proxybench gym serve``);
- ``bridge.py``: the script gym's interpreter runs (never imported here: its numpy is not proxybench's).

See docs/targets.md, "Another simulator as your target".
"""
