"""The agent contract (proxybench.testing.AgentContract) over every zoo agent, node agents and a behaviour-cloning
checkpoint; and deliberately broken agents, each failing the check named for what is wrong with it."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from proxybench.agents import agent_names
from proxybench.agents.base import Agent, Observation
from proxybench.agents.simple import RandomAgent, StraightAgent
from proxybench.domain.params import DomainParams
from proxybench.testing import AgentContract, CheckResult, ContractViolation, StreamSpec, parametrize_checks
from support.checkpoints import untrained_checkpoint

STREAM = StreamSpec(params=DomainParams(image_width=80, image_height=60), seconds=1.0)
PIXEL = Path(__file__).resolve().parent / "protocol_agents" / "pixel_agent.py"


@pytest.mark.parametrize("name", agent_names())
def test_every_zoo_agent_keeps_the_contract(name: str) -> None:
    report = AgentContract.for_agent(name, stream=STREAM).check_all()
    assert [r.name for r in report.results] == list(AgentContract.CHECKS)
    privileged = next(r for r in report.results if r.name == "privileged")
    assert ("privileged:" in privileged.reason) == AgentContract.for_agent(name).factory().privileged


@pytest.mark.parametrize(("mode", "privileged"), [("pixel", False), ("privileged", True)])
def test_node_agents_keep_the_contract_and_a_killed_node_is_a_named_failure(mode: str, privileged: bool) -> None:
    report = AgentContract.for_command([sys.executable, str(PIXEL), mode], stream=STREAM).check_all()
    by_name = {r.name: r for r in report.results}
    assert "killed mid-episode: AgentFailure (exited)" in by_name["failure"].reason
    assert "the next episode started a fresh node" in by_name["failure"].reason
    assert ("follow the true lane pose" in by_name["privileged"].reason) == privileged


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An untrained behaviour-cloning network (as test_heldout makes one): a real checkpoint agent."""
    return untrained_checkpoint(tmp_path_factory.mktemp("bc"))


def test_a_behaviour_cloning_checkpoint_keeps_the_contract(checkpoint: Path) -> None:
    report = AgentContract.for_agent(str(checkpoint), stream=STREAM).check_all()
    assert "camera-only" in next(r for r in report.results if r.name == "privileged").reason


# --- broken on purpose: each must fail the check named for its fault ---------------------------------

class NanCommand(StraightAgent):
    def act(self, obs: Observation) -> np.ndarray:
        return np.array([0.3, np.nan]) if obs.time > 0.3 else super().act(obs)


class TooFast(StraightAgent):
    def act(self, obs: Observation) -> np.ndarray:
        return np.array([1.5, 1.5])


class NeedsLanePoseButSaysCameraOnly(Agent):
    name = "liar"

    def act(self, obs: Observation) -> np.ndarray:
        return np.array([0.3, 0.3 + 0.1 * self.true_lane_pose(obs).lateral])


class PeeksAtTheLanePose(StraightAgent):
    """Camera-only by its flag, but steers by the lane pose whenever one is there."""

    def act(self, obs: Observation) -> np.ndarray:
        lateral = obs.lane_pose.lateral if obs.lane_pose is not None else 0.0
        return np.array([0.3, 0.3 + lateral])


class SaysPrivilegedButIgnoresIt(StraightAgent):
    privileged = True


class LeaksAcrossEpisodes(StraightAgent):
    """Counts frames since it was made, not since the episode began."""

    def __init__(self) -> None:
        super().__init__(0.3)
        self.frames = 0

    def act(self, obs: Observation) -> np.ndarray:
        self.frames += 1
        return np.array([0.3, 0.3 + 0.01 * min(self.frames, 50)])


class Unseeded(RandomAgent):
    def reset(self, seed: int, episode: str | None = None) -> None:
        super().reset(seed, episode)
        self._rng = np.random.default_rng()  # fresh entropy, whatever the seed


class CloseTwiceFails(StraightAgent):
    def __init__(self) -> None:
        super().__init__(0.3)
        self.closed = False

    def close(self) -> None:
        if self.closed:
            raise RuntimeError("already closed")
        self.closed = True


BROKEN = [
    (NanCommand, {"commands"}, "not finite"),
    (TooFast, {"commands"}, "outside [-1, 1]"),
    (NeedsLanePoseButSaysCameraOnly, {"commands", "privileged"}, "says camera-only, but given no true lane pose"),
    (PeeksAtTheLanePose, {"privileged"}, "its commands change when the true lane pose is given"),
    (SaysPrivilegedButIgnoresIt, {"privileged"}, "it does not read it, so declare privileged = False"),
    (LeaksAcrossEpisodes, {"isolation"}, "differs from episode 2 of a fresh agent"),
    (Unseeded, {"determinism", "isolation", "privileged"}, "answered differently"),
    (CloseTwiceFails, {"failure"}, "close() raised when called a second time"),
]


@pytest.mark.parametrize(("cls", "failing", "words"), BROKEN, ids=[c.__name__ for c, _, _ in BROKEN])
def test_a_broken_agent_fails_the_check_named_for_its_fault(cls: type[Agent], failing: set[str], words: str) -> None:
    contract = AgentContract(cls, name=cls.__name__, stream=STREAM)
    report = contract.run()
    assert {r.name for r in report.failures} == failing, report.summary()
    assert any(words in r.reason for r in report.failures), report.summary()
    with pytest.raises(ContractViolation) as err:
        report.raise_if_failed()
    assert all(f"  {name}: " in str(err.value) for name in failing) and cls.__name__ in str(err.value)


def test_a_node_that_cannot_start_fails_every_check_with_its_reason() -> None:
    report = AgentContract.for_command("/no/such/agent-node", stream=STREAM).run()
    assert not any(r.passed for r in report.results)
    assert all("could not make the agent: AgentFailure (start-failed)" in r.reason for r in report.results)
    assert all(isinstance(r, CheckResult) and r.error is not None for r in report.results)


def test_an_unknown_agent_name_is_the_callers_error() -> None:
    with pytest.raises(KeyError, match="unknown agent 'no-such-agent'"):
        AgentContract.for_agent("no-such-agent")


@pytest.fixture(scope="module")
def pid_contract():
    with AgentContract.for_agent("pid", stream=STREAM) as contract:
        yield contract


@parametrize_checks(AgentContract)
def test_one_test_per_check_with_the_pytest_helper(pid_contract: AgentContract, check: str) -> None:
    result = pid_contract.assert_check(check)
    assert result.passed and result.to_dict()["name"] == check
