"""What the CLI's ``--watchtowers`` options share: a layout and its streams for a run, and the log they leave."""

from __future__ import annotations

from pathlib import Path

from proxybench.autolab.calibration import stream_spec
from proxybench.autolab.logs import LogManifest, write_sim_log
from proxybench.autolab.watchtowers import Layout, resolve_layout
from proxybench.domain.maps import Map

__all__ = ["finish_sim_log", "layout_streams", "logs_from_results", "result_log"]

#: ends of an episode that are the run's own (not a premature end of the recording)
EPISODE_ENDS = ("timeout",)


def layout_streams(spec: str, m: Map):
    """(layout, the runner's StreamSpec, the map with the layout's ground tags) for ``--watchtowers SPEC``."""
    from proxybench.runner.streams import with_fixtures

    layout = resolve_layout(spec, m)
    streams = stream_spec(layout)
    return layout, streams, with_fixtures(m, streams.fixtures)


def finish_sim_log(out: Path, layout: Layout, map_name: str, agent: str, episode: int, seconds: float,
                   termination: str, source: str = "simulation") -> Path:
    """Calibrations and ``log.yaml`` beside the streams a simulated run wrote into ``out/watchtowers``."""
    manifest = LogManifest(source=source, map=map_name, agent=agent, episode=episode, seconds=seconds,
                           termination=None if termination in EPISODE_ENDS else termination)
    return write_sim_log(out, layout, out / "watchtowers", manifest)


def result_log(res, folder: Path, layout: Layout, map_name: str, seconds: float, source: str) -> None:
    """Make ``folder`` (its ``watchtowers/`` holding a job's streams) a log, with the job's true trajectory."""
    import shutil

    if res.trajectory is not None:
        shutil.copyfile(res.trajectory, folder / "trajectory.parquet")
    finish_sim_log(folder, layout, map_name, res.agent, res.episode, seconds, res.termination, source)


def logs_from_results(results, layout: Layout, map_name: str, root: Path, seconds: float) -> int:
    """Copy each job's streams to ``root/<agent>/<episode>/watchtowers`` and make it a log; how many."""
    import shutil

    n = 0
    for res in results:
        if res.streams is None or not Path(res.streams).is_dir():
            continue
        folder = root / res.agent / str(res.episode)
        if (folder / "watchtowers").exists():
            shutil.rmtree(folder / "watchtowers")
        shutil.copytree(res.streams, folder / "watchtowers")
        result_log(res, folder, layout, map_name, seconds, "simulation")
        n += 1
    return n
