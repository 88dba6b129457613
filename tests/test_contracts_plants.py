"""The plant contract (proxybench.testing.PlantContract) over the batched simulator plant and robot nodes (the
simulator served by `proxybench robot serve`, a stock-AIDO-like robot); and deliberately broken plants, each
failing the check named for what is wrong with it; and `proxybench robot check`, the same suite for a lab's bridge."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.protocol import jpeg
from proxybench.runner.episode import SimPlant
from proxybench.testing import PlantContract

SMALL = DomainParams(image_width=80, image_height=60)
SERVE = [sys.executable, "-m", "proxybench.cli", "robot", "serve", "--param", "image_width=80", "--param",
         "image_height=60"]
AGENTS = Path(__file__).resolve().parent / "protocol_agents"


def test_the_simulator_plant_keeps_the_contract() -> None:
    report = PlantContract.for_simulator(params=SMALL, n=2).check_all()
    by_name = {r.name: r.reason for r in report.results}
    assert "2 robot(s) started at the requested poses" in by_name["start-pose"]
    assert "80×60 RGB uint8 frames" in by_name["observations"] and "true lane pose" in by_name["observations"]


def test_the_simulator_served_as_a_robot_node_keeps_the_contract() -> None:
    report = PlantContract.for_robot_command(SERVE, image_size=(80, 60)).check_all()
    failure = next(r for r in report.results if r.name == "failure").reason
    assert "killed mid-episode: RobotFailure (exited)" in failure and "started a fresh node" in failure


@pytest.fixture
def stand_in(tmp_path: Path) -> str:
    """A stock-AIDO-like robot (no proxybench extension, no ground truth), as a lab's bridge might be."""
    frame = tmp_path / "frame.jpg"
    frame.write_bytes(jpeg.encode(np.full((60, 80, 3), 90, np.uint8)))
    return f"{sys.executable} {AGENTS / 'aido_robot.py'} {frame}"


def test_robot_check_runs_the_suite_on_a_bridge(stand_in: str) -> None:
    res = CliRunner().invoke(app, ["robot", "check", stand_in, "--seconds", "0.6"])
    assert res.exit_code == 0, res.output
    for name in PlantContract.CHECKS:
        assert f"✓ {name}: " in res.output, res.output
    assert "no ground truth for privileged agents" in res.output and "6 of 6 checks passed" in res.output


def test_robot_check_names_a_node_that_cannot_start() -> None:
    res = CliRunner().invoke(app, ["robot", "check", "/no/such/bridge"])
    assert res.exit_code == 1
    assert "✗ starts: could not make the plant: RobotFailure (start-failed)" in res.output
    assert "not run: the plant did not start" in res.output and "6 failed" in res.output


def test_a_robot_node_that_dies_at_setup_or_mid_episode_is_a_named_failure() -> None:
    at_setup = PlantContract.for_robot_command([sys.executable, str(AGENTS / "misbehave_robot.py"), "crash",
                                                "spawn_robot"]).run()
    starts = at_setup.results[0]
    assert starts.name == "starts" and not starts.passed and "RobotFailure (exited)" in starts.reason
    assert starts.error is not None and "boom: something broke" in "\n".join(starts.error.stderr_tail)
    mid = PlantContract.for_robot_command([sys.executable, str(AGENTS / "misbehave_robot.py"), "crash", "step"])
    with mid:
        assert mid.check("starts").passed
        stepping = mid.check("stepping")
    assert not stepping.passed and stepping.reason.startswith("RobotFailure (exited)")


# --- broken on purpose: each must fail the check named for its fault ---------------------------------

class IgnoresStartPose(SimPlant):
    def begin(self, seeds, poses, routes, seconds, camera, privileged):
        return super().begin(seeds, [None] * len(poses), routes, seconds, camera, privileged)


class SeedsFromTheClock(SimPlant):
    def begin(self, seeds, poses, routes, seconds, camera, privileged):
        rng = np.random.default_rng()
        return super().begin([int(s) + int(rng.integers(1 << 20)) for s in seeds], poses, routes, seconds, camera,
                             privileged)


class SlowClock(SimPlant):
    """Stamps observations at half the simulator's time."""

    def observation(self, i, image, privileged):
        obs = super().observation(i, image, privileged)
        return dataclasses.replace(obs, time=obs.time / 2)


class LeaksGroundTruth(SimPlant):
    def observation(self, i, image, privileged):
        return super().observation(i, image, True)


class EndsOnce(SimPlant):
    def begin(self, *args):
        self.ended = False
        return super().begin(*args)

    def end(self):
        if self.ended:
            raise RuntimeError("already ended")
        self.ended = True
        super().end()


BROKEN = [
    (IgnoresStartPose, {"start-pose"}, "asked to start at"),
    (SeedsFromTheClock, {"determinism"}, "seed 1 again"),
    (SlowClock, {"observations"}, "frame k at k/15 s"),
    (LeaksGroundTruth, {"observations"}, "a camera agent's observation carries ground truth"),
    (EndsOnce, {"failure"}, "end() raised when called a second time"),
]


@pytest.mark.parametrize(("cls", "failing", "words"), BROKEN, ids=[c.__name__ for c, _, _ in BROKEN])
def test_a_broken_plant_fails_the_check_named_for_its_fault(cls: type[SimPlant], failing: set[str], words: str) -> None:
    report = PlantContract(lambda: cls(Simulator("loop_3x3", SMALL), jpeg.roundtrip),
                           name=cls.__name__, frame_rate=SMALL.frame_rate).run()
    assert {r.name for r in report.failures} == failing, report.summary()
    assert any(words in r.reason for r in report.failures), report.summary()
