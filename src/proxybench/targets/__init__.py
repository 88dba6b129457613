"""Targets as data: what proxies are compared against (thesis: the target domain).

A target is the built-in reality model (``reality``), a directory of recorded episodes (a lab's runs, or
runs recorded with ``proxybench target record``), or a robot node (``robot:CMD``). See docs/targets.md.

- :mod:`~proxybench.targets.manifest`: the strict ``target.yaml`` of a recorded target;
- :mod:`~proxybench.targets.recorded`: reading and checking recorded episodes (trajectories or scores);
- :mod:`~proxybench.targets.spec`: the target kinds and what they give an experiment (:class:`TargetRun`);
- :mod:`~proxybench.targets.record`: recording a live target into a directory, resumably.

The names below load on first use (:mod:`proxybench.lazy`).
"""

from proxybench.lazy import lazy_exports

_FROM = {"manifest": ("TargetError", "TargetManifest", "load_manifest"),
         "recorded": ("Recording", "check_recording", "load_recording"),
         "spec": ("RealityTarget", "RecordedTarget", "Target", "TargetEpisode", "TargetInfo", "TargetRun",
                  "open_target")}
__getattr__ = lazy_exports(__name__, {n: f"{__name__}.{m}" for m, names in _FROM.items() for n in names})

__all__ = [
    "RealityTarget", "RecordedTarget", "Recording", "Target", "TargetEpisode", "TargetError", "TargetInfo",
    "TargetManifest", "TargetRun", "check_recording", "load_manifest", "load_recording", "open_target",
]
