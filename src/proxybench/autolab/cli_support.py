"""What the CLI's ``--watchtowers`` options share: a layout and its streams for a run, and the log they leave."""

from __future__ import annotations

from pathlib import Path

from proxybench.autolab.calibration import stream_spec
from proxybench.autolab.logs import LogManifest, write_sim_log
from proxybench.autolab.watchtowers import Layout, resolve_layout
from proxybench.domain.maps import Map

__all__ = ["finish_sim_log", "layout_streams"]

#: ends of an episode that are the run's own (not a premature end of the recording)
EPISODE_ENDS = ("timeout",)


def layout_streams(spec: str, m: Map):
    """(layout, the runner's StreamSpec, the map with the layout's ground tags) for ``--watchtowers SPEC``."""
    from proxybench.runner.streams import with_fixtures

    layout = resolve_layout(spec, m)
    streams = stream_spec(layout)
    return layout, streams, with_fixtures(m, streams.fixtures)


def finish_sim_log(out: Path, layout: Layout, map_name: str, agent: str, episode: int, seconds: float,
                   termination: str) -> Path:
    """Calibrations and ``log.yaml`` beside the streams a simulated run wrote into ``out/watchtowers``."""
    manifest = LogManifest(source="simulation", map=map_name, agent=agent, episode=episode, seconds=seconds,
                           termination=None if termination in EPISODE_ENDS else termination)
    return write_sim_log(out, layout, out / "watchtowers", manifest)
