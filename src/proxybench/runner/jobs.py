"""What a unit of evaluation work is: one agent, one domain, one episode (how a worker does it: :mod:`.execute`).

A ``Job`` is plain data (picklable, JSON-able), so any backend (process pool, Ray cluster) can carry it;
its ``key`` is a content hash of everything that determines the result (agent spec, θ, map, episode,
duration, code version; the content of map files and of checkpoint agents), which is what makes sweeps
cacheable and resumable.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

from proxybench import __version__
from proxybench.domain.events import Termination
from proxybench.domain.kinds import DomainKind
from proxybench.domain.params import DomainParams

if TYPE_CHECKING:
    from proxybench.domain.npcs import Traffic
    from proxybench.runner.streams import StreamSpec

#: bump when what an episode produces changes without a change of its inputs (it is part of every job key)
ENGINE_VERSION = 6  # 2: camera agents see JPEG-decoded frames, as over the AIDO protocol; 3: intersection routes;
# 4: NPC robots and pedestrians simulated (benchmark ``npcs:``), object colours and extra duckies in θ;
# 5: the vision agents' lane fit is compiled (closed-form least squares, equal to lstsq within 1e-9, so their
# trajectories can differ in the last bits); 6: floor tags and NPC robots' roof tags drawn as AprilTag 36h11 patterns

__all__ = ["DOMAIN_KINDS", "ENGINE_VERSION", "AgentSpec", "DomainSpec", "Job", "JobResult", "batch_group",
           "is_privileged"]


@dataclass(frozen=True)
class AgentSpec:
    """A zoo agent by ``name``, or an external node started with ``command`` (any language; a string may use
    shell syntax) and ``options``: the non-default fields of :class:`~proxybench.protocol.options.NodeOptions`
    (working directory, transport, timeouts, reflection) as sorted pairs, so the spec stays hashable.
    ``protocol``: ``"aido"`` (an AIDO agent node) or ``"sdk"`` (a duckietown-sdk program driving a virtual
    DB21J over DTPS, :mod:`proxybench.dtps`; its options are :class:`~proxybench.dtps.options.SdkOptions`)."""

    name: str
    command: str | None = None
    options: tuple[tuple[str, Any], ...] = ()
    protocol: str = "aido"

    @classmethod
    def node(cls, name: str, command: str, options: Any = None) -> AgentSpec:
        """A node agent; ``options``: a ``NodeOptions`` (or None for the defaults)."""
        return cls(name, command, options.items() if options is not None else ())

    @classmethod
    def sdk(cls, name: str, command: str, options: Any = None) -> AgentSpec:
        """A duckietown-sdk agent program; ``options``: an ``SdkOptions`` (or None for the defaults)."""
        return cls(name, command, options.items() if options is not None else (), "sdk")

    @property
    def label(self) -> str:
        return self.name

    def node_options(self):
        """The ``NodeOptions`` of a node agent (``SdkOptions`` of an SDK agent)."""
        if self.protocol == "sdk":
            from proxybench.dtps.options import SdkOptions

            return SdkOptions(**dict(self.options))
        from proxybench.protocol.options import NodeOptions

        return NodeOptions(**dict(self.options))

    def key_data(self) -> dict[str, Any]:
        """What identifies the agent in a job's hash (options and protocol only when set, so older keys stay
        valid)."""
        data: dict[str, Any] = {"name": self.name, "command": self.command}
        if self.options:
            data["options"] = dict(self.options)
        if self.protocol != "aido":
            data["protocol"] = self.protocol
        return data


#: [Hz] the camera rate of :class:`~proxybench.domain.params.DomainParams` when nobody sets one
DEFAULT_FRAME_RATE = 15.0
#: what a job's domain can be: a proxy instance S_θ, the built-in reality model, or a robot node (the robot
#: protocol); a recording (``DomainKind.RECORDED``) is read, never run
DOMAIN_KINDS = (DomainKind.SIMULATION, DomainKind.REALITY_MODEL, DomainKind.ROBOT)


@dataclass(frozen=True)
class DomainSpec:
    """A domain instance: a label, its parameters θ (a :class:`DomainParams`) and what kind of domain it is.

    ``kind`` is "simulation" for proxy instances, "reality-model" for the built-in stand-in target, and
    "robot" for a robot node started with ``command`` (docs/robot-protocol.md: a physical robot's bridge,
    another simulator, or ``proxybench robot serve``). A simulated domain without ``params`` has the default
    θ. A robot is what it is: its θ is not ours to set, so ``params`` stays None, and its episodes are cached
    by *what was asked* (the command string, map, episode, agent), not by what the robot is: after changing
    the robot (recalibration, new firmware), use a fresh run directory or delete its cached episodes.
    ``nodes``: how many processes of ``command`` may run at once on this machine (one per busy worker, up to
    this; not part of any key): keep 1 for a bridge to one physical robot, raise it for a simulator node.
    ``options``: how to start and talk to the node, the non-default fields of
    :class:`~proxybench.protocol.options.RobotNodeOptions` (working directory, transport, timeouts,
    reflection) as sorted pairs; of them only ``cwd`` is part of the key (it changes what the command runs; a
    timeout or the transport does not change an episode). ``frame_rate`` [Hz]: what a robot node is asked to
    step at (the benchmark's or the proxies' rate; a node that says its own rate is stepped at that); part of
    the key when it is not the default 15 Hz. ``link``: how the robot is reached:
    ``protocol`` (a robot node process, above) or ``dtps`` (a DTPS robot, :meth:`dtps`: ``command`` is then its
    address ``HOST:PORT/PATH`` and ``options`` a :class:`~proxybench.dtps.robot_options.DtpsRobotOptions`).
    """

    name: str
    params: DomainParams | None = None
    kind: DomainKind = DomainKind.SIMULATION
    command: str | None = None
    nodes: int = 1
    options: tuple[tuple[str, Any], ...] = ()
    frame_rate: float = DEFAULT_FRAME_RATE
    link: str = "protocol"

    @classmethod
    def robot(cls, command: str, *, frame_rate: float, name: str | None = None, nodes: int = 1,
              options: Any = None) -> DomainSpec:
        """A robot domain stepped at ``frame_rate`` [Hz]; ``options``: a ``RobotNodeOptions`` (or None for the
        defaults)."""
        return cls(name or f"robot:{command}", kind=DomainKind.ROBOT, command=command, nodes=nodes,
                   options=options.items() if options is not None else (), frame_rate=float(frame_rate))

    @classmethod
    def dtps(cls, address: Any, *, frame_rate: float, options: Any = None) -> DomainSpec:
        """The DTPS robot at ``address`` (a ``DtpsAddress``) stepped at ``frame_rate`` [Hz]; ``options``: a
        ``DtpsRobotOptions`` (or None for the defaults). One robot: one episode at a time."""
        return cls(f"dtps:{address}", kind="robot", command=str(address), nodes=1,
                   options=options.items() if options is not None else (), frame_rate=float(frame_rate), link="dtps")

    def node_options(self):
        """The ``RobotNodeOptions`` of a robot domain (``DtpsRobotOptions`` of a DTPS robot)."""
        if self.link == "dtps":
            from proxybench.dtps.robot_options import DtpsRobotOptions

            return DtpsRobotOptions(**dict(self.options))
        from proxybench.protocol.options import RobotNodeOptions

        return RobotNodeOptions(**dict(self.options))

    def __post_init__(self) -> None:
        if self.kind not in DOMAIN_KINDS:
            raise ValueError(f"DomainSpec {self.name!r}: kind must be one of {', '.join(DOMAIN_KINDS)}, got "
                             f"{str(self.kind)!r}")
        object.__setattr__(self, "kind", DomainKind(self.kind))  # a member, given its string or itself
        if self.link not in ("protocol", "dtps") or (self.link == "dtps" and self.kind is not DomainKind.ROBOT):
            raise ValueError(f"DomainSpec {self.name!r}: link must be 'protocol', or 'dtps' for a robot domain, got "
                             f"{self.link!r} ({self.kind})")
        if self.kind is DomainKind.ROBOT:
            if not (isinstance(self.command, str) and self.command.strip()):
                raise ValueError(f"DomainSpec {self.name!r}: a robot domain needs command= (the robot node to start)")
            if self.params is not None:
                raise ValueError(f"DomainSpec {self.name!r}: a robot domain takes no params (the robot's θ is its "
                                 f"own; pass settings in its command)")
            if not (isinstance(self.nodes, int) and self.nodes >= 1):
                raise ValueError(f"DomainSpec {self.name!r}: nodes must be a positive integer, got {self.nodes!r}")
            return
        if self.command is not None or self.options:
            raise ValueError(f"DomainSpec {self.name!r}: command= and options= are only for kind='robot', not "
                             f"{self.kind!r}")
        if self.params is None:
            object.__setattr__(self, "params", DomainParams())
        elif not isinstance(self.params, DomainParams):  # θ crosses the job seam validated, once
            raise TypeError(f"DomainSpec {self.name!r}: params must be a DomainParams, got "
                            f"{type(self.params).__name__} (build one with DomainParams.model_validate)")

    def canonical(self) -> str:
        """What identifies the domain in a job's key: θ as JSON (``{}`` for a robot), the kind, and a robot's
        command, working directory and rate where they are set (so older keys stay valid)."""
        params = self.params.model_dump(mode="json") if self.params is not None else {}
        doc: dict[str, Any] = {"params": params, "kind": self.kind}
        if self.command is not None:  # absent otherwise, so simulated domains keep their keys
            doc["command"] = self.command
        cwd = dict(self.options).get("cwd")
        if cwd is not None:  # absent otherwise, so robot domains without one keep their keys
            doc["cwd"] = cwd
        if self.kind is DomainKind.ROBOT and self.frame_rate != DEFAULT_FRAME_RATE:  # likewise
            doc["frame_rate"] = self.frame_rate
        if self.link != "protocol":  # likewise; what changes a DTPS robot's episodes is part of its key
            doc["link"] = self.link
            doc["dtps"] = self.node_options().key_data()
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
        if self.domain.kind is DomainKind.ROBOT and self.npcs is not None and not self.npcs.empty:
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
    termination: Termination
    trajectory: str | None
    message: str = ""
    timings: dict[str, float] = field(default_factory=dict)
    streams: str | None = None  # folder of the episode's fixed-camera streams, if it recorded any

    def __post_init__(self) -> None:
        self.termination = Termination(self.termination)  # a member, given its string (an unknown one raises)

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @staticmethod
    def from_json(text: str) -> JobResult:
        return JobResult(**json.loads(text))


def _agent_id(spec: AgentSpec) -> dict[str, Any]:
    """What identifies an agent in a key: its spec, and for a behaviour-cloning checkpoint (a path given as
    the name) the content of its files, so that retraining into the same path invalidates cached episodes.
    A node command is identified by its string only (like a robot's: what was asked)."""
    from proxybench.agents.kinds import kinds
    from proxybench.agents.zoo import ZOO

    out = spec.key_data()
    if spec.command is None and spec.name not in ZOO:
        for kind_name, kind in kinds():
            if kind.claims(spec.name):
                out[kind_name] = kind.identity(spec.name)  # "checkpoint": as before, so cached keys stay valid
                break
    return out


def _map_id(name: str) -> str:
    """Maps by name are built-in; a file path is identified by its content, so edits invalidate caches."""
    p = Path(name)
    if p.suffix in (".yaml", ".yml") and p.exists():
        return hashlib.sha256(p.read_bytes()).hexdigest()[:16]
    return name


def batch_group(job: Job) -> tuple:
    """Jobs with equal groups can share one batched simulator: same domain, map, NPCs, length and rules, and
    agents that see alike (all privileged or all camera); in-process agents may differ robot by robot. A node
    agent groups only with itself. Jobs on one robot domain share a node process whatever their agent, map
    or length (one after another).
    """
    if job.domain.kind is DomainKind.ROBOT:
        return (DomainKind.ROBOT, job.domain.canonical())
    who = job.agent if job.agent.command else ("in-process", is_privileged(job.agent))
    return (who, job.domain.canonical(), job.map, job.duration, job.camera_only, job.metrics, job.npcs, job.streams)


def is_privileged(spec: AgentSpec) -> bool:
    """Whether the agent a spec names reads the true lane pose, without starting it: a zoo agent's flag, an SDK
    agent's ``privileged`` option; False for node agents and checkpoints (camera only)."""
    from proxybench.agents.zoo import ZOO

    if spec.protocol == "sdk":
        return bool(dict(spec.options).get("privileged", False))
    return bool(spec.command is None and spec.name in ZOO and ZOO[spec.name].privileged)
