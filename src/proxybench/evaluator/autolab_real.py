"""What any **non-virtual** robot's Autolab job shares (docs/autolab.md, "A real robot"): a lab's DTPS robot
(:mod:`.autolab_dtps`, driven by the agent) and its robot node (:mod:`.autolab_node`, stepped by the runner).

Neither robot is simulated by proxybench, so both are placed by the lab's operator (:func:`place_robot`, the desk of
:mod:`proxybench.autolab.operator`), watched by the lab's own DTPS watchtowers (:func:`open_watchtowers`), clocked by
the first command (:func:`rebase_streams`), and scored from the localised trajectory only
(:func:`localize_episode`: the :class:`Scoring` that :mod:`.autolab` hands in); a split ends in one report, one
``trajectories-<split>.zip``, the DTA's verdict and the scores (:func:`finish_split`). An invalid run is run again,
the operator placing the robot again, as the benchmark says (:func:`run_attempts`: ``invalid_retries``, as for a
virtual robot, :mod:`.autolab_attempts`). The lab's faults are worded once here (:func:`robot_failure`,
:func:`intervened`).
"""

from __future__ import annotations

import csv
import json
import logging
import os
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from proxybench.autolab.lab import Lab
from proxybench.evaluator.autolab_attempts import attempt_name, pack_attempts, retry_invalid, unfit
from proxybench.evaluator.outcome import Artifact, HostFault

__all__ = ["Ran", "Scoring", "attempt_folder", "check_real_robot", "episode_name", "finish_split", "intervened",
           "localize_episode", "open_watchtowers", "place_robot", "rebase_streams", "robot_failure", "run_attempts",
           "tell_operator"]

log = logging.getLogger("proxybench.evaluator.job")


@dataclass
class Ran:
    """One episode as :func:`~.autolab.localize_episode` reads it: its streams, no truth, how it ended."""

    episode: int
    streams: Path
    termination: object
    trajectory: Path | None = None


@dataclass(frozen=True)
class Scoring:
    """What a non-virtual robot's split shares with a virtual robot's (:mod:`.autolab`: localise, validate and score
    an episode; aggregate; the video), handed in by that module, which imports this one (never the other way)."""

    localize: Callable[..., Any]
    scores: Callable[..., dict[str, float | None]]
    video: Callable[..., None]


def robot_failure(lab: Lab, robot, what: str, detail: str) -> HostFault:
    """The lab's fault: its robot failed in ``what`` (an episode) saying ``detail``."""
    return HostFault(f"robot_failure: robot {robot.name!r} of lab {lab.name!r} failed in {what}: {detail}")


def intervened(lab: Lab, robot, what: str, reason: str) -> HostFault:
    """The operator stepped in (``autolab intervene``) during ``what``: the episode and the job end."""
    return HostFault(f"manual_intervention: the operator intervened on robot {robot.name!r} of lab {lab.name!r} in "
                     f"{what}: {reason}")


def check_real_robot(lab: Lab, robot_is: str) -> None:
    """What a non-virtual robot (``robot_is``: "a DTPS robot", …) needs of the lab: its own cameras, an operator;
    :class:`HostFault` saying what is missing."""
    if lab.watchtowers.layout is not None:
        raise HostFault(f"lab {lab.name!r}: simulated watchtowers (layout) cannot see {robot_is}; give the lab's "
                        "own cameras as watchtowers.streams")
    if lab.reset.mode == "teleport":  # lab.yaml refuses it already; a lab made in code might not
        raise HostFault(f"lab {lab.name!r}: {robot_is} is placed by its operator (reset.mode operator or pose_file)")


def open_watchtowers(lab: Lab):
    """The lab's own DTPS watchtowers, read while its episodes run (:func:`~proxybench.autolab.live.live_streams`);
    a stream that cannot be read is the lab's fault."""
    from proxybench.autolab.live import live_streams
    from proxybench.dtps.cameras import ReaderError

    try:
        return live_streams(lab, None)
    except ReaderError as exc:
        raise HostFault(f"watchtowers: {exc}") from None


def tell_operator(text: str) -> None:
    """The placement request: the job's log, and the evaluator's terminal where it has one."""
    log.warning("%s", text)
    try:
        fd = os.open("/dev/tty", os.O_WRONLY | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return
    try:
        os.write(fd, f"[proxybench autolab] {text}\n".encode())
    except OSError:
        pass
    finally:
        os.close(fd)


def place_robot(desk, lab: Lab, robot, bench, ep, what: str) -> tuple[float, float, float]:
    """The operator places ``robot`` at the episode's start (the pose file's, else the benchmark's) and confirms on
    the desk (:meth:`~proxybench.autolab.operator.OperatorDesk.place`); no answer in time is the lab's fault. The
    pose."""
    from proxybench.autolab.operator import OperatorTimeout
    from proxybench.runner.starts import start_pose

    pose = ep.pose if ep.pose is not None else start_pose(bench.map, ep.seed, bench.domain_params())
    x, y, th = pose
    request = f"place robot {robot.name} at x={x:.3f} m, y={y:.3f} m, θ={th * 57.29578:.1f}° for {what}"
    try:
        waited = desk.place(request, lab.operator.timeout_s, tell=tell_operator)
    except OperatorTimeout as exc:
        raise HostFault(f"robot_failure: {exc}") from None
    log.info("%s: the operator placed %s after %.1f s", what, robot.name, waited)
    return pose


def rebase_streams(folder: Path, origin: float) -> int:
    """Each watchtower's ``timestamps.csv`` in ``folder`` on the episode's clock: ``t = stamp − origin`` (the
    camera's stamp, the robot's first command's wall time); frames before it dropped (their files removed). The
    frames kept."""
    kept = 0
    for stamps in sorted(folder.glob("*/timestamps.csv")):
        with open(stamps, newline="") as fh:
            rows = list(csv.DictReader(fh))
        keep = []
        for r in rows:
            t = float(r["stamp"]) - origin
            if t >= 0.0:
                keep.append((r["frame"], f"{t:.6f}", r["stamp"], r["received"]))
            else:
                for f in stamps.parent.glob(f"{int(r['frame']):06d}.*"):
                    f.unlink()
        if not keep:
            for f in stamps.parent.iterdir():
                f.unlink()
            stamps.parent.rmdir()
            continue
        with open(stamps, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["frame", "t", "stamp", "received"])
            w.writerows(keep)
        kept += len(keep)
    return kept


def episode_name(split: str, episode: int, attempt: int) -> str:
    """How the operator's request, the desk and the lab's faults name an attempt: ``validation episode 0``, a re-run
    ``validation episode 0, attempt 2``."""
    return f"{split} episode {episode}" + ("" if attempt == 1 else f", attempt {attempt}")


def attempt_folder(job, split: str, episode: int, attempt: int) -> Path:
    """An attempt's folder, ``autolab/<split>/K`` (a re-run: ``K-attempt-A``): every attempt's streams and record
    kept."""
    return job.dir / "autolab" / split / attempt_name(episode, attempt)


def localize_episode(job, scoring: Scoring, ran: Ran, bench, lab: Lab, m, folder: Path, robot, split: str,
                     attempt: int = 1, record: Path | None = None):
    """The episode localised, validated and scored as a virtual robot's (``scoring.localize``), from its streams
    only (no truth), into ``folder / "localized"``; ``attempt``: which run of the episode it is (the lab's drills
    may spare later ones); ``record``: the robot's own record of it, kept beside (never scored)."""
    from proxybench.tasks.metrics import METRICS

    job.phase = f"{split} localisation"
    done = scoring.localize(ran, bench, lab, None, m, folder / "localized", METRICS, robot.name, attempt=attempt)
    done.robot_record = None if record is None else str(record)
    job.phase = split
    return done


def run_attempts(job, bench, split: str, robot, run: Callable[[int], Any]):
    """One episode on a non-virtual robot as the benchmark says: ``run(attempt)`` runs it (the operator places the
    robot, as for every attempt) and returns it measured; while it is not fit to be scored it is run again, up to
    ``invalid_retries`` times (:func:`~.autolab_attempts.retry_invalid`: the job's wall budget extended per re-run,
    each attempt keeping the ones before). The last attempt."""
    (done,) = retry_invalid(job, bench, split, robot.name, [run(1)], lambda _bad, attempt: [run(attempt)])
    return done


def finish_split(job, lab: Lab, robot, bench, split: str, hidden: bool, scoring: Scoring, *, kind: str,
                 about: dict[str, Any], episodes, records: list[dict], live,
                 extra: dict[str, Any] | None = None) -> dict[str, float | None]:
    """A split's report (``kind``: its ``domain_kind``; ``about``: how the robot is reached; ``records``: each
    attempt's robot record, as ``robot_record``; ``extra``: after it), its ``trajectories-<split>.zip`` (each
    episode's localisation and the robot's own record as ``robot-episode-K``, each earlier attempt's beside,
    ``attempts.json``), the DTA's verdict (once the retries are spent, naming every attempt) and the scores, from
    the localisation only."""
    report = {"domain_kind": kind, "measured_by": "watchtowers", "lab": lab.name, "robot": robot.name, **about,
              "watchtowers": len(live.names),
              "localization": [e.report() for e in episodes], "localization_median_error_m": None,
              "robot_record": records, **(extra or {}),
              "watchtower_streams": [e.report() for e in live.sink.episodes],
              "episodes": [{"episode": e.episode, "scores": e.report()["scores"], "valid": e.valid}
                           for e in episodes], "invalid_retries": bench.invalid_retries}
    if hidden:
        job.outcome.hidden_report = report
    else:
        job.outcome.public_report.update(report)
    zip_path = job.dir / f"trajectories-{split}.zip"
    with zipfile.ZipFile(zip_path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for e in episodes:
            for f in e.files:
                zf.write(f, f"episode-{e.episode}{'' if f.suffix == '.parquet' else '-' + f.stem}{f.suffix}")
            if e.robot_record:
                zf.write(e.robot_record, f"robot-episode-{e.episode}{Path(e.robot_record).suffix}")
        pack_attempts(zf, episodes)
        zf.writestr("robot-record.json", json.dumps(records, indent=1))
    job.outcome.artifacts.append(Artifact(zip_path.name, str(zip_path), hidden, "application/zip"))
    bad = [e for e in episodes if not e.fit]
    if bad:  # the retries are spent: the lab's fault, the job goes back to the queue for another lab
        raise HostFault(unfit(bad[0], split, bench.invalid_retries))
    if not hidden and job.job.video and episodes and episodes[0].trajectory is not None:
        scoring.video(job, episodes[0].trajectory, bench)
    return scoring.scores(episodes, bench)
