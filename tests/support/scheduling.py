"""How pytest-xdist shares the tests between its workers (pyproject's addopts: ``-n 2 --dist loadgroup
--no-loadscope-reorder``); tests/conftest.py installs these hooks.

- The tests of one file run in one worker, so that its module-scoped fixtures (a gym node, a browser, a trained
  checkpoint) are built once; a test that names a group of its own (``support.sandbox.AGENT_USER_GROUP``) runs
  with that group instead.
- Groups are handed out longest first, so that the last ones are short and both workers finish together: the
  agent user's tests, then files with ``slow`` tests (the more the earlier), then by number of tests.
- A pytest-xdist that cannot pass the groups on stops the run, naming why, instead of running grouped tests
  side by side.
"""

from __future__ import annotations

import os

import pytest

__all__ = ["pytest_collection_modifyitems", "pytest_xdist_node_collection_finished"]


def _group(item: pytest.Item) -> str:
    mark = item.get_closest_marker("xdist_group")
    return str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))
    if not os.environ.get("PYTEST_XDIST_WORKER"):  # one process (-n 0): the tests in their usual order
        return
    members: dict[str, list[pytest.Item]] = {}
    for item in items:
        members.setdefault(_group(item), []).append(item)

    def cost(group: str) -> tuple:
        tests = members[group]
        return group != "agent-user", -sum(t.get_closest_marker("slow") is not None for t in tests), -len(tests)

    items[:] = [item for group in sorted(members, key=cost) for item in members[group]]  # stable within a group


@pytest.hookimpl(optionalhook=True)  # pytest-xdist's hook, in the controller: each worker's collected test ids
def pytest_xdist_node_collection_finished(node, ids: list[str]) -> None:
    """Stop at once where ``--dist loadgroup`` would not group, so the agent user's tests would meet each other.

    pytest-xdist passes each test's group to its scheduler in the test's id (``id@group``); on pytest 9.2 it
    cannot (pytest-dev/pytest-xdist#1386) and the tests were spread as if they had none."""
    if node.config.getvalue("dist") != "loadgroup":
        return
    ungrouped = [i for i in ids if "@" not in i.rsplit("]", 1)[-1]]
    if ungrouped:
        pytest.exit(f"--dist loadgroup does not group {ungrouped[0]} (and {len(ungrouped) - 1} more): this "
                    "pytest-xdist cannot give this pytest the groups (pytest-dev/pytest-xdist#1386; the test extra "
                    "pins versions that work); -n 0 runs the tests in one process", returncode=4)
