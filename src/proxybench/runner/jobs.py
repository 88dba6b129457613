"""What a unit of evaluation work is: one agent, one domain, one episode. And how a worker does it.

A ``Job`` is plain data (picklable, JSON-able), so any backend (process pool, Ray cluster) can carry it;
its ``key`` is a content hash of everything that determines the result (agent spec, θ, map, episode,
duration, code version; the content of map files and of checkpoint agents), which is what makes sweeps
cacheable and resumable.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

from proxybench import __version__

if TYPE_CHECKING:
    from proxybench.domain.npcs import Traffic
    from proxybench.runner.streams import StreamSpec

#: bump when what an episode produces changes without a change of its inputs (it is part of every job key)
ENGINE_VERSION = 6  # 2: camera agents see JPEG-decoded frames, as over the AIDO protocol; 3: intersection routes;
# 4: NPC robots and pedestrians simulated (benchmark ``npcs:``), object colours and extra duckies in θ;
# 5: the vision agents' lane fit is compiled (closed-form least squares, equal to lstsq within 1e-9, so their
# trajectories can differ in the last bits); 6: floor tags and NPC robots' roof tags drawn as AprilTag 36h11 patterns

__all__ = [
    "DOMAIN_KINDS", "ENGINE_VERSION", "AgentSpec", "DomainSpec", "Job", "JobResult", "batch_group",
    "camera_filter", "execute", "execute_batch", "is_privileged", "make_agent_for",
]


@dataclass(frozen=True)
class AgentSpec:
    """A zoo agent by ``name``, or an external node started with ``command`` (any language; a string may use
    shell syntax) and ``options``: the non-default fields of :class:`~proxybench.protocol.options.NodeOptions`
    (working directory, transport, timeouts, reflection) as sorted pairs, so the spec stays hashable."""

    name: str
    command: str | None = None
    options: tuple[tuple[str, Any], ...] = ()

    @classmethod
    def node(cls, name: str, command: str, options: Any = None) -> AgentSpec:
        """A node agent; ``options``: a ``NodeOptions`` (or None for the defaults)."""
        return cls(name, command, options.items() if options is not None else ())

    @property
    def label(self) -> str:
        return self.name

    def node_options(self):
        """The ``NodeOptions`` of a node agent."""
        from proxybench.protocol.options import NodeOptions

        return NodeOptions(**dict(self.options))

    def key_data(self) -> dict[str, Any]:
        """What identifies the agent in a job's hash (options only when set, so older keys stay valid)."""
        data: dict[str, Any] = {"name": self.name, "command": self.command}
        if self.options:
            data["options"] = dict(self.options)
        return data


#: what a domain can be: a proxy instance S_θ, the built-in reality model, or a robot node (the robot protocol)
DOMAIN_KINDS = ("simulation", "reality-model", "robot")


@dataclass(frozen=True)
class DomainSpec:
    """A domain instance: a label, its parameters θ (DomainParams fields) and what kind of domain it is.

    ``kind`` is "simulation" for proxy instances, "reality-model" for the built-in stand-in target, and
    "robot" for a robot node started with ``command`` (docs/robot-protocol.md: a physical robot's bridge,
    another simulator, or ``proxybench robot serve``). A robot is what it is: its θ is not ours to set, so
    ``params`` stays empty, and its episodes are cached by *what was asked* (the command string, map,
    episode, agent), not by what the robot is: after changing the robot (recalibration, new firmware), use
    a fresh run directory or delete its cached episodes. ``nodes``: how many processes of ``command`` may
    run at once on this machine (one per busy worker, up to this; not part of any key): keep 1 for a bridge
    to one physical robot, raise it for a simulator node. ``options``: how to start and talk to the node,
    the non-default fields of :class:`~proxybench.protocol.options.RobotNodeOptions` (working directory,
    transport, timeouts, reflection) as sorted pairs; of them only ``cwd`` is part of the key (it changes
    what the command runs; a timeout or the transport does not change an episode).
    """

    name: str
    params: dict[str, Any] = field(default_factory=dict)
    kind: str = "simulation"
    command: str | None = None
    nodes: int = 1
    options: tuple[tuple[str, Any], ...] = ()

    @classmethod
    def robot(cls, command: str, *, name: str | None = None, nodes: int = 1, options: Any = None) -> DomainSpec:
        """A robot domain; ``options``: a ``RobotNodeOptions`` (or None for the defaults)."""
        return cls(name or f"robot:{command}", kind="robot", command=command, nodes=nodes,
                   options=options.items() if options is not None else ())

    def node_options(self):
        """The ``RobotNodeOptions`` of a robot domain."""
        from proxybench.protocol.options import RobotNodeOptions

        return RobotNodeOptions(**dict(self.options))

    def __post_init__(self) -> None:
        if self.kind not in DOMAIN_KINDS:
            raise ValueError(f"DomainSpec {self.name!r}: kind must be one of {DOMAIN_KINDS}, got {self.kind!r}")
        if self.kind == "robot":
            if not (isinstance(self.command, str) and self.command.strip()):
                raise ValueError(f"DomainSpec {self.name!r}: a robot domain needs command= (the robot node to start)")
            if self.params:
                raise ValueError(f"DomainSpec {self.name!r}: a robot domain takes no params (the robot's θ is its "
                                 f"own; pass settings in its command), got {sorted(self.params)}")
            if not (isinstance(self.nodes, int) and self.nodes >= 1):
                raise ValueError(f"DomainSpec {self.name!r}: nodes must be a positive integer, got {self.nodes!r}")
        elif self.command is not None or self.options:
            raise ValueError(f"DomainSpec {self.name!r}: command= and options= are only for kind='robot', not "
                             f"{self.kind!r}")

    def canonical(self) -> str:
        doc: dict[str, Any] = {"params": self.params, "kind": self.kind}
        if self.command is not None:  # absent otherwise, so simulated domains keep their keys
            doc["command"] = self.command
        cwd = dict(self.options).get("cwd")
        if cwd is not None:  # absent otherwise, so robot domains without one keep their keys
            doc["cwd"] = cwd
        return json.dumps(doc, sort_keys=True)


@dataclass(frozen=True)
class Job:
    """One episode to run: agent × domain × map × episode (seed, optional start pose and route) × duration."""

    agent: AgentSpec
    domain: DomainSpec
    map: str
    episode: int
    seed: int
    duration: float
    pose: tuple[float, float, float] | None = None
    camera_only: bool = False
    metrics: tuple[str, ...] = ()
    route: tuple[str, ...] | None = None  # turns at intersections (domain.routes); None: drawn from the seed
    npcs: Traffic | None = None  # NPC robots and pedestrians of the episode's world (domain.npcs)
    streams: StreamSpec | None = None  # fixed cameras (watchtowers) recorded during the episode (runner.streams)

    def __post_init__(self) -> None:
        if self.domain.kind == "robot" and self.npcs is not None and not self.npcs.empty:
            raise ValueError(f"job {self.agent.label} / {self.domain.name}: a robot node drives one robot and no "
                             f"NPCs; this job has npcs (a benchmark with `npcs:` needs a simulated domain)")

    @cached_property
    def key(self) -> str:
        """Content hash: equal keys ⇔ the same result (given deterministic agents). Computed once per job
        (it reads map and checkpoint files) and carried along when the job is pickled to a worker."""
        doc = {"agent": _agent_id(self.agent), "domain": json.loads(self.domain.canonical()), "map": _map_id(self.map),
               "seed": self.seed, "pose": self.pose, "duration": self.duration, "camera_only": self.camera_only,
               "route": self.route, "npcs": None if self.npcs is None else self.npcs.to_dict(),
               "version": __version__, "engine": ENGINE_VERSION}
        if self.streams is not None:  # absent otherwise, so jobs without streams keep their keys
            doc["streams"] = self.streams.key_data()
        blob = json.dumps(doc, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:24]


@dataclass
class JobResult:
    """Scores of one finished episode plus where its trajectory is stored."""

    key: str
    agent: str
    domain: str
    episode: int
    seed: int
    scores: dict[str, float]
    termination: str
    trajectory: str | None
    message: str = ""
    timings: dict[str, float] = field(default_factory=dict)
    streams: str | None = None  # folder of the episode's fixed-camera streams, if it recorded any

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @staticmethod
    def from_json(text: str) -> JobResult:
        return JobResult(**json.loads(text))


def _agent_id(spec: AgentSpec) -> dict[str, Any]:
    """What identifies an agent in a key: its spec, and for a behaviour-cloning checkpoint (a path given as
    the name) the content of its files, so that retraining into the same path invalidates cached episodes.
    A node command is identified by its string only (like a robot's: what was asked)."""
    from proxybench.agents.zoo import ZOO

    out = spec.key_data()
    if spec.command is None and spec.name not in ZOO:
        from proxybench.learning import is_checkpoint

        if is_checkpoint(spec.name):
            pt = Path(spec.name).with_suffix(".pt")
            out["checkpoint"] = _file_digest(pt) + _file_digest(pt.with_suffix(".json"))
    return out


def _file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def _map_id(name: str) -> str:
    """Maps by name are built-in; a file path is identified by its content, so edits invalidate caches."""
    p = Path(name)
    if p.suffix in (".yaml", ".yml") and p.exists():
        return hashlib.sha256(p.read_bytes()).hexdigest()[:16]
    return name


# -- the worker side --------------------------------------------------------------------------------

_SIMS: dict[tuple[Any, ...], Any] = {}


def _simulator(job: Job, n: int = 1):
    """One cached simulator per (map, θ, batch size) per worker: building one costs more than an episode."""
    from proxybench.domain.params import DomainParams
    from proxybench.domain.simulator import Simulator

    fixtures = job.streams.fixtures if job.streams is not None else ()
    k = (job.map, job.domain.canonical(), n, job.npcs, fixtures)
    if k not in _SIMS:
        if len(_SIMS) > 8:
            _SIMS.clear()
        m = job.map
        if fixtures:
            from proxybench.domain.maps import load_map
            from proxybench.runner.streams import with_fixtures

            m = with_fixtures(load_map(job.map), fixtures)
        _SIMS[k] = Simulator(m, DomainParams.model_validate(job.domain.params), n=n, npcs=job.npcs)
    return _SIMS[k]


def batch_group(job: Job) -> tuple:
    """Jobs with equal groups can share one batched simulator: same domain, map, NPCs, length and rules, and
    agents that see alike (all privileged or all camera); in-process agents may differ robot by robot. A node
    agent groups only with itself. Jobs on one robot domain share a node process whatever their agent, map
    or length (one after another).
    """
    if job.domain.kind == "robot":
        return ("robot", job.domain.canonical())
    who = job.agent if job.agent.command else ("in-process", is_privileged(job.agent))
    return (who, job.domain.canonical(), job.map, job.duration, job.camera_only, job.metrics, job.npcs, job.streams)


def is_privileged(spec: AgentSpec) -> bool:
    """Whether the agent a spec names reads the true lane pose, without starting it: a zoo agent's flag;
    False for node agents and checkpoints (camera only)."""
    from proxybench.agents.zoo import ZOO

    return bool(spec.command is None and spec.name in ZOO and ZOO[spec.name].privileged)


def _refused(job: Job, agent, setup_s: float, msg: str | None = None) -> JobResult:
    """A privileged agent on a camera-only job (or on a robot without ground truth): no episode, a recorded
    reason, NaN scores."""
    msg = msg or f"agent {agent.name!r} is privileged (reads the true lane pose); this benchmark is camera-only"
    return JobResult(job.key, job.agent.label, job.domain.name, job.episode, job.seed,
                     dict.fromkeys(job.metrics or _all_metrics(), float("nan")), "agent_failure", None, msg,
                     {"setup_s": setup_s})


def _all_metrics() -> tuple[str, ...]:
    from proxybench.tasks.metrics import METRICS

    return tuple(METRICS)


def camera_filter():
    """What camera agents see: the JPEG round trip of every frame, exactly what a protocol node receives."""
    from proxybench.protocol.jpeg import roundtrip

    return roundtrip


def make_agent_for(spec: AgentSpec):
    """The agent a spec names: a zoo agent in-process, or a node process behind the protocol."""
    if spec.command:
        from proxybench.protocol import RemoteAgent

        agent = RemoteAgent(spec.command, **spec.node_options().process_kwargs())
        agent.name = spec.name
        return agent
    from proxybench.agents import make_agent

    return make_agent(spec.name)


def execute(job: Job, out_dir: str | None) -> JobResult:
    """Run one job in this process; write its trajectory under ``out_dir`` (atomically) if given."""
    return execute_batch([job], out_dir)[0]


def execute_batch(jobs: list[Job], out_dir: str | None) -> list[JobResult]:
    """Run jobs of one :func:`batch_group` together: one simulator of N robots, one agent per robot (agents
    may differ from robot to robot; a batch gives the same trajectories as N single runs).

    In-process agents are batched; node agents (one process each) run one by one. Robot domains go to
    :func:`execute_robot_batch`.
    """
    import time

    from proxybench.runner.episode import run_episodes
    from proxybench.tasks.metrics import METRICS

    if len({batch_group(j) for j in jobs}) != 1:
        raise ValueError("execute_batch: the jobs do not share one batch group")
    if jobs[0].domain.kind == "robot":
        from proxybench.runner.robot_jobs import execute_robot_batch

        return execute_robot_batch(jobs, out_dir)
    if len(jobs) > 1 and jobs[0].agent.command:
        return [r for j in jobs for r in execute_batch([j], out_dir)]
    job0 = jobs[0]
    t0, c0 = time.perf_counter(), time.process_time()
    agents = [make_agent_for(j.agent) for j in jobs]
    if len({a.privileged for a in agents}) > 1:  # an agent that is not what its name said: see alike, run alike
        for a in agents:
            getattr(a, "close", lambda: None)()
        return [r for flag in (False, True)
                for r in execute_batch([j for j, a in zip(jobs, agents, strict=True) if a.privileged == flag],
                                       out_dir)]
    sim = _simulator(job0, len(jobs))
    t1 = time.perf_counter()
    recorders = _recorders(jobs, sim, out_dir)
    try:
        if agents[0].privileged and job0.camera_only:
            return [_refused(j, a, (t1 - t0) / len(jobs)) for j, a in zip(jobs, agents, strict=True)]
        trajs = run_episodes(
            sim, agents, [j.seed for j in jobs], job0.duration, poses=[j.pose for j in jobs],
            routes=[j.route for j in jobs], camera=not agents[0].privileged, allow_privileged=not job0.camera_only,
            image_filter=camera_filter(),
            metas=[{"map": j.map, "episode": j.episode, "domain": j.domain.name, "domain_kind": j.domain.kind,
                    "source": j.domain.kind, "job": j.key} for j in jobs],
            frame_hook=_stream_hook(recorders),
        )
    finally:
        for a in agents:
            getattr(a, "close", lambda: None)()
        for rec in recorders:
            rec.close()
    t2 = time.perf_counter()
    results = [_result(j, tr, out_dir, (t1 - t0) / len(jobs), (t2 - t1) / len(jobs), METRICS)
               for j, tr in zip(jobs, trajs, strict=True)]
    for r, rec in zip(results, recorders, strict=False):
        r.streams = str(rec.out)
    cpu = (time.process_time() - c0) / len(jobs)
    for r in results:
        r.timings["cpu_s"] = cpu
    return results


def _recorders(jobs: list[Job], sim, out_dir: str | None) -> list:
    """One stream recorder per job of a batch that asks for streams (robot i of the batch is world i)."""
    if jobs[0].streams is None:
        return []
    if out_dir is None:
        raise ValueError("jobs with streams need an output folder (the streams are written beside the trajectory)")
    from proxybench.runner.streams import StreamRecorder

    return [StreamRecorder(sim, j.streams, Path(out_dir) / f"{j.key}.streams", world=i) for i, j in enumerate(jobs)]


def _stream_hook(recorders: list):
    """The frame hook that feeds the stream recorders: each world's cameras while its episode runs."""
    if not recorders:
        return None

    def hook(k: int, images, alive, plant) -> None:
        for i, rec in enumerate(recorders):
            if alive[i]:
                rec.frame(plant.time(i))
    return hook


def _result(job: Job, traj, out_dir: str | None, setup_s: float, episode_s: float, metrics) -> JobResult:
    t = time.perf_counter()
    scores = {name: metrics[name](traj) for name in (job.metrics or tuple(metrics))}
    path = None
    if out_dir is not None:
        path = str(Path(out_dir) / f"{job.key}.parquet")
        traj.save(path)
    message = next((e["message"] for e in traj.events if e["kind"] == "agent_failure"), "")
    timing = traj.meta.get("timing", {})
    sim_s, agent_s = timing.get("sim_s", 0.0), timing.get("agent_s", 0.0)
    timings = {"setup_s": setup_s, "sim_s": sim_s, "agent_s": agent_s,
               "bookkeeping_s": (episode_s - sim_s - agent_s) + (time.perf_counter() - t),
               "simulated_s": traj.duration}
    return JobResult(job.key, job.agent.label, job.domain.name, job.episode, job.seed, scores, traj.termination,
                     path, message, timings)

