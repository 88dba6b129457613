"""What the usefulness experiments compare proxies against: a target, of one of three kinds.

- ``reality``: the built-in reality model (:mod:`proxybench.domain.reality`), a *simulated* stand-in for a
  Duckiebot, its θ overridable;
- a **recorded** directory (:mod:`proxybench.targets.recorded`): a lab's runs, or runs recorded earlier
  with ``proxybench target record``; it costs no simulation;
- ``robot:CMD``: a robot node started with CMD (the robot protocol, docs/robot-protocol.md), its episodes
  run one after another through the runner, cached like any other episode;
- ``dtps:HOST[:PORT]/PATH``: a DTPS robot, a real Duckiebot or a Duckiematrix robot (:mod:`.dtps`,
  docs/dtps.md), likewise.

Every target gives the experiments the same thing, a :class:`TargetRun`: the episodes (agent, id, seed,
start pose) and each agent's per-episode scores. Proxies replay each agent's target episodes from the
same start poses and seeds, so proxy and target episodes are paired. :class:`TargetInfo` says plainly
what the target was, so that no report presents a simulated result as a real one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from proxybench.domain.kinds import DomainKind
from proxybench.domain.params import DomainParams
from proxybench.runner.jobs import DEFAULT_FRAME_RATE, DomainSpec
from proxybench.targets.base import Target, TargetEpisode, TargetInfo, TargetRun, episode_seed, live_run
from proxybench.targets.manifest import TargetError, TargetManifest

__all__ = ["RealityTarget", "RecordedTarget", "Target", "TargetEpisode", "TargetInfo", "TargetRun", "episode_seed",
           "open_target"]

class _LiveTarget(Target):
    """A target whose episodes the runner plays: the reality model, or a robot node."""

    def domain(self, image_size: tuple[int, int]) -> DomainSpec:
        raise NotImplementedError

    def truth(self) -> dict[str, float]:
        return {}

    def run(self, agents, *, map_name, seconds, episodes, seed, metrics, image_size, run_dir, backend=None,
            progress=None) -> TargetRun:
        run, _ = live_run(self, self.domain(image_size), agents, map_name=map_name, seconds=seconds, episodes=episodes,
                          seed=seed, metrics=metrics, run_dir=run_dir, backend=backend, progress=progress)
        run.truth = self.truth()
        return run


class RealityTarget(_LiveTarget):
    """The built-in reality model, optionally with some of its parameters changed."""

    kind = DomainKind.REALITY_MODEL

    def __init__(self, overrides: dict[str, Any] | None = None):
        from pydantic import ValidationError

        from proxybench.domain.reality import reality_params
        from proxybench.untrusted import problems

        self.overrides = dict(overrides or {})
        try:
            reality_params(**self.overrides)
        except ValidationError as exc:
            raise TargetError(problems(exc, "target_params")) from None

    def domain(self, image_size: tuple[int, int]) -> DomainSpec:
        from proxybench.domain.reality import reality_params

        w, h = image_size
        params = reality_params(**{**self.overrides, "image_width": w, "image_height": h})
        return DomainSpec("reality", params, kind=DomainKind.REALITY_MODEL)

    def truth(self) -> dict[str, float]:
        from proxybench.domain.reality import TRUTH

        out = {k: float(v) for k, v in TRUTH.items() if isinstance(v, int | float) and not isinstance(v, bool)}
        out.update({k: float(v) for k, v in self.overrides.items() if k in out})
        return out

    def info(self) -> TargetInfo:
        changed = ", ".join(f"{k}={v}" for k, v in self.overrides.items())
        return TargetInfo(
            DomainKind.REALITY_MODEL, True, "reality model (simulated)" + (f", {changed}" if changed else ""),
            "SIMULATED: the target is proxybench's reality model, a simulated stand-in for a Duckiebot with effects "
            "the proxies cannot express (wheel slip, motor dead-band, latency jitter, a lens that differs from its "
            "calibration, other light, sensor noise)" + (f", with {changed}" if changed else "") + ". No real robot "
            "was involved.", {"overrides": self.overrides})


class RecordedTarget(Target):
    """A directory of recorded episodes (see :mod:`proxybench.targets.recorded`)."""

    kind = DomainKind.RECORDED

    def __init__(self, root: str | Path):
        from proxybench.targets.manifest import load_manifest

        self.root = Path(root)
        self.manifest = load_manifest(self.root)  # fail early, before any proxy runs
        if self.root.is_file():
            self.root = self.root.parent
        self.fixed_map = self.manifest.map
        self.fixed_seconds = self.manifest.seconds
        self.fixed_agents = list(self.manifest.agents)
        self.n_episodes = len(self.manifest.episodes)

    def info(self) -> TargetInfo:
        m = self.manifest
        who = " ".join(f"{w} {x}" for w, x in (("by", m.who), ("at", m.where), ("on", m.when)) if x)
        what = {
            "real": "REAL robots (as its manifest declares)",
            "reality-model": "SIMULATED runs of proxybench's reality model (a stand-in for a Duckiebot)",
            "robot-node": (f"runs on a robot node ({m.robot.command if m.robot else '?'}"
                           + (f", which described itself as a {m.robot.kind}" if m.robot and m.robot.kind else "")
                           + (f": {m.robot.simulator.describe()}, another simulator than proxybench's"
                              if m.robot and m.robot.simulator and m.robot.kind == "simulation" else "")
                           + "); proxybench cannot tell whether a robot node is a real robot or a simulator"),
            # the source says a simulator ran it, not which: proxybench's own simulated watchtower runs
            # (run/evaluate --watchtowers, then localize) are "simulation" too ("another simulator" was wrong there)
            "simulation": "SIMULATED runs (of a simulator: proxybench's own or another; the recording does not say "
                          "which)",
            "dtps-robot": _dtps_words(m.robot),
        }[m.source]
        told = m.robot.dtps.kind if m.robot and m.robot.dtps else None
        simulated = {"real": False, "reality-model": True, "simulation": True,
                     "robot-node": True if m.robot and m.robot.kind == "simulation" else None,
                     "dtps-robot": {"real": False, "simulated": True}.get(told or "")}[m.source]
        return TargetInfo(
            DomainKind.RECORDED, simulated, f"recorded: {self.root} (source: {m.source})",
            f"The target is a recording at {self.root.resolve()} (source: {m.source}): {what}"
            + (f"; recorded {who}" if who else "") + (f". {m.description}" if m.description else "") + ".",
            {"root": str(self.root.resolve()), "source": m.source, "who": m.who, "where": m.where, "when": m.when,
             "kind": m.kind, "robot": m.robot.model_dump() if m.robot else None})

    def run(self, agents, *, map_name, seconds, episodes, seed, metrics, image_size, run_dir, backend=None,
            progress=None) -> TargetRun:
        from proxybench.targets.recorded import load_recording, resolve_map

        rec = load_recording(self.root, metrics)
        chosen = rec.select([a.label for a in agents], episodes)
        if progress:
            progress("target episodes (recorded)", len(chosen), len(chosen))
        eps = [TargetEpisode(e.agent, e.episode, e.seed, e.pose) for e in chosen]
        results: dict[str, list[list[float]]] = {}
        for e in chosen:
            results.setdefault(e.agent, []).append([e.scores[m] for m in metrics])
        m = self.manifest
        params = _recorded_theta(m) if m.domain_kind is DomainKind.REALITY_MODEL else None
        return TargetRun(self.info(), resolve_map(self.root, m.map), m.seconds, metrics, eps,
                         {a: np.asarray(v, dtype=float) for a, v in results.items()}, dict(m.truth or {}), params, 0,
                         {(e.agent, e.episode): e.file for e in chosen if e.file})


def _dtps_words(robot: Any) -> str:
    """What a DTPS robot's recording says it was (what the user said it is, else that proxybench cannot tell)."""
    if robot is None or robot.dtps is None:
        return "runs on a DTPS robot; proxybench cannot tell a Duckiematrix robot from a real one"
    from proxybench.targets.dtps import describe_robot

    return "runs on " + describe_robot(robot.command.removeprefix("dtps:"), robot.dtps)[1]


def _recorded_theta(m: TargetManifest) -> DomainParams | None:
    """θ a recording of the reality model says it ran with, where it is a θ of this version (a recording made
    by a version whose θ had other fields keeps its θ in the manifest only, for the record; none is used)."""
    from pydantic import ValidationError

    try:
        return None if m.params is None else DomainParams.model_validate(m.params)
    except ValidationError:
        return None


def open_target(text: str, *, params: dict[str, Any] | None = None, robot_nodes: int = 1,
                robot_options: Any = None, frame_rate: float = DEFAULT_FRAME_RATE, dtps_options: Any = None) -> Target:
    """The target ``text`` names: ``reality``, ``robot:CMD``, ``dtps:HOST[:PORT]/PATH`` or a directory (or manifest
    file) of recordings.

    ``params``: θ overrides of the reality model (only with ``reality``); ``robot_nodes``: how many processes
    of a robot node may run at once, ``robot_options``: how to start and talk to it (a
    :class:`~proxybench.protocol.options.RobotNodeOptions`; both only with ``robot:``); ``dtps_options``: how to
    drive a DTPS robot (a :class:`~proxybench.dtps.robot_options.DtpsRobotOptions`; only with ``dtps:``);
    ``frame_rate`` [Hz]: the proxies' camera rate, at which a robot is driven.
    """
    text = text.strip()
    if params and text != "reality":
        raise TargetError("target_params: only the reality model's parameters can be overridden "
                          f"(the target is {text!r})")
    if robot_options is not None and robot_options.non_default() and not text.startswith("robot:"):
        raise TargetError(f"robot_options (--robot-cwd, --robot-transport, ...): only a robot node (robot:COMMAND) is "
                          f"started with them; the target is {text!r}")
    if dtps_options is not None and dtps_options.non_default() and not text.startswith("dtps:"):
        raise TargetError(f"dtps_options (--dtps-reset, --dtps-pose, ...): only a DTPS robot (dtps:HOST/PATH) is "
                          f"driven with them; the target is {text!r}")
    if text == "reality":
        return RealityTarget(params)
    if text.startswith("dtps:"):
        from proxybench.targets.dtps import DtpsTarget

        return DtpsTarget(text, dtps_options, frame_rate)
    if text.startswith("robot:"):
        from proxybench.targets.robot import RobotTarget

        command = text.removeprefix("robot:").strip()
        if not command:
            raise TargetError("target: robot: needs the command that starts the robot node, e.g. "
                              "'robot:proxybench robot serve --param trim=0.1'")
        return RobotTarget(command, robot_nodes, robot_options, frame_rate)
    if Path(text).exists():
        return RecordedTarget(text)
    raise TargetError(f"target: {text!r} is not 'reality', 'robot:COMMAND', 'dtps:HOST[:PORT]/PATH' or an existing "
                      "directory of recordings")
