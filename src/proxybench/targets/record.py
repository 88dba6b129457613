"""Record a target once, re-use it in every experiment: ``proxybench target record``.

Runs each agent for the asked episodes on a live target (the reality model or a robot node) through the
runner and writes a recorded target directory::

    DIR/target.yaml                         the manifest (written first: an interrupted recording says what it is)
    DIR/episodes/<agent>/<episode>.parquet  one proxybench trajectory file per finished episode
    DIR/.record/                            the runner's episode cache while recording (removed when complete)
    DIR/logs/<agent>/<episode>/watchtowers/ with ``streams``: each episode's fixed-camera (watchtower) streams

Every finished episode is on disk at once (atomically), so an interrupted recording loses nothing: run the
same command again and it records only what is missing. Asking for more agents or episodes extends the
recording; a different map, length, seed or target is refused (a recording holds one experiment).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from proxybench import __version__
from proxybench.domain.events import Termination
from proxybench.domain.kinds import DomainKind
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import AgentSpec, Job, JobResult
from proxybench.runner.streams import StreamSpec
from proxybench.runner.sweep import run_jobs
from proxybench.targets.base import Target, episode_seed
from proxybench.targets.dtps import DtpsTarget
from proxybench.targets.manifest import (
    MANIFEST_NAME,
    SOURCE_KINDS,
    RobotInfo,
    TargetError,
    TargetManifest,
    load_manifest,
    source_of,
    write_manifest,
)
from proxybench.targets.robot import robot_said
from proxybench.targets.spec import RealityTarget

__all__ = ["RecordSummary", "record_target"]


@dataclass
class RecordSummary:
    """What a recording run did."""

    root: Path
    manifest: TargetManifest
    recorded: int  # episodes run now
    kept: int  # episodes already on disk
    failed: list[str]


def _check_label(label: str) -> None:
    p = Path(label)
    if p.is_absolute() or ".." in p.parts or not label.strip():
        raise TargetError(f"agent label {label!r} cannot name a folder of the recording; give it a plain NAME "
                          "(NAME=COMMAND for a node)")


def _source(target: Target) -> tuple[str, RobotInfo | None]:
    if isinstance(target, RealityTarget):
        return source_of(DomainKind.REALITY_MODEL), None
    if isinstance(target, DtpsTarget):
        return "dtps-robot", RobotInfo(command=target.command, kind=target.options.kind or "", dtps=target.options)
    command = getattr(target, "command", None)
    if command:
        return source_of(DomainKind.ROBOT), RobotInfo(command=command, options=getattr(target, "options", None))
    raise TargetError(f"cannot record a {target.kind} target (record the reality model, a robot node or a DTPS "
                      "robot)")


def _plan(out: Path, new: TargetManifest, agents: list[AgentSpec]) -> TargetManifest:
    """The manifest after this run: ``new``, extended by what ``out`` holds already (same experiment only)."""
    if not (out / MANIFEST_NAME).exists():
        return new
    old = load_manifest(out)
    for name in ("source", "map", "seconds", "seed", "robot", "robot.options.cwd", "trajectories", "metrics_table"):
        a, b = _field(old, name), _field(new, name)
        if name == "robot" and a is not None and b is not None:
            a, b = a.command, b.command
        if name == "robot.options.cwd" and (old.robot is None or old.robot.options is None):
            continue  # recorded before the options were kept: nothing to compare
        if a != b:
            raise TargetError(f"{out / MANIFEST_NAME}: {name}: this recording has {a!r}, the command asks for {b!r}; "
                              "record into another directory (a recording holds one experiment)")
    if old.params is not None and new.params is not None and _theta(old.params) != _theta(new.params):
        raise TargetError(f"{out / MANIFEST_NAME}: params: the target's θ differs from the recording's; record "
                          "into another directory")
    agents_all = list(old.agents) + [a for a in new.agents if a not in old.agents]
    episodes_all = sorted(set(old.episodes) | set(new.episodes))
    given = {a.label for a in agents}
    if set(episodes_all) != set(old.episodes):
        lacking = [a for a in old.agents if a not in given]
        if lacking:
            raise TargetError(f"the recording at {out} has agent(s) {', '.join(lacking)}, which need the new episodes "
                              "too: give them again with --agent")
    robot = old.robot if new.robot is None or old.robot is None else old.robot.model_copy(
        update={"options": new.robot.options, "dtps": new.robot.dtps})  # timeouts, transport, ...: as started now
    return old.model_copy(update={"agents": agents_all, "episodes": episodes_all, "robot": robot,
                                  "description": new.description or old.description,
                                  "who": new.who or old.who, "where": new.where or old.where,
                                  "when": new.when or old.when})


def _field(manifest: TargetManifest, dotted: str) -> object:
    """A manifest field by its dotted path (``robot.options.cwd``); None where a step is missing."""
    value: object = manifest
    for part in dotted.split("."):
        value = getattr(value, part, None)
    return value


def _theta(params: dict) -> object:
    """θ in a comparable form (YAML gives lists where θ has tuples)."""
    from proxybench.domain.params import DomainParams

    return DomainParams.model_validate(params)


def _place(res: JobResult, dest: Path) -> None:
    """Put a finished episode's trajectory at its final name, atomically (a hard link where possible)."""
    if res.trajectory is None:
        raise TargetError(f"episode {res.episode} of {res.agent} left no trajectory ({res.message})")
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_name(f".{dest.name}.{os.getpid()}.tmp")
    tmp.unlink(missing_ok=True)
    try:
        os.link(res.trajectory, tmp)
    except OSError:
        shutil.copyfile(res.trajectory, tmp)
    tmp.replace(dest)


def record_target(
    out: str | Path, target: Target, agents: list[AgentSpec], *, map_name: str = "loop_3x3", seconds: float = 60.0,
    episodes: int = 10, seed: int = 0, image_size: tuple[int, int] = (160, 120), description: str = "",
    who: str = "", where: str = "", when: str = "", backend: Backend | None = None,
    progress: Callable[[int, int], None] | None = None, streams: StreamSpec | None = None,
    on_streams: Callable[[JobResult, Path], None] | None = None,
) -> RecordSummary:
    """Record ``agents`` × ``episodes`` on a live ``target`` into ``out`` (resuming and extending; see module).

    ``streams``: also record these fixed cameras (a lab's watchtowers, simulated targets only) into
    ``out/logs/<agent>/<episode>/watchtowers``; ``on_streams(result, folder)`` is called for each (e.g. to add
    the watchtowers' calibrations and the run's log manifest).
    """
    from proxybench.domain.maps import MapError, load_map
    from proxybench.domain.reality import TRUTH

    out = Path(out)
    if not agents:
        raise TargetError("agents: give at least one agent to record")
    for a in agents:
        _check_label(a.label)
    try:
        load_map(map_name)
    except (MapError, FileNotFoundError) as exc:
        raise TargetError(f"map: {exc}") from None
    source, robot = _source(target)
    new_kind = SOURCE_KINDS[source]
    if streams is not None and new_kind is not DomainKind.REALITY_MODEL:
        raise TargetError("watchtowers are simulated: record them on the reality model, not on a robot node")
    dom = target.domain(image_size)  # type: ignore[attr-defined]
    truth = {k: float(v) for k, v in TRUTH.items() if isinstance(v, int | float) and not isinstance(v, bool)}
    truth.update({k: float(v) for k, v in getattr(target, "overrides", {}).items() if k in truth})
    new = TargetManifest(
        source=source, description=description, who=who, where=where, when=when,
        map=str(Path(map_name).resolve()) if Path(map_name).is_file() else map_name, seconds=seconds,
        agents=[a.label for a in agents], episodes=list(range(episodes)), seed=seed, robot=robot,
        params=dom.params.model_dump(mode="json") if new_kind is DomainKind.REALITY_MODEL else None,
        truth=truth if new_kind is DomainKind.REALITY_MODEL else None, recorded_with=f"proxybench {__version__}")
    out.mkdir(parents=True, exist_ok=True)
    manifest = _plan(out, new, agents)
    write_manifest(out, manifest)  # first: an interrupted recording still says what it is
    specs = {a.label: a for a in agents}
    seeds = {e: episode_seed(seed, e) for e in manifest.episodes}
    poses = dict(zip(seeds, target.planned_poses(manifest.map, list(seeds), list(seeds.values())), strict=True))
    todo: list[Job] = []
    dest: dict[str, Path] = {}
    kept = 0
    for label in manifest.agents:
        for e in manifest.episodes:
            path = out / manifest.trajectory_file(label, e)
            if path.is_file():
                kept += 1
                continue
            if label not in specs:
                raise TargetError(f"the recording lacks agent {label!r} episode {e}: give --agent {label} to record it")
            job = Job(specs[label], dom, manifest.map, e, seeds[e], seconds, pose=poses[e], streams=streams)
            todo.append(job)
            dest[job.key] = path
    failed: list[str] = []
    robot_failed: list[str] = []

    def keep(res: JobResult) -> None:
        if res.termination is Termination.ROBOT_FAILURE:  # no episode happened: nothing to keep, retried next time
            robot_failed.append(f"{res.agent} episode {res.episode}: {res.message}")
            return
        _place(res, dest[res.key])
        if res.streams is not None:
            folder = out / "logs" / res.agent / str(res.episode)
            _place_streams(Path(res.streams), folder / "watchtowers")
            if on_streams is not None:
                on_streams(res, folder)
        if res.termination is Termination.AGENT_FAILURE:
            failed.append(f"{res.agent} episode {res.episode}: {res.message}")

    def place(done: int, total: int, res: JobResult | None) -> None:
        if res is not None and res.key in dest:
            keep(res)
        if progress:
            progress(done, total)

    cache = out / ".record"
    sweep = run_jobs(todo, cache, backend or InlineBackend(), progress=place)
    for job, res in zip(todo, sweep.results, strict=True):  # episodes the cache held from an interrupted run
        if not dest[job.key].is_file() and res.termination is not Termination.ROBOT_FAILURE:
            keep(res)
    if robot_failed:
        shown = "\n  ".join(robot_failed[:5])
        what = getattr(target, "what", "robot node")
        raise TargetError(f"the {what} failed on {len(robot_failed)} episode(s); the others are recorded in {out}; "
                          f"run the same command again to retry:\n  {shown}")
    if source == source_of(DomainKind.ROBOT) and robot is not None and todo:
        kind, simulator = robot_said(dest[todo[0].key])
        if kind:
            update = {"kind": kind} | ({"simulator": simulator} if simulator is not None else {})
            manifest = manifest.model_copy(update={"robot": manifest.robot.model_copy(update=update)})
            write_manifest(out, manifest)
    if all((out / manifest.trajectory_file(a, e)).is_file()
           for a in manifest.agents for e in manifest.episodes):
        shutil.rmtree(cache, ignore_errors=True)
    return RecordSummary(out, manifest, sweep.ran, kept, failed)


def _place_streams(src: Path, dest: Path) -> None:
    """Copy an episode's stream folder (from the runner's cache, kept until the recording is complete) to its
    place in the recording."""
    if dest.exists():
        shutil.rmtree(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    shutil.copytree(src, dest)
