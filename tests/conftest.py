"""Shared fixtures: server tests run once on SQLite and once on a real PostgreSQL server."""

from __future__ import annotations

import os

import pytest

from support.postgres import PostgresServer

# Programs the tests start as separate processes (agent and robot nodes, AIDO's own code, hostile agents):
# never import them into the test process (``--doctest-modules`` would), where their module-level code
# (e.g. AIDO scripts' ``logging.disable``) would change every later test.
collect_ignore_glob = ["aido/*.py", "hostile_agents/*.py", "protocol_agents/*.py", "dtps_agents/*.py",
                       "dtps_robots/*.py"]


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Under pytest-xdist (``--dist loadgroup``, pyproject's addopts) the tests of one file run in one worker, so
    that its module-scoped fixtures (a gym node, a browser, a trained checkpoint) are built once; tests that name
    a group of their own (``support.sandbox.AGENT_USER_GROUP``) run with that group instead."""
    for item in items:
        if item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))


@pytest.hookimpl(optionalhook=True)  # pytest-xdist's hook: each worker's collected test ids
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


@pytest.fixture(scope="session")
def postgres():
    server = PostgresServer()
    reason = server.start()
    if reason is not None:
        if os.environ.get("PROXYBENCH_REQUIRE_PG"):
            pytest.fail(f"PostgreSQL required (PROXYBENCH_REQUIRE_PG) but unavailable: {reason}")
        pytest.skip(reason)
    yield server
    server.stop()


@pytest.fixture(params=["sqlite", "postgresql"])
def database_url(request, tmp_path):
    """A fresh, empty database of each kind."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'server.sqlite3'}"
    return request.getfixturevalue("postgres").new_database()
