"""An Autolab's job (``proxybench evaluator --autolab lab.yaml``): the robot is measured by the watchtowers.

For each split of a leased job the worker runs the benchmark's episodes on the lab's robot while the lab's
watchtowers record, then per episode:

1. **localise** the robot from the watchtower streams (:func:`proxybench.autolab.localize.localize_log`: the
   same detection and pose graph as ``proxybench localize``), each frame detected online as it arrived while the
   episode ran (:mod:`proxybench.autolab.online`: a bounded queue, drops counted, the lag logged every few
   seconds), so that only the pose graph is left;
2. **validate** the run (the DTA's rules, :func:`proxybench.autolab.validate.validate_run`, with the lab's
   limits): a robot the watchtowers lost is ``tracking_lost``, any other invalid run ``invalid``; either makes
   the job the lab's fault (``host-error``, queued again for another try), with the reason;
3. **score** from the *localised* trajectory (its lane pose recomputed from the map, as for any recorded run),
   never from the pose the robot reports; the robot's own record is kept beside it, and where it is the
   simulator's truth (a virtual robot) each episode reports the localisation's error against it.

Today a lab's robot is a **virtual** DB21J (the simulator; an SDK agent reaches it over DTPS as on the
Duckiematrix) and its watchtowers are **simulated** from a layout (their frames written by the simulator, or served
as DTPS camera topics and read back, ``serve: dtps``) or a lab's own **DTPS camera topics** (``streams``), read by
the lab's watchtower reader (:mod:`proxybench.autolab.live`). A lab's **DTPS robot** is driven by the agent and
watched (:mod:`.autolab_dtps`), a **robot node** (``command:``) stepped by the runner and watched
(:mod:`.autolab_node`), both measured by the lab's own streams; recorded streams are described by ``lab.yaml`` but
refused here (``host-error``, saying so). A lab of several virtual
robots runs a job on each at once (the evaluator's :mod:`.robots` gives each job its robot); with ``world: shared``
they drive one world (:mod:`.lab_world`: they see and can hit each other, each localised under its own roof tag, a
run another robot ran into invalid), else each robot is the ego of a world of its own, seen by the watchtowers under
the simulator's ego roof tag (400), which localisation names after the job's robot.

The worker's :class:`~proxybench.evaluator.run._Job` is passed in (duck-typed: this module does not import
``run``): its benchmark, agent, agent contract, progress and outcome are reused as they are.
"""

from __future__ import annotations

import logging
import shutil
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.autolab.lab import Lab
from proxybench.autolab.online import Lag
from proxybench.evaluator.autolab_attempts import attempt_name, pack_attempts, retry_invalid, unfit
from proxybench.evaluator.outcome import Artifact, HostFault, Outcome, SubmissionFault

__all__ = ["AutolabEpisode", "localize_episode", "run_autolab", "stop_streams", "world_tags"]

log = logging.getLogger("proxybench.evaluator.job")
#: the Autolab's job feature: a benchmark stored with it is leased only by Autolab evaluators
FEATURE = "autolab"


@dataclass
class AutolabEpisode:
    """One episode as the lab measured it: the localised trajectory file, its scores, the DTA's verdict, and,
    where the robot's record is the truth (virtual robots), the localisation's error against it."""

    episode: int
    trajectory: Path | None
    scores: dict[str, float]
    valid: bool
    reasons: list[str]
    lost: bool
    samples: int
    frames: int
    error_median_m: float | None = None
    error_p95_m: float | None = None
    files: list[Path] = field(default_factory=list)
    online: dict[str, Any] | None = None  # what the online detection did (autolab.online), None: detected offline
    seen: list[str] = field(default_factory=list)  # the lab's robots the watchtowers localised (a shared world: all)
    attempt: int = 1  # 1: the episode's first run; 2, …: run again because the one before was invalid
    robot_record: str | None = None  # the robot's own trajectory of this attempt
    earlier: list[AutolabEpisode] = field(default_factory=list)  # the invalid attempts before this one, in order

    @property
    def fit(self) -> bool:
        """Whether it can be scored: valid, and localised at least twice."""
        return self.valid and self.trajectory is not None

    @property
    def verdict(self) -> str:
        """``valid``, ``tracking_lost`` (the watchtowers lost the robot) or ``invalid`` (another DTA rule)."""
        return "valid" if self.fit else "tracking_lost" if self.lost or self.trajectory is None else "invalid"

    def why(self) -> str:
        """Why it is not fit to be scored, in one line."""
        return "; ".join(self.reasons) or "the watchtowers localised the robot fewer than twice"

    def attempt_report(self) -> dict[str, Any]:
        """This attempt in the report's ``attempts``: its number, the DTA's verdict and why."""
        return {"attempt": self.attempt, "verdict": self.verdict, "reasons": [] if self.fit else [self.why()],
                "samples": self.samples, "frames": self.frames}

    def report(self) -> dict[str, Any]:
        from proxybench.evaluator.report import clean

        return {"episode": self.episode, "valid": self.valid, "reasons": self.reasons, "samples": self.samples,
                "frames": self.frames, "scores": {k: clean(v) for k, v in self.scores.items()},
                "localization_median_error_m": clean(self.error_median_m),
                "localization_p95_error_m": clean(self.error_p95_m), "online_detection": self.online,
                "robots_localised": self.seen, "attempt": self.attempt,
                "attempts": [e.attempt_report() for e in [*self.earlier, self]]}


def _check_lab(lab: Lab, bench, robot_name: str | None = None) -> None:
    """What this evaluator can do with this lab, its robot ``robot_name`` (None: the first) and the benchmark;
    :class:`HostFault` saying what it cannot."""
    lab.robot(robot_name)  # a robot the lab lacks: KeyError naming it
    recorded = [s.name for s in lab.watchtowers.streams if s.recorded is not None]
    if recorded:
        raise HostFault(f"lab {lab.name!r}: watchtower(s) {', '.join(recorded)} are recorded folders (for `proxybench "
                        "localize`); a job records its watchtowers live: give them as dtps: HOST[:PORT]/PATH")
    if bench.map != lab.map:
        raise HostFault(f"benchmark {bench.name!r} is on map {bench.map!r}; lab {lab.name!r} has map {lab.map!r}")
    if bench.duration > lab.limits.max_episode_s:
        raise HostFault(f"benchmark {bench.name!r}: episodes of {bench.duration:g} s are longer than lab "
                        f"{lab.name!r} runs (limits.max_episode_s {lab.limits.max_episode_s:g} s)")
    if bench.traffic() is not None and not bench.traffic().empty:
        raise HostFault(f"benchmark {bench.name!r} has npcs:, which lab {lab.name!r} does not have")


def _with_reset(bench, lab: Lab):
    """The benchmark with its start poses from the lab's pose file (``reset.mode: pose_file``), else as it is
    (teleport: the virtual robot is put at the benchmark's starts)."""
    if lab.reset.mode != "pose_file" or lab.reset.poses is None:
        return bench
    from proxybench.dtps.robot_options import load_start_poses

    specs = bench.episode_specs()
    try:
        poses = load_start_poses(lab.reset.poses, [s.index for s in specs])
    except ValueError as exc:
        raise HostFault(f"lab {lab.name!r}: reset.poses: {exc}") from None
    episodes = bench.episodes.model_copy(update={"poses": [list(poses[s.index]) for s in specs],
                                                 "seeds": [s.seed for s in specs], "count": None})
    return bench.model_copy(update={"episodes": episodes})


def _errors(truth, t: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Position error [m] of each localised sample against the robot's record, interpolated at its time."""
    tt = truth["t"]
    x = np.interp(t, tt, truth["x"])
    y = np.interp(t, tt, truth["y"])
    return np.hypot(pose[:, 0] - x, pose[:, 1] - y)


def stop_streams(streams: Path, lab: Lab, attempt: int = 1) -> list[str]:
    """The lab's drill (``drills.streams_stop_s``): the named watchtowers' recordings (default all) end at that
    episode time, their later frames gone, as a camera whose stream stopped; the watchtowers stopped. ``attempt``:
    which run of the episode this is (``drills.streams_stop_attempts`` may spare the later ones)."""
    import csv

    at = lab.drills.streams_stop_s
    if at is None or not lab.drills.stops_streams(attempt):
        return []
    names = lab.drills.streams_stop or sorted(p.name for p in streams.iterdir() if p.is_dir())
    for name in names:
        stamps = streams / name / "timestamps.csv"
        if not stamps.is_file():  # a lab's own stream that delivered nothing in the episode: nothing to stop
            continue
        with open(stamps, newline="") as fh:
            reader = csv.DictReader(fh)
            rows = list(reader)
            columns = reader.fieldnames or ["frame", "t"]  # a lab's own streams also say each frame's stamp
        kept = [r for r in rows if float(r["t"]) <= at]
        for r in rows[len(kept):]:
            for frame in (streams / name).glob(f"{int(r['frame']):06d}.*"):
                frame.unlink()
        with open(stamps, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=columns)
            w.writeheader()
            w.writerows(kept)
    log.warning("drill: watchtower stream(s) %s stopped at t = %g s", ", ".join(names), at)
    return names


def world_tags(robot: str) -> dict[int, str]:
    """Roof tag id -> robot name in the world of the virtual robot ``robot`` when the lab's robots do not share a
    world (``world: own``): each is the ego of its own and wears the simulator's ego tag."""
    from proxybench.domain.apriltags import ROOF_TAG_BASE

    return {ROOF_TAG_BASE: robot}


def localize_episode(res, bench, lab: Lab, layout, m, folder: Path, metrics,
                     robot: str | None = None, online=None, attempt: int = 1) -> AutolabEpisode:
    """One episode's streams → log → localised, validated and scored (see the module); ``robot``: the lab's robot
    that drove it (None: the first); ``online``: the episode's frames as detected while it ran
    (:class:`~proxybench.autolab.online.OnlineEpisode`: only the pose graph is left; None: detected here);
    ``attempt``: which run of the episode this is (1: the first; an invalid one is run again, ``invalid_retries``)."""
    from proxybench.autolab.localize import localize_log
    from proxybench.autolab.logs import LogManifest, read_log, write_sim_log
    from proxybench.autolab.target import track_table
    from proxybench.autolab.validate import validate_run
    from proxybench.domain.events import Event, Termination
    from proxybench.tasks.trajectory import Trajectory

    robot = lab.robot(robot).name
    folder.mkdir(parents=True, exist_ok=True)
    if res.streams is None or not Path(res.streams).is_dir():
        raise HostFault(f"episode {res.episode}: the watchtowers recorded nothing (no streams)")
    truth = Trajectory.load(res.trajectory) if res.trajectory else None
    ended = None if res.termination is Termination.TIMEOUT else str(res.termination)
    shutil.copytree(res.streams, folder / "streams")
    stop_streams(folder / "streams", lab, attempt)
    manifest = LogManifest(source="simulation", map=bench.map, agent="agent", episode=res.episode,
                           seconds=bench.duration, termination=ended, active=robot,
                           robots=lab.roof_tags() if lab.world == "shared" else world_tags(robot))
    if not any(p.is_dir() for p in (folder / "streams").iterdir()):
        raise HostFault(f"tracking_lost: episode {res.episode}: no watchtower delivered a frame")
    if layout is None:  # a lab's own streams, read over DTPS: its calibration files, its ground tags
        from proxybench.autolab.live import write_stream_log

        write_stream_log(folder, lab, folder / "streams", manifest)
    else:
        write_sim_log(folder, layout, folder / "streams", manifest)
    run_log = read_log(folder)
    frames = online.frames_for(run_log) if online is not None else None  # the log's frames, drills applied
    loc = localize_log(run_log, m, workers=1, decimate=2.0, frames=frames)
    verdict = validate_run(run_log, loc, lab.limits.thresholds())
    track = loc.robots.get(robot)
    lost = any("lost" in r or "never localised" in r for r in verdict.reasons)
    episode = AutolabEpisode(res.episode, None, {}, verdict.valid, list(verdict.reasons), lost,
                             0 if track is None else int(track.t.size), loc.frames,
                             online=online.report() if online is not None else None, seen=sorted(loc.robots),
                             attempt=attempt, robot_record=res.trajectory or None)
    if track is None or track.t.size < 2:
        return episode
    import pandas as pd

    cols = track_table(track, run_log.manifest.start)
    pd.DataFrame(cols).to_csv(folder / "track.csv", index=False, float_format="%.6g")
    t, pose = cols["t"], track.pose
    events = [] if verdict.valid else [Event(float(t[-1]), "tracking_lost" if lost else "invalid",
                                             "; ".join(verdict.reasons))]
    # a valid run that ended by time ran the whole episode, though its last sighting is a frame inside it
    meta = {**(truth.meta if truth is not None else {}), "source": "autolab", "measured_by": "watchtowers",
            "lab": lab.name, "robot": robot, "episode_seconds": bench.duration,
            "ran_whole_episode": verdict.valid and res.termination is Termination.TIMEOUT}
    meta.pop("timing", None)
    localized = Trajectory.from_poses(m, t, pose, meta=meta, events=[*(truth.events if truth else []), *events],
                                      termination=res.termination, origin=str(folder / "track.csv"))
    episode.trajectory = localized.save(folder / "localized.parquet")
    episode.scores = {name: float(metrics[name](localized)) for name in bench.metrics}
    episode.files = [folder / "localized.parquet", folder / "track.csv"]
    if truth is not None:
        err = _errors(truth, t, pose)
        pd.DataFrame({"t": t, "error_m": err, "sigma_x": track.sigma[:, 0], "sigma_y": track.sigma[:, 1],
                      "views": track.views}).to_csv(folder / "errors.csv", index=False, float_format="%.6g")
        episode.files.append(folder / "errors.csv")
        episode.error_median_m, episode.error_p95_m = float(np.median(err)), float(np.percentile(err, 95))
    return episode


def _log_lag(split: str, lag: Lag) -> None:
    """The live view of the online localisation (every few seconds while episodes run): how far behind it is."""
    log.info("%s: localisation %d frames behind (%.1f s of episode), %d detected, %d dropped so far", split,
             lag.queued, lag.behind_s, lag.detected, lag.dropped)


def _scores(episodes: list[AutolabEpisode], bench) -> dict[str, float | None]:
    """The benchmark's aggregated columns (``<metric>_<stat>``) over the localised episodes' scores."""
    import pandas as pd

    from proxybench.evaluator.report import clean
    from proxybench.tasks.aggregate import aggregate, scores_by_agent

    rows = [{"agent": "agent", "domain": "autolab", "episode": e.episode, "metric": k, "value": v}
            for e in episodes for k, v in e.scores.items()]
    agg = aggregate(pd.DataFrame(rows, columns=["agent", "domain", "episode", "metric", "value"]), n_resamples=1000)
    raw = next(iter(scores_by_agent(agg).values()), {}) if len(agg) else {}
    scores = {k: clean(v) for k, v in raw.items()}
    for c in bench.criteria():
        scores.setdefault(c.metric, None)
    return scores


def _pack(path: Path, ev, episodes: list[AutolabEpisode]) -> Path:
    """``episode-<k>.parquet`` (localised: what was scored), ``episode-<k>-track.csv`` (with σ and views),
    ``episode-<k>-errors.csv`` (against the robot's record) and ``robot-episode-<k>.parquet`` (the robot's own);
    an episode run again because it was invalid keeps each attempt before the last under
    ``episode-<k>-attempt-<a>…`` and ``robot-episode-<k>-attempt-<a>.parquet``, and ``attempts.json`` lists every
    attempt of every episode (number, verdict, reasons)."""
    by_ep = {r.episode: r for r in ev.sweep.results}
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for e in episodes:
            for f in e.files:
                inner = "" if f.suffix == ".parquet" else f"-{f.stem}"
                zf.write(f, f"episode-{e.episode}{inner}{f.suffix}")
            r = by_ep.get(e.episode)
            if r is not None and r.trajectory and Path(r.trajectory).is_file():
                zf.write(r.trajectory, f"robot-episode-{e.episode}.parquet")
        pack_attempts(zf, episodes)
    return path


@dataclass
class _Driven:
    """One run of a split's episodes on the robot (all of them, or the invalid ones again): the split's evaluation
    (a re-run's results put in place of the attempts before), the robot's record of it, this run's episodes as the
    watchtowers measured them, what the DTPS reader received (None: no reader) and how many watchtowers watched."""

    ev: Any
    record: Any
    episodes: list[AutolabEpisode]
    streams: list[dict[str, Any]] | None
    towers: int


def _drive(job, lab: Lab, bench, spec, split: str, hidden: bool, attempt: int = 1,
           only: set[int] | None = None, base=None) -> _Driven:
    """Episodes on the lab's robot with its watchtowers recording, each localised and validated (the module):
    every episode of ``bench``, or with ``only`` those again (``attempt`` 2, …: the run of each before was invalid,
    :func:`_retry_invalid`), their results put into ``base``, the split's evaluation so far."""
    from proxybench.autolab.calibration import stream_spec
    from proxybench.autolab.live import live_streams
    from proxybench.autolab.online import OnlineDetector
    from proxybench.domain.maps import load_map
    from proxybench.dtps.cameras import ReaderError
    from proxybench.evaluator.lab_world import contact_invalid, episode_streams, shared_domain
    from proxybench.evaluator.report import summarize
    from proxybench.protocol.failures import AgentFailure
    from proxybench.runner.backends import InlineBackend
    from proxybench.runner.episode import PrivilegedAgentError
    from proxybench.runner.evaluate import evaluate_benchmark, with_reruns
    from proxybench.runner.jobs import is_privileged
    from proxybench.tasks.metrics import METRICS

    job.phase = split if attempt == 1 else f"{split} attempt {attempt}"
    runs = job.dir / "runs" / (split if attempt == 1 else f"{split}-attempt-{attempt}")
    m = load_map(bench.map)
    layout = lab.layout(m) if lab.watchtowers.layout is not None else None
    # each frame detected as it arrives (autolab.online): after an episode only its pose graph is left
    online = OnlineDetector(decimate=2.0, report=lambda lag: _log_lag(split, lag))
    try:  # watchtowers read over DTPS (served simulated ones, or the lab's own): autolab.live
        live = live_streams(lab, layout, online)
    except ReaderError as exc:
        raise HostFault(f"watchtowers: {exc}") from None
    streams = live.spec if live is not None else replace(stream_spec(layout), observer=online)
    towers = len(live.names) if live is not None else len(layout.watchtowers)
    robot = lab.robot(job.job.autolab_robot)
    world = job.job.lab_world  # world: shared: the episodes run in the lab's one world, which records the towers
    domain = None if world is None else shared_domain(world, robot.name, bench, runs / "towers")
    log.info("%s: %d episodes of %g s on lab %r's robot %r (virtual), %d watchtowers recording%s%s", split,
             len(bench.episode_specs()) if only is None else len(only), bench.duration, lab.name, robot.name, towers,
             "" if live is None else " over DTPS", "" if attempt == 1 else f"; attempt {attempt}")
    try:
        ev = evaluate_benchmark(bench, [spec], runs, InlineBackend(),
                                streams=streams if world is None else None, domain=domain,
                                privileged=is_privileged, progress=job.progress, episodes=only)
    except ReaderError as exc:
        raise HostFault(f"watchtowers: {exc}") from None
    except AgentFailure as exc:
        job.check_sandbox([exc.stderr_tail])
        raise SubmissionFault(f"agent node failed in the {split} episodes: {exc}") from None
    except PrivilegedAgentError as exc:
        raise SubmissionFault(str(exc)) from None
    finally:
        if live is not None:
            live.close()
        online.close()  # the worker detects what is queued, then ends
    from proxybench.domain.events import Termination

    failed = [r for r in ev.sweep.results if r.termination is Termination.ROBOT_FAILURE]
    if failed:
        raise HostFault(f"robot_failure: lab {lab.name!r}'s robot {robot.name!r} failed in {split} episode "
                        f"{failed[0].episode}: {failed[0].message}")
    hit: dict[int, str] = {}  # the shared world's collision rule: a robot another ran into ran an invalid episode
    if world is not None:
        ev.sweep.results = [episode_streams(r) for r in ev.sweep.results]
        hit = {r.episode: why for r in ev.sweep.results if (why := contact_invalid(r))}
    ran = ev  # this run's episodes; the split's evaluation holds the earlier attempts' valid ones beside them
    ev = ev if base is None else with_reruns(base, ev)
    record = summarize(ev, split, domain_kind="autolab/virtual")
    dead = [f for f in record.failures if str(f.get("message", "")).startswith("RobotFailure:")]
    if dead:  # the robot's DTPS endpoint died under the agent: the lab's fault, whatever the agent did after
        raise HostFault(f"robot_failure: lab {lab.name!r}'s robot {robot.name!r} failed in {split} episode "
                        f"{dead[0].get('episode')}: {str(dead[0]['message']).removeprefix('RobotFailure: ')}")
    if record.problems:  # the virtual robot is our simulator: its record must be whole
        raise RuntimeError(f"invalid {split} data from the virtual robot: " + "; ".join(record.problems[:5]))
    if record.failures:
        job.check_sandbox([f.get("stderr_tail") or [] for f in record.failures])
        if hidden:
            raise SubmissionFault(f"the agent failed in {len(record.failures)} hidden test episodes (details are "
                                  "shown to the operators only)")
        raise SubmissionFault(record.failure_message())
    job.phase = f"{split} localisation"
    episodes = []
    for k, res in enumerate(sorted(ran.sweep.results, key=lambda r: r.episode)):
        folder = job.dir / "autolab" / split / attempt_name(res.episode, attempt)  # every attempt kept
        episodes.append(localize_episode(res, bench, lab, layout, m, folder, METRICS, robot.name,
                                         online.episode(res.streams) if res.streams and world is None else None,
                                         attempt=attempt))
        job.progress(k + 1, len(ran.sweep.results))
        e = episodes[-1]
        if res.episode in hit:  # invalid whatever the watchtowers saw: run again like any invalid episode
            e.valid = False
            e.reasons.append(hit[res.episode])
        log.info("%s episode %d: %d frames, %d samples, %s%s", split, e.episode, e.frames, e.samples,
                 "valid" if e.valid else "INVALID: " + "; ".join(e.reasons),
                 "" if e.error_median_m is None else f"; localisation error median {100 * e.error_median_m:.2f} cm")
        if e.online is not None:
            log.info("%s episode %d: detected online: %d frames, %d dropped, at most %d queued", split, e.episode,
                     e.online["frames"], sum(e.online["dropped"].values()), e.online["max_queued"])
    return _Driven(ev, record, episodes, None if live is None else [e.report() for e in live.sink.episodes], towers)


def _retry_invalid(job, lab: Lab, bench, spec, split: str, hidden: bool, driven: _Driven) -> _Driven:
    """Run each episode the DTA's validation found invalid again on the robot (reset to its start, as every episode
    is), up to the benchmark's ``invalid_retries`` times: a run the lab measured badly (the robot lost, the light
    changed, a stream stopped) is the lab's fault, not the agent's, so the job only fails over to another lab once
    the retries are spent (:func:`~.autolab_attempts.retry_invalid`, which a DTPS robot's and a robot node's jobs
    use too). Each episode keeps its attempts before (``earlier``): every one is in the report and the artifacts."""
    state = driven  # the split's evaluation so far: each re-run's results put in place of the attempts before

    def again(bad: list[AutolabEpisode], attempt: int) -> list[AutolabEpisode]:
        nonlocal state
        redo = _drive(job, lab, bench, spec, split, hidden, attempt, {e.episode for e in bad}, state.ev)
        state = _Driven(redo.ev, redo.record, state.episodes,
                        None if state.streams is None else [*state.streams, *(redo.streams or [])], redo.towers)
        return redo.episodes

    episodes = retry_invalid(job, bench, split, lab.robot(job.job.autolab_robot).name, driven.episodes, again)
    return replace(state, episodes=episodes)


def _run_split(job, lab: Lab, bench, spec, split: str, hidden: bool) -> dict[str, float | None]:
    """Episodes on the lab's robot with its watchtowers recording; localised, validated, scored (the module), an
    invalid one run again as the benchmark says (``invalid_retries``)."""
    driven = _retry_invalid(job, lab, bench, spec, split, hidden, _drive(job, lab, bench, spec, split, hidden))
    ev, record, episodes, towers = driven.ev, driven.record, driven.episodes, driven.towers
    robot = lab.robot(job.job.autolab_robot)
    report = dict(record.report)
    report.update(domain_kind="autolab/virtual", measured_by="watchtowers", lab=lab.name, robot=robot.name,
                  watchtowers=towers, localization=[e.report() for e in episodes],
                  robot_reported_scores=record.scores, invalid_retries=bench.invalid_retries)
    if driven.streams is not None:  # what the DTPS reader received per episode (frames, bad messages, frames lost)
        report["watchtower_streams"] = driven.streams
    errs = [e.error_median_m for e in episodes if e.error_median_m is not None]
    report["localization_median_error_m"] = float(np.median(errs)) if errs else None
    for row, e in zip(report["episodes"], episodes, strict=True):
        row["scores"] = e.report()["scores"]
    if hidden:
        job.outcome.hidden_report = report
    else:
        job.outcome.public_report.update(report)
    zip_path = _pack(job.dir / f"trajectories-{split}.zip", ev, episodes)
    job.outcome.artifacts.append(Artifact(zip_path.name, str(zip_path), hidden, "application/zip"))
    bad = [e for e in episodes if not e.fit]
    if bad:  # the retries are spent: the lab's fault, the job goes back to the queue for another lab
        raise HostFault(unfit(bad[0], split, bench.invalid_retries))
    if not hidden and job.job.video and episodes[0].trajectory is not None:
        _video(job, episodes[0].trajectory, bench)
    return _scores(episodes, bench)


def _video(job, trajectory: Path, bench) -> None:
    """A top-down video of the first localised episode and its watchtower view (:func:`_tower_video`), both
    optional: a missing codec costs no result."""
    from proxybench.evaluator.report import topdown_video

    try:
        path = topdown_video(trajectory, job.dir / "validation-episode-0.mp4", bench.frame_rate)
    except Exception as exc:
        log.warning("no video of the first episode: %s", exc)
    else:
        job.outcome.artifacts.append(Artifact(path.name, str(path), False, "video/mp4"))
    _tower_video(job, Path(trajectory).parent)


def _tower_video(job, folder: Path) -> None:
    """The best-placed watchtower's frames of the episode localised in ``folder`` (its log and ``track.csv``), the
    localised pose and its σ drawn where the tower's calibration projects it (:mod:`proxybench.autolab.towerview`);
    its size and CPU time in the report (``watchtower_video``)."""
    import pandas as pd

    from proxybench.autolab.logs import read_log
    from proxybench.autolab.towerview import watchtower_video

    try:
        track = pd.read_csv(folder / "track.csv")
        video = watchtower_video(read_log(folder), {k: track[k].to_numpy() for k in track.columns},
                                 job.dir / "validation-episode-0-watchtower.mp4")
    except Exception as exc:
        log.warning("no watchtower video of the first episode: %s", exc)
        return
    if video is None:
        log.warning("no watchtower video of the first episode: no watchtower's view holds its localised pose")
        return
    log.info("watchtower video: %s, %d frames of %d x %d, %.2f s of CPU", video.watchtower, video.frames,
             video.width, video.height, video.cpu_s)
    job.outcome.artifacts.append(Artifact(video.path.name, str(video.path), False, "video/mp4"))
    job.outcome.public_report["watchtower_video"] = video.report()


def run_autolab(job) -> Outcome:
    """The whole Autolab job for the worker's ``job`` (see the module); fills and returns ``job.outcome``."""
    lab: Lab = job.job.autolab
    bench = _with_reset(job.benchmark(), lab)
    _check_lab(lab, bench, job.job.autolab_robot)
    job.outcome.public_report.update(evaluator=job.job.evaluator.model_dump(mode="json"),
                                     sandbox=job.job.isolation.report(), domain_kind="autolab/virtual")
    spec = job.agent(bench)
    split = _run_split
    if lab.robot(job.job.autolab_robot).kind == "dtps":  # a foreign robot: driven by the agent, watched by the lab
        from functools import partial

        from proxybench.evaluator.autolab_dtps import Scoring, check_dtps_robot, run_dtps_split

        check_dtps_robot(lab, spec)
        job.outcome.public_report["domain_kind"] = "autolab/dtps"
        split = partial(run_dtps_split, scoring=Scoring(localize_episode, _scores, _video))
    elif lab.robot(job.job.autolab_robot).kind == "command":  # a robot node: stepped by the runner, watched by the lab
        from functools import partial

        from proxybench.evaluator.autolab_dtps import Scoring
        from proxybench.evaluator.autolab_node import check_node_robot, run_node_split

        check_node_robot(lab)
        job.outcome.public_report["domain_kind"] = "autolab/node"
        split = partial(run_node_split, scoring=Scoring(localize_episode, _scores, _video))
    job.agent_contract(bench, spec)
    job.outcome.public_scores = split(job, lab, bench, spec, "validation", hidden=False)
    test_seed = job.lease.benchmark.test_seed
    if test_seed is not None:
        hidden = _with_reset(job.benchmark(test_seed), lab)
        job.outcome.hidden_scores = split(job, lab, hidden, spec, "test", hidden=True)
    job.outcome.message = (f"{len(bench.episode_specs())} validation episodes"
                           + (" and the hidden test episodes" if test_seed is not None else "")
                           + f" evaluated in lab {lab.name!r}, measured by its watchtowers")
    return job.outcome
