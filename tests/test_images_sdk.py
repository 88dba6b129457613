"""A duckietown-sdk agent as a container image (issue 37 item 4b): the image carries its own SDK (duckietown-sdk,
dtps-http and their dependencies at /opt/sdk, on PYTHONPATH) and runs it on its own Debian interpreter; its labels
say ``protocol: duckietown-sdk``. It reaches its virtual DB21J at 127.0.0.1:7501 as it would a Duckiebot on the
Duckiematrix: the sandbox (the image's root file system as ``/``) joins the bridge's network namespace, so it
reaches nothing else, sees no process of the host, and nothing it started is left.

The test image's SDK is this host's SDK environment's site-packages (``proxybench dtps setup``) copied into the
image (the same CPython 3.11 ABI as Debian 12's python3), without what the SDK never imports (scipy, matplotlib,
lxml, pip, …), with Debian's libturbojpeg0 (the SDK's JPEG decoder) and libstdc++6 (numpy's wheel).
"""

from __future__ import annotations

import os
import pwd
import socket
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from proxybench.cli.autolab_demo import LANE_AGENT
from proxybench.evaluator.image_agent import image_spec
from proxybench.evaluator.sandbox import Limits
from support.dtps import sdk
from support.images import PACKAGES, agent_image
from support.sandbox import AGENT_USER_GROUP, processes_left, require_safe_sandbox
from test_evaluator import Served, evaluator, the_job
from test_evaluator import served as served_fixture  # noqa: F401 - the fixture, under this name

pytestmark = [AGENT_USER_GROUP, sdk]  # its agents run as the agent user: one test at a time
AGENTS = Path(__file__).parent / "dtps_agents"
SDK_AGENT = Path(__file__).with_name("image_agents") / "sdk_agent.py"
#: never imported by a duckietown-sdk program (checked: `import duckietown.sdk.robots.duckiebot` loads none)
LEAVE_OUT = ("scipy", "scipy.libs", "matplotlib", "mpl_toolkits", "fontTools", "lxml", "kiwisolver", "contourpy",
             "pip", "__pycache__")


def _site_packages() -> Path:
    from proxybench.dtps.env import env_path

    (found,) = env_path().glob("lib/python3*/site-packages")
    return found


@pytest.fixture(scope="module")
def image(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, socket.socket]]:
    """The SDK image (its ENTRYPOINT given a port on the host's loopback that it must not reach) and that port's
    listener."""
    require_safe_sandbox()
    root = tmp_path_factory.mktemp("sdk-image")
    with socket.socket() as host:
        host.bind(("127.0.0.1", 0))
        host.listen()
        host.setblocking(False)
        files = {"sandboxed.py": (AGENTS / "sandboxed.py").read_bytes(), "lane.py": LANE_AGENT.encode()}
        layout = agent_image(root / "sdk", SDK_AGENT, args=(str(host.getsockname()[1]),), files=files,
                             packages=(*PACKAGES, "libturbojpeg0", "libstdc++6"),
                             trees={"opt/sdk": (_site_packages(), LEAVE_OUT)},
                             env={"PYTHONPATH": "/opt/sdk"}, user="1000:1000",
                             labels={"org.proxybench.agent.protocol": "duckietown-sdk",
                                     "org.proxybench.agent.timing": "lockstep",
                                     "org.proxybench.agent.start_timeout": "90"})
        yield layout, host


def test_an_sdk_image_drives_its_virtual_robot_and_reaches_nothing_else(
        image: tuple[Path, socket.socket], tmp_path: Path) -> None:
    from proxybench.domain.params import DomainParams
    from proxybench.domain.simulator import Simulator
    from proxybench.runner.episode import run_episode
    from proxybench.runner.jobs import SdkProgram
    from proxybench.runner.outcomes import camera_filter, make_agent_for

    isolation = require_safe_sandbox()
    layout, host = image
    spec = image_spec("sdk-image", layout, isolation, cache=tmp_path / "cache", limits=Limits())
    assert isinstance(spec, SdkProgram) and dict(spec.options)["own_netns"] is True
    assert dict(spec.options)["timing"] == "lockstep" and "--rootfs" in spec.command
    agent = make_agent_for(spec)
    try:
        sim = Simulator("loop_3x3", DomainParams(image_width=160, image_height=120))
        traj = run_episode(sim, agent, 3, 1.5, image_filter=camera_filter())
        # exit 6: not the image's interpreter or SDK; 3/4/5: saw a host process, reached the host, found no robot
        assert traj.termination == "timeout", (traj.events, getattr(agent.failure, "stderr_tail", None))
        assert agent.stats()["frames_answered"] == round(1.5 * 15) - 1
        bridge = agent.robot.link.pid
        assert os.stat(f"/proc/{bridge}").st_uid == pwd.getpwnam("nobody").pw_uid  # not root, not the agent
        assert os.readlink(f"/proc/{bridge}/ns/net") != os.readlink("/proc/self/ns/net")
    finally:
        agent.close()
    with pytest.raises(BlockingIOError):
        host.accept()  # it never reached the host's loopback
    assert processes_left(isolation.uid) == []


def test_an_sdk_image_submitted_to_the_server_is_evaluated_and_ranked(
        served_fixture: Served, image: tuple[Path, socket.socket], tmp_path: Path,  # noqa: F811
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The same image as an OCI archive (~57 MB: under the server's 64 MiB default) through the whole chain: upload,
    the server's check, a lease, the evaluator's unpack into its cache, the SDK program driving its virtual robot
    in the benchmark's episodes, the leaderboard."""
    served = served_fixture
    monkeypatch.setenv("PROXYBENCH_IMAGE_CACHE", str(tmp_path / "image-cache"))
    layout, host = image
    archive = tmp_path / "sdk.tar"
    subprocess.run(["skopeo", "--insecure-policy", "copy", "-q", f"oci:{layout}:latest", f"oci-archive:{archive}"],
                   check=True)
    sub = served.developer.submit_archive(archive, "sdk-image", benchmark="tiny_open")
    ev = evaluator(served, tmp_path, video=False)
    assert ev.take_one() == "success"
    job, (result,) = the_job(served, sub["id"])
    assert job["status"] == "success", job["message"]
    report = result["public_report"]
    assert report["agent_contract"]["checks"][0]["passed"]  # its commands reached the benchmark's robot
    assert [e["termination"] for e in report["episodes"]] == ["timeout"] * 2, report["episodes"]
    assert [r["label"] for r in served.developer.leaderboard("tiny_open")["rows"]] == ["sdk-image"]
    with pytest.raises(BlockingIOError):
        host.accept()
    assert processes_left(require_safe_sandbox().uid) == []
