"""What a unit of evaluation work is: one agent, one domain, one episode (how a worker does it: :mod:`.execute`).

A ``Job`` is plain data (picklable, JSON-able), so any backend (process pool, Ray cluster) can carry it;
its ``key`` is a content hash of everything that determines the result (agent spec, θ, map, episode,
duration, code version; the content of map files and of checkpoint agents), which is what makes sweeps
cacheable and resumable.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field, fields
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from proxybench import __version__
from proxybench.domain.events import Termination
from proxybench.domain.kinds import DomainKind
from proxybench.domain.params import DomainParams

if TYPE_CHECKING:
    from proxybench.domain.npcs import Traffic
    from proxybench.dtps.robot_options import DtpsAddress
    from proxybench.runner.streams import StreamSpec

#: bump when what an episode produces changes without a change of its inputs (it is part of every job key)
ENGINE_VERSION = 6  # 2: camera agents see JPEG-decoded frames, as over the AIDO protocol; 3: intersection routes;
# 4: NPC robots and pedestrians simulated (benchmark ``npcs:``), object colours and extra duckies in θ;
# 5: the vision agents' lane fit is compiled (closed-form least squares, equal to lstsq within 1e-9, so their
# trajectories can differ in the last bits); 6: floor tags and NPC robots' roof tags drawn as AprilTag 36h11 patterns

__all__ = ["DOMAIN_KINDS", "ENGINE_VERSION", "AgentSpec", "DomainSpec", "DtpsLink", "InProcessAgent", "Job",
           "JobResult", "LabWorldLink", "NodeAgent", "ProtocolLink", "RobotDomain", "SdkProgram", "SimDomain",
           "batch_group", "is_privileged"]


_OPTION_PAIRS = tuple[tuple[str, Any], ...]


def _pairs(options: Any) -> _OPTION_PAIRS:
    """Options (a pydantic options model, or None for the defaults) as the sorted non-default pairs a spec keeps."""
    return options.items() if options is not None else ()


def _nonblank(owner: str, what: str, value: Any) -> None:
    if not (isinstance(value, str) and value.strip()):
        raise ValueError(f"{owner}: {what} must be a non-empty string, got {value!r}")


class AgentSpec:
    """What agent a job plays, one of three flavours (a tagged union: each holds only what it needs):

    - :class:`InProcessAgent` (``name``): made in the worker's process from its name: a zoo agent, or what a
      registered agent kind claims (a behaviour-cloning checkpoint ``X.pt``, :mod:`proxybench.agents.kinds`);
    - :class:`NodeAgent` (``name``, ``command``, ``options``): an AIDO agent node started with ``command`` (any
      language; a string may use shell syntax); ``options``: the non-default fields of
      :class:`~proxybench.protocol.options.NodeOptions` (working directory, transport, timeouts, reflection) as
      sorted pairs, so the spec stays hashable;
    - :class:`SdkProgram` (``name``, ``command``, ``options``): a duckietown-sdk program driving a virtual DB21J
      over DTPS (:mod:`proxybench.dtps`); its options are :class:`~proxybench.dtps.options.SdkOptions`.

    ``AgentSpec(name)`` builds an :class:`InProcessAgent` (as ``Path(…)`` builds a ``PosixPath``);
    :meth:`node` and :meth:`sdk` build the others from their options models. Every flavour has ``name``,
    ``label`` and ``command`` (None in-process); :meth:`to_dict` / :meth:`from_dict` are its JSON form.
    """

    TAG: ClassVar[str]
    name: str
    command: str | None

    def __new__(cls, *args: Any, **kwargs: Any):
        return object.__new__(InProcessAgent if cls is AgentSpec else cls)  # its __init__ takes the arguments

    @staticmethod
    def node(name: str, command: str, options: Any = None) -> NodeAgent:
        """A node agent; ``options``: a ``NodeOptions`` (or None for the defaults)."""
        return NodeAgent(name, command, _pairs(options))

    @staticmethod
    def sdk(name: str, command: str, options: Any = None) -> SdkProgram:
        """A duckietown-sdk agent program; ``options``: an ``SdkOptions`` (or None for the defaults)."""
        return SdkProgram(name, command, _pairs(options))

    @property
    def label(self) -> str:
        return self.name

    def key_data(self) -> dict[str, Any]:
        """What identifies the agent in a job's hash: its name and command (None in-process), its options and
        protocol only when set (the keys this spec had as one class of flags, kept byte for byte)."""
        raise NotImplementedError

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON data, ``type`` naming the flavour (:meth:`from_dict` reads it back)."""
        out: dict[str, Any] = {"type": self.TAG}
        for f in fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            out[f.name] = dict(value) if f.name == "options" else value
        return out

    @staticmethod
    def from_dict(data: dict[str, Any]) -> AgentSpec:
        flavours = {c.TAG: c for c in (InProcessAgent, NodeAgent, SdkProgram)}
        data = dict(data)
        tag = data.pop("type", None)
        if tag not in flavours:
            raise ValueError(f"agent spec: type must be one of {', '.join(flavours)}, got {tag!r}")
        if "options" in data:
            data["options"] = tuple(sorted(data["options"].items()))
        return flavours[tag](**data)


@dataclass(frozen=True)
class InProcessAgent(AgentSpec):
    """An agent made in the worker's process from its name: a zoo agent or a checkpoint (see :class:`AgentSpec`)."""

    TAG: ClassVar[str] = "in-process"
    name: str
    command: ClassVar[None] = None  # no process of its own

    def key_data(self) -> dict[str, Any]:
        return {"name": self.name, "command": None}


@dataclass(frozen=True)
class _Process(AgentSpec):
    """An agent in a process of its own, started with ``command``: what node agents and SDK programs share."""

    name: str
    command: str
    options: _OPTION_PAIRS = ()

    def __post_init__(self) -> None:
        _nonblank(f"agent {self.name!r}", "command", self.command)

    def key_data(self) -> dict[str, Any]:
        data: dict[str, Any] = {"name": self.name, "command": self.command}
        if self.options:
            data["options"] = dict(self.options)
        return data


@dataclass(frozen=True)
class NodeAgent(_Process):
    """An AIDO agent node started with ``command`` (see :class:`AgentSpec`)."""

    TAG: ClassVar[str] = "node"

    def node_options(self):
        """Its :class:`~proxybench.protocol.options.NodeOptions`."""
        from proxybench.protocol.options import NodeOptions

        return NodeOptions(**dict(self.options))


@dataclass(frozen=True)
class SdkProgram(_Process):
    """A duckietown-sdk program driving a virtual robot over DTPS (see :class:`AgentSpec`): started like a node
    agent, but speaking DTPS, with ``SdkOptions``."""

    TAG: ClassVar[str] = "sdk"

    def node_options(self):
        """Its :class:`~proxybench.dtps.options.SdkOptions`."""
        from proxybench.dtps.options import SdkOptions

        return SdkOptions(**dict(self.options))

    def key_data(self) -> dict[str, Any]:
        return {**super().key_data(), "protocol": "sdk"}


#: [Hz] the camera rate of :class:`~proxybench.domain.params.DomainParams` when nobody sets one
DEFAULT_FRAME_RATE = 15.0
#: what a job's domain can be: a proxy instance S_θ, the built-in reality model, or a robot node (the robot
#: protocol); a recording (``DomainKind.RECORDED``) is read, never run
DOMAIN_KINDS = (DomainKind.SIMULATION, DomainKind.REALITY_MODEL, DomainKind.ROBOT)
#: the kinds of a :class:`SimDomain`
SIM_KINDS = (DomainKind.SIMULATION, DomainKind.REALITY_MODEL)


class DomainSpec:
    """A domain instance a job runs in, one of two flavours (a tagged union: each holds only what it needs):

    - :class:`SimDomain` (``name``, ``params``, ``kind``): our simulator with parameters θ (a
      :class:`DomainParams`; None: the default θ), ``kind`` "simulation" for proxy instances or "reality-model"
      for the built-in stand-in target;
    - :class:`RobotDomain` (``name``, ``link``, ``frame_rate``): a robot, reached by its ``link``: a
      :class:`ProtocolLink` (a robot node process started with a command, docs/robot-protocol.md: a physical
      robot's bridge, another simulator, ``proxybench robot serve``) or a :class:`DtpsLink` (a DTPS robot at an
      address). ``frame_rate`` [Hz]: what the robot is asked to step at (the benchmark's or the proxies' rate; a
      node that says its own rate is stepped at that). Its kind is "robot" and its θ is not ours to set
      (``params`` None); its episodes are cached by *what was asked* (command or address, map, episode, agent),
      not by what the robot is: after changing the robot (recalibration, new firmware), use a fresh run
      directory or delete its cached episodes.

    ``DomainSpec(name, params, kind)`` builds a :class:`SimDomain` (as ``Path(…)`` builds a ``PosixPath``);
    :meth:`robot` and :meth:`dtps` build robot domains. Every flavour has ``name``, ``kind``, ``params`` and
    :meth:`canonical` (what identifies it in a job's key); :meth:`to_dict` / :meth:`from_dict` are its JSON form.
    """

    name: str
    kind: DomainKind
    params: DomainParams | None

    def __new__(cls, *args: Any, **kwargs: Any):
        extra = set(kwargs) - {"name", "params", "kind"} if cls is DomainSpec else ()
        if extra:
            raise TypeError(f"DomainSpec(name, params, kind) is a simulated domain, not {', '.join(sorted(extra))}: "
                            f"a robot is DomainSpec.robot(COMMAND, frame_rate=…) or DomainSpec.dtps(ADDRESS, "
                            f"frame_rate=…)")
        return object.__new__(SimDomain if cls is DomainSpec else cls)  # its __init__ takes the arguments

    @staticmethod
    def robot(command: str, *, frame_rate: float, name: str | None = None, nodes: int = 1,
              options: Any = None) -> RobotDomain:
        """A robot node started with ``command``, stepped at ``frame_rate`` [Hz]; ``options``: a
        ``RobotNodeOptions`` (or None for the defaults); ``nodes``: see :class:`ProtocolLink`."""
        return RobotDomain(name or f"robot:{command}", ProtocolLink(command, _pairs(options), nodes),
                           float(frame_rate))

    @staticmethod
    def dtps(address: Any, *, frame_rate: float, options: Any = None) -> RobotDomain:
        """The DTPS robot at ``address`` (a ``DtpsAddress``) stepped at ``frame_rate`` [Hz]; ``options``: a
        ``DtpsRobotOptions`` (or None for the defaults). One robot: one episode at a time."""
        return RobotDomain(f"dtps:{address}", DtpsLink(address, _pairs(options)), float(frame_rate))

    def canonical(self) -> str:
        """What identifies the domain in a job's key, as JSON: θ (``{}`` for a robot) and the kind; a robot's
        command or address, working directory, rate and DTPS settings where they are set (the keys this spec
        had as one class of flags, kept byte for byte)."""
        raise NotImplementedError

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON data, ``type`` naming the flavour (:meth:`from_dict` reads it back)."""
        raise NotImplementedError

    @staticmethod
    def from_dict(data: dict[str, Any]) -> DomainSpec:
        data = dict(data)
        tag = data.pop("type", None)
        if tag == "simulated":
            params = data.pop("params", None)
            return SimDomain(params=None if params is None else DomainParams.model_validate(params), **data)
        if tag == "robot":
            link = dict(data.pop("link"))
            how = link.pop("type", None)
            options = tuple(sorted((k, tuple(v) if isinstance(v, list) else v)
                                   for k, v in link.pop("options", {}).items()))
            if how == "protocol":
                return RobotDomain(link=ProtocolLink(options=options, **link), **data)
            if how == "dtps":
                return RobotDomain(link=DtpsLink(link["address"], options), **data)
            if how == "lab-world":
                params = DomainParams.model_validate(link.pop("params"))
                return RobotDomain(link=LabWorldLink(params=params, **link), **data)
            raise ValueError(f"robot domain: link type must be protocol or dtps, got {how!r}")
        raise ValueError(f"domain spec: type must be simulated or robot, got {tag!r}")


@dataclass(frozen=True)
class SimDomain(DomainSpec):
    """Our simulator with parameters θ, as a proxy instance or as the reality model (see :class:`DomainSpec`)."""

    name: str
    params: DomainParams | None = None  # None: the default θ (held as DomainParams() once built)
    kind: DomainKind = DomainKind.SIMULATION

    def __post_init__(self) -> None:
        if self.kind not in SIM_KINDS:
            hint = (": a robot is DomainSpec.robot(COMMAND, frame_rate=…) or DomainSpec.dtps(…)"
                    if self.kind == DomainKind.ROBOT else "")
            raise ValueError(f"DomainSpec {self.name!r}: kind must be one of {', '.join(SIM_KINDS)} (a simulated "
                             f"domain), got {str(self.kind)!r}{hint}")
        object.__setattr__(self, "kind", DomainKind(self.kind))  # a member, given its string or itself
        if self.params is None:
            object.__setattr__(self, "params", DomainParams())
        elif not isinstance(self.params, DomainParams):  # θ crosses the job seam validated, once
            raise TypeError(f"DomainSpec {self.name!r}: params must be a DomainParams, got "
                            f"{type(self.params).__name__} (build one with DomainParams.model_validate)")

    def canonical(self) -> str:
        return json.dumps({"params": self.params.model_dump(mode="json"), "kind": self.kind}, sort_keys=True)

    def to_dict(self) -> dict[str, Any]:
        return {"type": "simulated", "name": self.name, "kind": str(self.kind),
                "params": self.params.model_dump(mode="json")}


@dataclass(frozen=True)
class ProtocolLink:
    """A robot node process started with ``command``, spoken to over the robot protocol. ``options``: how to
    start and talk to it, the non-default fields of :class:`~proxybench.protocol.options.RobotNodeOptions`
    (working directory, transport, timeouts, reflection) as sorted pairs; of them only ``cwd`` is part of the key
    (it changes what the command runs; a timeout or the transport does not change an episode). ``nodes``: how
    many processes of ``command`` may run at once on this machine (one per busy worker, up to this; not part of
    any key): keep 1 for a bridge to one physical robot, raise it for a simulator node."""

    command: str
    options: _OPTION_PAIRS = ()
    nodes: int = 1

    def __post_init__(self) -> None:
        _nonblank("robot node", "command (the robot node to start)", self.command)
        if not (isinstance(self.nodes, int) and self.nodes >= 1):
            raise ValueError(f"robot node {self.command!r}: nodes must be a positive integer, got {self.nodes!r}")

    def node_options(self):
        """Its :class:`~proxybench.protocol.options.RobotNodeOptions`."""
        from proxybench.protocol.options import RobotNodeOptions

        return RobotNodeOptions(**dict(self.options))

    def key_data(self) -> dict[str, Any]:
        data: dict[str, Any] = {"command": self.command}
        cwd = dict(self.options).get("cwd")
        if cwd is not None:  # absent otherwise, so robot domains without one keep their keys
            data["cwd"] = cwd
        return data

    def to_dict(self) -> dict[str, Any]:
        return {"type": "protocol", "command": self.command, "options": dict(self.options), "nodes": self.nodes}


@dataclass(frozen=True)
class DtpsLink:
    """A DTPS robot at ``address`` (a ``DtpsAddress``; its text ``[dtps:]HOST[:PORT]/PATH`` is read into one).
    ``options``: the non-default fields of :class:`~proxybench.dtps.robot_options.DtpsRobotOptions` as sorted
    pairs; what changes its episodes (topics, how episodes start) is part of the key. One robot: one episode at a
    time (``nodes`` is 1)."""

    address: DtpsAddress
    options: _OPTION_PAIRS = ()
    nodes: ClassVar[int] = 1

    def __post_init__(self) -> None:
        if isinstance(self.address, str):
            from proxybench.dtps.robot_options import parse_address

            object.__setattr__(self, "address", parse_address(self.address))

    @property
    def command(self) -> str:
        """The address as text, ``HOST:PORT/PATH``: what was asked, as a node's command is."""
        return str(self.address)

    def node_options(self):
        """Its :class:`~proxybench.dtps.robot_options.DtpsRobotOptions`."""
        from proxybench.dtps.robot_options import DtpsRobotOptions

        return DtpsRobotOptions(**dict(self.options))

    def key_data(self) -> dict[str, Any]:
        return {"command": self.command, "link": "dtps", "dtps": self.node_options().key_data()}

    def to_dict(self) -> dict[str, Any]:
        return {"type": "dtps", "address": self.command, "options": dict(self.options)}


@dataclass(frozen=True)
class LabWorldLink:
    """Robot ``robot`` of a lab's shared world (:mod:`proxybench.runner.lab_world`), served at the Unix socket
    ``path`` to whoever holds ``key`` (hex; never part of a job's key); ``params``: θ of its episodes; ``streams``: the
    folder its episodes' watchtower streams are written under (``<k>/``, the k-th episode; None: none). One robot:
    one episode at a time."""

    path: str
    key: str
    robot: str
    params: DomainParams = field(default_factory=DomainParams)
    streams: str | None = None
    nodes: ClassVar[int] = 1

    def __post_init__(self) -> None:
        _nonblank("lab world", "robot", self.robot)

    @property
    def command(self) -> str:
        return f"lab-world:{self.robot}"

    def key_data(self) -> dict[str, Any]:
        return {"command": self.command, "link": "lab-world", "params": self.params.model_dump(mode="json")}

    def to_dict(self) -> dict[str, Any]:
        return {"type": "lab-world", "path": self.path, "key": self.key, "robot": self.robot,
                "params": self.params.model_dump(mode="json"), "streams": self.streams}


@dataclass(frozen=True)
class RobotDomain(DomainSpec):
    """A robot reached by its ``link``, stepped at ``frame_rate`` [Hz] (see :class:`DomainSpec`)."""

    name: str
    link: ProtocolLink | DtpsLink | LabWorldLink
    frame_rate: float = DEFAULT_FRAME_RATE
    kind: ClassVar[DomainKind] = DomainKind.ROBOT
    params: ClassVar[None] = None  # the robot's θ is its own

    def __post_init__(self) -> None:
        if not isinstance(self.link, ProtocolLink | DtpsLink | LabWorldLink):
            raise TypeError(f"DomainSpec {self.name!r}: link must be a ProtocolLink or a DtpsLink, got "
                            f"{type(self.link).__name__}")

    @property
    def command(self) -> str:
        """What was asked: the node's command, or the DTPS robot's address."""
        return self.link.command

    @property
    def nodes(self) -> int:
        """How many episodes may run on it at once (:class:`ProtocolLink`'s ``nodes``; 1 for a DTPS robot)."""
        return self.link.nodes

    def canonical(self) -> str:
        doc: dict[str, Any] = {"params": {}, "kind": self.kind, **self.link.key_data()}
        if self.frame_rate != DEFAULT_FRAME_RATE:  # absent otherwise, so robots at the default rate keep their keys
            doc["frame_rate"] = self.frame_rate
        return json.dumps(doc, sort_keys=True)

    def to_dict(self) -> dict[str, Any]:
        return {"type": "robot", "name": self.name, "frame_rate": self.frame_rate, "link": self.link.to_dict()}


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
    if isinstance(spec, InProcessAgent) and spec.name not in ZOO:
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
    if isinstance(job.domain, RobotDomain):
        return (DomainKind.ROBOT, job.domain.canonical())
    who = ("in-process", is_privileged(job.agent)) if isinstance(job.agent, InProcessAgent) else job.agent
    return (who, job.domain.canonical(), job.map, job.duration, job.camera_only, job.metrics, job.npcs, job.streams)


def is_privileged(spec: AgentSpec) -> bool:
    """Whether the agent a spec names reads the true lane pose, without starting it: a zoo agent's flag, an SDK
    agent's ``privileged`` option; False for node agents and checkpoints (camera only)."""
    from proxybench.agents.zoo import ZOO

    if isinstance(spec, SdkProgram):
        return bool(dict(spec.options).get("privileged", False))
    return isinstance(spec, InProcessAgent) and spec.name in ZOO and bool(ZOO[spec.name].privileged)
