"""An Autolab evaluator's shared world (``lab.yaml``'s ``world: shared``, issue 36 item 3): started with the evaluator.

The lab's virtual robots share one floor, a :mod:`proxybench.runner.lab_world` server in a process of the
evaluator's own (spawned: nothing of the evaluator's threads is copied into it), listening on a Unix socket in the
evaluator's private work folder (mode 700: an agent, another user, cannot reach it) to whoever holds a key drawn
here. Each job's worker is told the socket and key (``WorkerJob.lab_world``, in its private ``job.json``) and
drives its robot through :class:`~proxybench.runner.jobs.LabWorldLink`; the world renders each robot's camera, which
the worker's virtual DB21J publishes to the sandboxed agent as before.
"""

from __future__ import annotations

import multiprocessing
import secrets
from pathlib import Path

from pydantic import BaseModel, ConfigDict

from proxybench.autolab.lab import Lab

__all__ = ["LabWorldProcess", "WorldAddress", "world_spec"]

#: [s] for the world's simulator and renderers to be built (compiled kernels come from numba's cache)
START_TIMEOUT_S = 300.0


class WorldAddress(BaseModel):
    """Where a worker reaches the lab's shared world: the server's Unix socket and its key (hex)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    path: str
    key: str


def world_spec(lab: Lab):
    """The :class:`~proxybench.runner.lab_world.LabWorldSpec` of ``lab``: its map, virtual robots with their roof
    tags, its simulated watchtowers (their calibration tags part of the floor)."""
    from proxybench.autolab.calibration import stream_spec
    from proxybench.domain.maps import load_map
    from proxybench.runner.lab_world import LabWorldSpec

    tags = {name: tag for tag, name in lab.roof_tags().items()}
    robots = tuple(r.name for r in lab.robots if r.kind == "virtual")
    if not robots:
        raise ValueError(f"lab {lab.name!r}: world: shared needs virtual robots")
    return LabWorldSpec(lab.map, robots, tuple(tags[r] for r in robots), stream_spec(lab.layout(load_map(lab.map))))


class LabWorldProcess:
    """The lab's shared world served from a process of its own, listening in ``folder`` (default: this user's private
    folder, :mod:`proxybench.private`)."""

    def __init__(self, lab: Lab, folder: Path | None = None):
        from proxybench.private import user_folder
        from proxybench.runner.lab_world import LabWorldAddress, serve

        folder = folder or user_folder("lab-worlds")

        spec = world_spec(lab)
        sock = folder / f"lab-world-{secrets.token_hex(4)}.sock"  # short: a Unix socket's path has 107 bytes at most
        self.address = WorldAddress(path=str(sock), key=secrets.token_hex(32))
        ctx = multiprocessing.get_context("spawn")
        ready = ctx.Event()
        self.process = ctx.Process(target=serve, name=f"lab-world-{lab.name}", daemon=True,
                                   args=(spec, LabWorldAddress(self.address.path, bytes.fromhex(self.address.key)),
                                         ready))
        self.process.start()
        waited = 0.0
        while not ready.wait(1.0):
            waited += 1.0
            if not self.process.is_alive() or waited > START_TIMEOUT_S:
                self.close()
                raise RuntimeError(f"lab {lab.name!r}: its shared world did not start (exit code "
                                   f"{self.process.exitcode}; waited {waited:g} s)")

    def close(self) -> None:
        """End the world (its robots' episodes with it)."""
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(10)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(10)
        Path(self.address.path).unlink(missing_ok=True)


def shared_domain(address: WorldAddress, robot: str, bench, streams: Path):
    """The domain a job's episodes run in on ``robot`` of the shared world at ``address``: the benchmark's θ and
    rate, its watchtower streams written under ``streams`` (``<k>/``, one folder per episode)."""
    from proxybench.runner.jobs import LabWorldLink, RobotDomain

    link = LabWorldLink(address.path, address.key, robot, bench.domain_params(), str(streams))
    return RobotDomain(f"lab-world:{robot}", link, float(bench.frame_rate))


def episode_streams(res):
    """``res`` (a job result on the shared world) with its ``streams``: the folder its robot's plant said."""
    import dataclasses

    from proxybench.tasks.trajectory import Trajectory

    if res.streams is not None or not res.trajectory:
        return res
    said = Trajectory.load(res.trajectory).meta.get("lab_world") or {}
    return dataclasses.replace(res, streams=said.get("streams"))


def contact_invalid(res) -> str | None:
    """Why episode ``res`` is invalid by the lab's collision rule, as a reason of the DTA's verdict: another robot ran
    into this one (None: it was not hit, or it was at fault too and ended as a ``collision``)."""
    from proxybench.runner.lab_world import CONTACT_EVENT
    from proxybench.tasks.trajectory import Trajectory

    if not res.trajectory:
        return None
    hit = Trajectory.load(res.trajectory).event(CONTACT_EVENT)
    if hit is None:
        return None
    return f"at t = {hit.t:.2f} s {hit.message}"
