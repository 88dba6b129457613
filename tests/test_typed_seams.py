"""The typed seams (issue 22): enums and records in code, the same strings and keys in files as before."""

from __future__ import annotations

import json
import pickle
import typing

import numpy as np
import pyarrow.parquet as pq
import pytest
from pydantic import ValidationError

from proxybench.contract import Lease
from proxybench.domain.kinds import ROBOT_NODE, DomainKind, robot_node_kind
from proxybench.domain.maps import load_map
from proxybench.domain.params import DomainParams
from proxybench.evaluator.job import WorkerJob
from proxybench.runner.jobs import (
    AgentSpec,
    DomainSpec,
    DtpsLink,
    InProcessAgent,
    Job,
    JobResult,
    NodeAgent,
    ProtocolLink,
    RobotDomain,
    SdkProgram,
    SimDomain,
)
from proxybench.targets.manifest import SOURCE_KINDS, SOURCES, TargetManifest, source_of
from proxybench.targets.robot import RobotTarget
from proxybench.targets.spec import RealityTarget
from proxybench.tasks.trajectory import TERMINATIONS, Event, Termination, Trajectory, TrajectoryError
from support.jobs import worker_job


@pytest.fixture(scope="module")
def road():
    return load_map("straight_road")


def _traj(road, **kw) -> Trajectory:
    t = np.arange(0.0, 1.0, 0.05)
    pose = np.stack([0.3 + 0.2 * t, np.full_like(t, 0.68), np.zeros_like(t)], axis=1)
    return Trajectory.from_poses(road, t, pose, **kw)


# -- Termination ---------------------------------------------------------------------------------------------

def test_terminations_keep_the_strings_files_hold():
    assert [str(t) for t in Termination] == ["timeout", "off_road", "left_map", "collision", "agent_failure", "reset",
                                             "ended_early", "robot_failure"]
    assert Termination.TIMEOUT == "timeout" and json.dumps({"t": Termination.COLLISION}) == '{"t": "collision"}'
    assert Termination.ROBOT_FAILURE not in TERMINATIONS  # a failed robot leaves no trajectory


def test_trajectory_file_holds_the_string_and_loads_the_member(road, tmp_path):
    path = _traj(road, termination="collision").save(tmp_path / "a.parquet")
    block = json.loads(pq.read_schema(path).metadata[b"proxybench"])
    assert block["termination"] == "collision"
    assert Trajectory.load(path).termination is Termination.COLLISION


def test_a_file_with_an_unknown_termination_is_refused_by_name(road, tmp_path):
    path = _traj(road).save(tmp_path / "a.parquet")
    table = pq.read_table(path)
    block = json.loads(table.schema.metadata[b"proxybench"])
    block["termination"] = "exploded"
    pq.write_table(table.replace_schema_metadata({b"proxybench": json.dumps(block).encode()}), path)
    with pytest.raises(TrajectoryError, match=r"a\.parquet: unknown termination 'exploded'"):
        Trajectory.load(path)
    with pytest.raises(TrajectoryError, match="unknown termination 'robot_failure'"):
        _traj(road, termination="robot_failure")


def test_job_results_round_trip_their_termination():
    res = JobResult("k", "pid", "d", 0, 1, {"survival_time": 1.0}, Termination.OFF_ROAD, None)
    text = res.to_json()
    assert json.loads(text)["termination"] == "off_road"
    assert JobResult.from_json(text).termination is Termination.OFF_ROAD
    with pytest.raises(ValueError):  # a damaged record is redone by the sweep, never trusted
        JobResult.from_json(text.replace("off_road", "melted"))


# -- Event ---------------------------------------------------------------------------------------------------

def test_events_keep_their_file_form(road, tmp_path):
    """The objects in a file's ``events`` list are read into records and written back as they were."""
    raw = [{"t": 0.5, "kind": "agent_failure", "message": "AgentFailure: died", "reason": "exited", "exit_code": 3,
            "stderr_tail": ["Traceback", "boom"]},
           {"t": 0.7, "kind": "collision", "message": "the robot came too close to a duckie", "with": "duckie"},
           {"t": 0.9, "kind": "npc_stopped", "message": "NPC robot 0 (pid) stopped", "npc": 0},
           {"t": 1.0, "kind": "tracking_lost", "message": "", "camera": 4}]  # another writer's field, kept
    events = [Event.from_dict(d) for d in raw]
    assert [e.to_dict() for e in events] == raw
    assert events[0].stderr_tail == ("Traceback", "boom") and events[1].kind is Termination.COLLISION
    path = _traj(road, events=events).save(tmp_path / "a.parquet")
    assert json.loads(pq.read_schema(path).metadata[b"proxybench"])["events"] == raw
    back = Trajectory.load(path)
    assert back.events == events and back.failure == events[0] and back.event("collision").with_ == "duckie"
    assert _traj(road).failure is None


@pytest.mark.parametrize(("bad", "field"), [({"kind": "x"}, "'t'"), ({"t": 1.0}, "'kind'"),
                                             ({"t": 1.0, "kind": "x", "exit_code": "3"}, "'exit_code'"),
                                             ({"t": 1.0, "kind": "x", "stderr_tail": "boom"}, "'stderr_tail'")])
def test_a_malformed_event_is_refused_naming_file_event_and_field(road, tmp_path, bad, field):
    path = _traj(road).save(tmp_path / "a.parquet")
    table = pq.read_table(path)
    block = json.loads(table.schema.metadata[b"proxybench"])
    block["events"] = [{"t": 0.0, "kind": "note", "message": "fine"}, bad]
    pq.write_table(table.replace_schema_metadata({b"proxybench": json.dumps(block).encode()}), path)
    with pytest.raises(TrajectoryError, match=rf"a\.parquet: event 1: event field {field}"):
        Trajectory.load(path)


# -- DomainKind ----------------------------------------------------------------------------------------------

def test_one_domain_kind_vocabulary_with_the_strings_files_hold():
    assert [str(k) for k in DomainKind] == ["simulation", "reality-model", "robot", "recorded"]
    spec = DomainSpec("r", kind="reality-model")  # a string from a file or an old caller: held as the member
    assert spec.kind is DomainKind.REALITY_MODEL and '"kind": "reality-model"' in spec.canonical()
    assert DomainSpec.robot("bridge", frame_rate=15.0).kind is DomainKind.ROBOT
    with pytest.raises(ValueError, match=r"kind must be one of simulation, reality-model \(a simulated domain\), got "
                                         r"'recorded'"):
        DomainSpec("x", kind=DomainKind.RECORDED)  # a recording is read, never run
    assert robot_node_kind("simulation") == "robot-node/simulation"


def test_the_manifest_keeps_its_words_through_a_documented_mapping():
    """A recording's source says real | reality-model | robot-node | simulation: each maps to a DomainKind but
    ``real`` (physical robots recorded outside proxybench), and recordings proxybench makes write the words back."""
    assert set(typing.get_args(TargetManifest.model_fields["source"].annotation)) == set(SOURCE_KINDS) == set(SOURCES)
    assert SOURCE_KINDS["real"] is None and SOURCE_KINDS[ROBOT_NODE] is DomainKind.ROBOT
    for kind in (DomainKind.SIMULATION, DomainKind.REALITY_MODEL, DomainKind.ROBOT):
        assert SOURCE_KINDS[source_of(kind)] is kind
    m = TargetManifest(source="robot-node", map="loop_3x3", seconds=5, agents=["pid"], episodes=[0],
                       robot={"command": "bridge"})
    assert m.domain_kind is DomainKind.ROBOT and m.simulated


def test_targets_say_their_kind_as_a_member():
    assert RealityTarget().info().kind is DomainKind.REALITY_MODEL
    assert RobotTarget("bridge").info().kind is DomainKind.ROBOT


# -- DomainSpec.params ---------------------------------------------------------------------------------------

def test_theta_crosses_the_job_seam_typed_and_keys_stay_as_they_were():
    theta = DomainParams(trim=0.1, image_width=80, image_height=60, light_rgb=(0.9, 1.0, 1.1))
    spec = DomainSpec("trim=0.1", theta)
    assert spec.params is theta and DomainSpec("d").params == DomainParams()
    # the key serialises θ exactly as the dict of its fields did before DomainSpec.params was typed
    assert spec.canonical() == json.dumps({"params": theta.model_dump(mode="json"), "kind": "simulation"},
                                          sort_keys=True)
    assert json.loads(DomainSpec.robot("bridge", frame_rate=15.0).canonical())["params"] == {}
    with pytest.raises(TypeError, match="params must be a DomainParams, got dict"):
        DomainSpec("x", {"trim": 0.1})
    with pytest.raises(TypeError, match="a simulated domain, not command"):  # a robot's θ is its own
        DomainSpec("r", theta, kind="robot", command="bridge")


def test_domain_specs_hash_by_value_in_sets_and_job_keys():
    a = DomainSpec("p", DomainParams(trim=0.1))
    b = DomainSpec("p", DomainParams(trim=0.1))
    c = DomainSpec("p", DomainParams(trim=0.2))
    assert a == b and hash(a) == hash(b) and len({a, b, c}) == 2 and {a: 1}[b] == 1
    job = Job(AgentSpec("pid"), a, "loop_3x3", 0, 1, 2.0)
    assert job.key == Job(AgentSpec("pid"), b, "loop_3x3", 0, 1, 2.0).key != \
        Job(AgentSpec("pid"), c, "loop_3x3", 0, 1, 2.0).key
    assert pickle.loads(pickle.dumps(job)).domain == a  # what a process pool carries


# -- AgentSpec / DomainSpec: tagged unions -------------------------------------------------------------------

def _specs():
    from proxybench.dtps.options import SdkOptions
    from proxybench.dtps.robot_options import DtpsRobotOptions, parse_address
    from proxybench.protocol.options import NodeOptions, RobotNodeOptions

    agents = [AgentSpec("pid"), AgentSpec.node("n", "python3 n.py", NodeOptions(cwd="/tmp", step_timeout=2.0)),
              AgentSpec.sdk("s", "python3 s.py", SdkOptions(timing="lockstep", privileged=True))]
    domains = [DomainSpec("p", DomainParams(trim=0.1)), DomainSpec("r", DomainParams(trim=0.05), "reality-model"),
               DomainSpec.robot("bridge", frame_rate=30, nodes=2, options=RobotNodeOptions(cwd="/opt/b")),
               DomainSpec.dtps(parse_address("dtps:bot.local/bot"), frame_rate=15,
                               options=DtpsRobotOptions(reset="teleport", pose_tolerance=(0.1, 0.3)))]
    return agents, domains


def test_each_flavour_holds_only_what_it_needs():
    agents, domains = _specs()
    assert [type(a) for a in agents] == [InProcessAgent, NodeAgent, SdkProgram]  # AgentSpec(name): in-process
    assert [type(d) for d in domains] == [SimDomain, SimDomain, RobotDomain, RobotDomain]
    assert all(isinstance(a, AgentSpec) for a in agents) and all(isinstance(d, DomainSpec) for d in domains)
    assert agents[0].command is None and not hasattr(agents[0], "options")
    assert AgentSpec.node("a", "x") != AgentSpec.sdk("a", "x")  # the same command speaking another protocol
    robot, dtps = domains[2:]
    assert (robot.kind, robot.params, robot.nodes, robot.link) == ("robot", None, 2,
                                                                  ProtocolLink("bridge", (("cwd", "/opt/b"),), 2))
    assert isinstance(dtps.link, DtpsLink) and dtps.nodes == 1 and dtps.command == "bot.local:11911/bot"
    with pytest.raises(ValueError, match="command must be a non-empty string"):
        AgentSpec.node("a", " ")
    with pytest.raises(TypeError, match="positional argument"):
        AgentSpec("a", "python3 a.py")  # a node is AgentSpec.node(NAME, COMMAND)


def test_specs_keep_the_key_data_they_had_as_one_class_of_flags():
    agents, domains = _specs()
    assert [a.key_data() for a in agents] == [
        {"name": "pid", "command": None},
        {"name": "n", "command": "python3 n.py", "options": {"cwd": "/tmp", "step_timeout": 2.0}},
        {"name": "s", "command": "python3 s.py", "options": {"privileged": True, "timing": "lockstep"},
         "protocol": "sdk"}]
    assert [json.loads(d.canonical()) for d in domains[2:]] == [
        {"params": {}, "kind": "robot", "command": "bridge", "cwd": "/opt/b", "frame_rate": 30.0},
        {"params": {}, "kind": "robot", "command": "bot.local:11911/bot", "link": "dtps",
         "dtps": {"reset": "teleport"}}]


def test_specs_round_trip_through_pickle_and_json():
    agents, domains = _specs()
    for spec in agents:
        assert pickle.loads(pickle.dumps(spec)) == spec == AgentSpec.from_dict(json.loads(json.dumps(spec.to_dict())))
    for spec in domains:
        assert pickle.loads(pickle.dumps(spec)) == spec == DomainSpec.from_dict(json.loads(json.dumps(spec.to_dict())))
    job = Job(agents[2], domains[3], "loop_3x3", 0, 1, 2.0)
    assert pickle.loads(pickle.dumps(job)).key == job.key


# -- the evaluator's lease -----------------------------------------------------------------------------------

def test_the_lease_reaches_the_worker_typed(tmp_path):
    """The server's lease reply → the loop's Lease → job.json (the model's own JSON) → the worker's Lease."""
    reply = {"job_id": 7, "lease_id": "ab12", "lease_seconds": 30, "attempt": 2, "features": ["sim", "target"],
             "submission": {"id": 3, "label": "mine", "archive_sha256": "0" * 64, "manifest": {"name": "pkg"}},
             "benchmark": {"name": "aido_lf", "version": 4, "spec_yaml": "name: aido_lf\n", "test_seed": 99},
             "a_field_of_a_newer_server": 1}
    lease = Lease.model_validate(reply)
    job = worker_job(robot_options={"cwd": "/lab"}).model_copy(update={"lease": lease, "job_features": ["target"]})
    back = WorkerJob.read(job.write(tmp_path / "job.json"))
    assert back == job and isinstance(back.lease, Lease) and back.lease.benchmark.test_seed == 99
    assert back.lease.submission.manifest == {"name": "pkg"} and back.isolation == job.isolation
    text = (tmp_path / "job.json").read_text().replace('"lease_seconds": 30.0', '"lease_seconds": "soon"')
    (tmp_path / "job.json").write_text(text)
    with pytest.raises(ValidationError, match=r"lease\.lease_seconds"):
        WorkerJob.read(tmp_path / "job.json")
