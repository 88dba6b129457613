"""Shared fixtures: server tests run once on SQLite and once on a real PostgreSQL server."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

import pytest
from hypothesis import HealthCheck, settings

from support.postgres import PostgresServer
from support.scheduling import (  # noqa: F401 - hooks: how pytest-xdist shares the tests out
    pytest_collection_modifyitems,
    pytest_xdist_node_collection_finished,
)

# Property tests hold on a busy machine (CI shares it with studies; users train networks beside it): no per-example
# deadline and no health check on how fast examples are generated. What they test is correctness, never speed.
settings.register_profile("proxybench", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("proxybench")

# An Autolab's robot leases are file locks shared by every evaluator process of this user (evaluator/robots.py):
# each test process keeps its own, so that tests running at once with one lab's name never wait for each other's
# robots (each xdist worker sets its own, not inheriting the controller's; the processes a test starts inherit it;
# tests of the locks themselves give their own folder).
os.environ["PROXYBENCH_AUTOLAB_LOCKS"] = tempfile.mkdtemp(prefix="proxybench-robot-locks-")
atexit.register(shutil.rmtree, os.environ["PROXYBENCH_AUTOLAB_LOCKS"], True)

# Programs the tests start as separate processes (agent and robot nodes, AIDO's own code, hostile agents):
# never import them into the test process (``--doctest-modules`` would), where their module-level code
# (e.g. AIDO scripts' ``logging.disable``) would change every later test.
collect_ignore_glob = ["aido/*.py", "hostile_agents/*.py", "protocol_agents/*.py", "dtps_agents/*.py",
                       "dtps_robots/*.py", "image_agents/*.py"]  # image agents exit unless inside their image


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
