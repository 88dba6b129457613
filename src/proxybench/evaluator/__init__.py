"""Evaluators: workers that lease jobs from a challenges server, run them sandboxed, and upload results.

- :mod:`.loop`: :class:`Evaluator` — lease, heartbeat, run the job in a worker process, upload, repeat;
- :mod:`.run`: the worker — agent, validation and hidden test episodes, checks, report, outcome status;
- :mod:`.sandbox`: agent packages unpacked and started without network, root, or unbounded resources;
- :mod:`.report`: scores, per-episode report, data checks, trajectory archive and video;
- :mod:`.compliance`: the check a target (the reality model, or a robot node) passes before a target job.

``PROXYBENCH_TOKEN=… proxybench evaluator --server URL`` (or ``--token-file F``) runs one; see docs/evaluator.md.
"""

from proxybench.evaluator.loop import Evaluator, EvaluatorConfig, Reporter
from proxybench.evaluator.sandbox import Isolation, Limits, detect_isolation

__all__ = ["Evaluator", "EvaluatorConfig", "Isolation", "Limits", "Reporter", "detect_isolation"]
