"""duckietown-sdk agent packages in the evaluator's sandbox (docs/dtps.md, "Agent packages").

The program runs as the agent user in bubblewrap; its virtual robot (the DTPS bridge) serves in a network
namespace of its own as ``nobody``, which the sandbox joins: the agent finds the robot at 127.0.0.1:7501,
reaches nothing else and sees no process of the host. Needs the SDK environment and the safe sandbox.
"""

from __future__ import annotations

import os
import pwd
import shutil
import socket
from pathlib import Path

import pytest

from proxybench.cli.autolab_demo import LANE_AGENT
from proxybench.protocol.package import AgentManifest, PackageError, check_archive
from support.dtps import sdk
from support.sandbox import AGENT_USER_GROUP, require_safe_sandbox

pytestmark = AGENT_USER_GROUP  # its agents and evaluators run as the agent user: one test at a time

AGENTS = Path(__file__).parent / "dtps_agents"


def test_an_sdk_manifest_takes_timing_and_refuses_aido_transports():
    assert AgentManifest(name="m", protocol="duckietown-sdk", command="python3 a.py", timing="lockstep").timing
    with pytest.raises(ValueError, match="transport"):
        AgentManifest(name="m", protocol="duckietown-sdk", command="python3 a.py", transport="fifo")
    with pytest.raises(ValueError, match="timing: only for protocol duckietown-sdk"):
        AgentManifest(name="m", protocol="aido-z2", command="python3 a.py", timing="lockstep")


def test_an_sdk_package_archive_is_accepted(tmp_path):
    import io
    import zipfile

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("proxybench-agent.yaml", "name: mine\nprotocol: duckietown-sdk\ncommand: python3 lane.py\n")
        zf.writestr("lane.py", LANE_AGENT)
    assert check_archive(buf.getvalue()).protocol == "duckietown-sdk"
    with pytest.raises(PackageError, match="protocol"):
        bad = io.BytesIO()
        with zipfile.ZipFile(bad, "w") as zf:
            zf.writestr("proxybench-agent.yaml", "name: m\nprotocol: ros\ncommand: python3 a.py\n")
        check_archive(bad.getvalue())


@sdk
def test_an_sdk_package_drives_from_its_sandbox_and_reaches_only_its_robot(tmp_path):
    from proxybench.domain.params import DomainParams
    from proxybench.domain.simulator import Simulator
    from proxybench.evaluator import sandbox as sb
    from proxybench.runner.episode import run_episode
    from proxybench.runner.jobs import SdkProgram
    from proxybench.runner.outcomes import camera_filter, make_agent_for

    isolation = require_safe_sandbox()
    package = tmp_path / "agent"
    package.mkdir(mode=0o755)
    shutil.copy(AGENTS / "sandboxed.py", package / "sandboxed.py")
    (package / "lane.py").write_text(LANE_AGENT)  # the Autolab demo's lane follower, which sandboxed.py runs
    for name in ("lane.py", "sandboxed.py"):
        (package / name).chmod(0o644)
    with socket.socket() as host:  # a port on the host's loopback the agent must not reach
        host.bind(("127.0.0.1", 0))
        host.listen()
        manifest = AgentManifest(name="sdk-pkg", protocol="duckietown-sdk", timing="lockstep", start_timeout=90,
                                 command=["python3", "sandboxed.py", str(host.getsockname()[1])])
        spec = sb.package_spec(manifest, package, sb.Limits(), isolation)
        assert isinstance(spec, SdkProgram) and dict(spec.options)["own_netns"] is True
        agent = make_agent_for(spec)
        try:
            sim = Simulator("loop_3x3", DomainParams(image_width=160, image_height=120))
            traj = run_episode(sim, agent, 3, 1.5, image_filter=camera_filter())
            assert traj.termination == "timeout", traj.events  # exit 3/4/5 would be an agent_failure saying which
            assert agent.stats()["frames_answered"] == round(1.5 * 15) - 1
            bridge = agent.robot.link.pid
            assert os.stat(f"/proc/{bridge}").st_uid == pwd.getpwnam("nobody").pw_uid  # not root, not the agent
            assert os.readlink(f"/proc/{bridge}/ns/net") != os.readlink("/proc/self/ns/net")
        finally:
            agent.close()
