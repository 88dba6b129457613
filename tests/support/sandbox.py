"""The agent sandbox for tests: use it where this host has it; where CI says it must (PROXYBENCH_REQUIRE_SANDBOX),
its absence fails the tests instead of skipping them."""

from __future__ import annotations

import os
import time

import pytest

from proxybench.evaluator.sandbox import Isolation, detect_isolation

__all__ = ["AGENT_USER_GROUP", "agent_uid", "processes_left", "processes_of", "require_safe_sandbox"]

#: the pytest-xdist group of every test that starts processes as the agent user (a sandboxed agent package, or the
#: probe every evaluator runs at its start): they run one at a time, in one worker (``--dist loadgroup``), because
#: a test that checks that no process of the agent user is left, or a hostile agent's ``kill(-1)`` or fork bomb
#: (limits per user), would meet the agents of a test running beside it
AGENT_USER_GROUP = pytest.mark.xdist_group("agent-user")


def require_safe_sandbox() -> Isolation:
    """The safe sandbox (agents as the unprivileged agent user in bubblewrap), or skip / fail saying why not."""
    isolation = detect_isolation()
    if not isolation.safe:
        reason = isolation.problem or isolation.note
        if os.environ.get("PROXYBENCH_REQUIRE_SANDBOX"):
            pytest.fail(f"the agent sandbox is required (PROXYBENCH_REQUIRE_SANDBOX) but unusable: {reason}")
        pytest.skip(f"no safe agent sandbox on this host: {reason}")
    return isolation


def agent_uid() -> int | None:
    isolation = detect_isolation()
    return isolation.uid if isolation.safe else None


def processes_of(uid: int) -> list[str]:
    """'pid [state] command' of every process the user ``uid`` runs now."""
    out = []
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            if os.stat(entry.path).st_uid != uid:
                continue
            with open(os.path.join(entry.path, "cmdline"), "rb") as f:
                cmdline = f.read().replace(b"\0", b" ").decode(errors="replace")
            with open(os.path.join(entry.path, "stat")) as f:
                state = f.read().rsplit(")", 1)[-1].split()[0]  # R, S, Z (zombie), ...
            out.append(f"{entry.name} [{state}] {cmdline[:200]}")
        except OSError:
            continue
    return out


def processes_left(uid: int, timeout: float = 10.0) -> list[str]:
    """:func:`processes_of` once they are gone or ``timeout`` [s] has passed (a sandbox may be exiting)."""
    deadline = time.monotonic() + timeout
    while (left := processes_of(uid)) and time.monotonic() < deadline:
        time.sleep(0.2)
    return left
