"""The suite holds on a busy machine: property tests have no per-example deadline and no generation-speed health
check (issue 39: two Hypothesis failures at load 9–20), whatever a test's own ``@settings`` leave unset."""

from __future__ import annotations

import re
from pathlib import Path

from hypothesis import HealthCheck, settings


def test_the_project_profile_has_no_deadline_and_no_speed_health_check() -> None:
    assert settings.default.deadline is None
    assert HealthCheck.too_slow in settings.default.suppress_health_check


def test_no_property_test_sets_a_deadline_of_its_own() -> None:
    timed = [f"{p.name}:{i}" for p in Path(__file__).parent.glob("test_*.py")
             for i, line in enumerate(p.read_text().splitlines(), 1)
             if re.search(r"deadline\s*=\s*(?!None)[\w.]", line) and "settings(" in line]
    assert not timed, f"Hypothesis deadlines fail on a busy machine: {timed}"
