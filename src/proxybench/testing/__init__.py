"""Contract suites for agents and plants, importable by users (as Optuna's storage test suite is).

``StudyContract`` checks a registered study (config, command, report from a canned result);
``AgentContract`` checks an agent (zoo name, checkpoint, node command, any factory of
:class:`~proxybench.agents.base.Agent`); ``PlantContract`` a plant of the episode engine (the simulator, a
robot node, your robot's bridge). Each check returns a typed :class:`CheckResult`; ``check_all()`` raises
:class:`ContractViolation` naming every failure (docs/robot-protocol.md, "Checking a bridge", and the
README's Python section show both in use)::

    from proxybench.testing import AgentContract, PlantContract

    AgentContract(MyAgent).check_all()                       # any zero-argument factory of an Agent
    AgentContract.for_command("python3 my_node.py").check_all()
    PlantContract.for_robot_command("python3 my_bridge.py").check_all()

Layer: above the runner (it plays episodes through it), below the command line and the evaluator.
"""

from proxybench.testing.agent import AgentContract, Play
from proxybench.testing.plant import PlantContract
from proxybench.testing.results import (
    CheckFailed,
    CheckResult,
    Contract,
    ContractReport,
    ContractViolation,
    parametrize_checks,
)
from proxybench.testing.streams import StreamSpec
from proxybench.testing.study import StudyContract

__all__ = ["AgentContract", "CheckFailed", "CheckResult", "Contract", "ContractReport", "ContractViolation",
           "PlantContract", "Play", "StreamSpec", "StudyContract", "parametrize_checks"]
