"""An invalid run run again, as the benchmark says (``invalid_retries``; docs/autolab.md, "An Autolab evaluator"):
what every Autolab robot's job shares, a virtual robot's (:mod:`.autolab`) and a DTPS robot's or robot node's
(:mod:`.autolab_real`).

A run the DTA's validation finds invalid (the robot lost, a stream stopped, the light changed) is the lab's
measurement failing, not the agent, so the episode is run again on the robot (reset or placed again, as every
episode is) up to ``invalid_retries`` times before the job is the lab's fault: :func:`retry_invalid` runs them (how
an episode is run again is the caller's), each attempt keeping the ones before (``earlier``);
:func:`attempt_name` names an attempt's folder, :func:`pack_attempts` puts every earlier attempt into the split's
zip, and :func:`unfit` words the host error once the retries are spent.

Episodes are duck-typed (:class:`~.autolab.AutolabEpisode`: ``episode``, ``attempt``, ``fit``, ``verdict``,
``why()``, ``earlier``, ``files``, ``robot_record``, ``attempt_report()``): this module imports neither evaluator.
"""

from __future__ import annotations

import json
import logging
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

__all__ = ["attempt_name", "pack_attempts", "retry_invalid", "unfit"]

log = logging.getLogger("proxybench.evaluator.job")

E = TypeVar("E")


def attempt_name(episode: int, attempt: int) -> str:
    """An attempt's folder under ``autolab/<split>/``: ``K`` for the first, ``K-attempt-A`` for a re-run (every
    attempt kept: a re-run never writes over the one before)."""
    return str(episode) if attempt == 1 else f"{episode}-attempt-{attempt}"


def retry_invalid(job: Any, bench: Any, split: str, robot: str, episodes: list[E],
                  run_again: Callable[[list[E], int], Sequence[E]]) -> list[E]:
    """``episodes`` (in order) with each one not fit to be scored run again by ``run_again(bad, attempt)`` (the
    robot reset or placed again; it returns the episodes it ran, as measured) up to the benchmark's
    ``invalid_retries`` times. Each re-run adds ``duration × wall_time_factor`` per episode to the job's wall-clock
    budget (``job.allow_extra_wall``: the lab's time, so the agent never fails its budget for the lab's retries).
    A re-run keeps the attempts before it (``earlier``); the last attempt stands in the list, fit or not."""
    for attempt in range(2, bench.invalid_retries + 2):
        bad = {e.episode: e for e in episodes if not e.fit}
        if not bad:
            break
        for e in bad.values():
            log.warning("%s episode %d is %s (%s): resetting robot %r and running it again (attempt %d of %d)",
                        split, e.episode, e.verdict, e.why(), robot, attempt, bench.invalid_retries + 1)
        job.allow_extra_wall(len(bad) * bench.duration * bench.wall_time_factor)
        redone = {}
        for e in run_again(list(bad.values()), attempt):
            e.earlier = [*bad[e.episode].earlier, bad[e.episode]]
            redone[e.episode] = e
        episodes = [redone.get(e.episode, e) for e in episodes]
    return episodes


def pack_attempts(zf: zipfile.ZipFile, episodes: Sequence[Any]) -> None:
    """Into a split's zip: each earlier attempt's files as ``episode-K-attempt-A…`` and its robot record as
    ``robot-episode-K-attempt-A.<suffix>``, and ``attempts.json`` listing every attempt of every episode (number,
    verdict, reasons). The last attempt's files are the caller's (``episode-K…``: what was scored)."""
    for e in episodes:
        for a in e.earlier:
            name = f"episode-{e.episode}-attempt-{a.attempt}"
            for f in a.files:
                zf.write(f, f"{name}{'' if f.suffix == '.parquet' else f'-{f.stem}'}{f.suffix}")
            if a.robot_record and Path(a.robot_record).is_file():
                zf.write(a.robot_record, f"robot-{name}{Path(a.robot_record).suffix}")
    zf.writestr("attempts.json", json.dumps({str(e.episode): [a.attempt_report() for a in [*e.earlier, e]]
                                             for e in episodes}, indent=1))


def unfit(e: Any, split: str, retries: int) -> str:
    """The host error of an episode still invalid after every attempt: the verdict, the reasons, each attempt's."""
    attempts = [*e.earlier, e]
    text = f"{e.verdict}: {split} episode {e.episode} is not fit to be scored (the DTA's validation): {e.why()}"
    if len(attempts) == 1:
        return text + (" (invalid_retries: 0)" if retries == 0 else "")
    return (text + f"; after {len(attempts)} attempts (the benchmark's invalid_retries: {retries}): "
            + "; ".join(f"attempt {a.attempt}: {a.verdict} ({a.why()})" for a in attempts))
