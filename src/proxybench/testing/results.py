"""What a contract check says, and the machinery every contract shares (Optuna's storage test suite, for us).

A contract is a list of named checks over one *subject* (an agent, a plant). Each check returns a
:class:`CheckResult` (name, passed, reason) and never raises for the subject's faults, so the command line
and the evaluator can report every check; :meth:`Contract.check_all` is the pytest-friendly form that raises
:class:`ContractViolation` naming every failed check. Checks share the episodes they play (memoised per
contract), so running all of them costs little more than the most expensive one.
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, ClassVar, Self

__all__ = ["CheckFailed", "CheckResult", "Contract", "ContractReport", "ContractViolation", "describe_error",
           "expect_node_failure", "kill_node", "parametrize_checks", "release"]


@dataclass(frozen=True)
class CheckResult:
    """One check of a contract: its ``name``, whether it ``passed`` and why (``reason``), its wall time [s].

    ``error`` is the exception behind a failure, where there was one (e.g. a node's
    :class:`~proxybench.protocol.AgentFailure`, with its stderr tail), for callers that act on it.
    """

    name: str
    passed: bool
    reason: str
    seconds: float = 0.0
    error: BaseException | None = field(default=None, compare=False, repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "passed": self.passed, "reason": self.reason, "seconds": round(self.seconds, 3)}

    def line(self) -> str:
        """``✓ name: reason`` / ``✗ name: reason``: one line for a terminal or a log."""
        return f"{'✓' if self.passed else '✗'} {self.name}: {self.reason}"


class ContractViolation(AssertionError):
    """A subject failed one or more checks of its contract; the message names each failed check and why."""

    def __init__(self, report: ContractReport):
        self.report = report
        super().__init__(report.summary())


@dataclass
class ContractReport:
    """Every check run on ``subject``; ``ok`` when all passed."""

    contract: str
    subject: str
    results: list[CheckResult]

    @property
    def ok(self) -> bool:
        return all(r.passed for r in self.results)

    @property
    def failures(self) -> list[CheckResult]:
        return [r for r in self.results if not r.passed]

    def summary(self) -> str:
        failed = self.failures
        head = (f"{self.subject} passes the {self.contract} ({len(self.results)} checks)" if not failed else
                f"{self.subject} fails {len(failed)} of {len(self.results)} checks of the {self.contract}:")
        return "\n".join([head, *(f"  {r.name}: {r.reason}" for r in failed)])

    def to_dict(self) -> dict[str, Any]:
        return {"contract": self.contract, "subject": self.subject, "ok": self.ok,
                "checks": [r.to_dict() for r in self.results]}

    def raise_if_failed(self) -> Self:
        if not self.ok:
            raise ContractViolation(self)
        return self


class CheckFailed(Exception):
    """Raised inside a check: it fails with this reason (and the exception behind it, if any)."""

    def __init__(self, reason: str, error: BaseException | None = None):
        super().__init__(reason)
        self.error = error


class Contract:
    """Named checks over one subject. Subclasses list ``CHECKS`` and define ``check_<name>`` (dashes become
    underscores) returning ``(passed, reason)`` or raising :class:`CheckFailed`; any other exception out of a
    check fails it with the exception's type and message (the subject's fault, described, never a traceback)."""

    CHECKS: ClassVar[tuple[str, ...]] = ()
    title: ClassVar[str] = "contract"
    subject: str = "subject"

    def __init__(self) -> None:
        self._memo: dict[Any, Any] = {}
        self._cleanup: list[Callable[[], Any]] = []

    # -- running -----------------------------------------------------------------------------------
    def check(self, name: str) -> CheckResult:
        """Run one check (by name, one of ``CHECKS``) and say how it went; never raises for the subject."""
        if name not in self.CHECKS:
            raise KeyError(f"unknown check {name!r} of the {self.title}; known: {', '.join(self.CHECKS)}")
        t0 = time.perf_counter()
        error: BaseException | None = None
        try:
            passed, reason = getattr(self, "check_" + name.replace("-", "_"))()
        except CheckFailed as exc:
            passed, reason, error = False, str(exc), exc.error
        except Exception as exc:  # the subject failed in a way the check did not expect: say how
            passed, reason, error = False, describe_error(exc), exc
        return CheckResult(name, bool(passed), reason, time.perf_counter() - t0, error)

    def run(self, checks: Iterable[str] | None = None) -> ContractReport:
        """Every check (or those named), in order; a report that never raises for the subject's faults."""
        try:
            results = [self.check(name) for name in (self.CHECKS if checks is None else tuple(checks))]
        finally:
            self.close()
        return ContractReport(self.title, self.subject, results)

    def check_all(self, checks: Iterable[str] | None = None) -> ContractReport:
        """As :meth:`run`, raising :class:`ContractViolation` (an ``AssertionError``) naming every failed check."""
        return self.run(checks).raise_if_failed()

    def assert_check(self, name: str) -> CheckResult:
        """One check, raising :class:`ContractViolation` if it fails (for a test per check)."""
        result = self.check(name)
        if not result.passed:
            raise ContractViolation(ContractReport(self.title, self.subject, [result]))
        return result

    # -- shared helpers ----------------------------------------------------------------------------
    def _memoised(self, key: Any, make: Callable[[], Any]) -> Any:
        """``make()`` once per key; a :class:`CheckFailed` it raised is remembered and raised again."""
        if key not in self._memo:
            try:
                self._memo[key] = make()
            except CheckFailed as exc:
                self._memo[key] = exc
        value = self._memo[key]
        if isinstance(value, CheckFailed):
            raise CheckFailed(str(value), value.error)
        return value

    def _on_close(self, fn: Callable[[], Any]) -> None:
        self._cleanup.append(fn)

    def close(self) -> None:
        """Release what the checks started (node processes, plants); the memoised episodes stay."""
        while self._cleanup:
            fn = self._cleanup.pop()
            with contextlib.suppress(Exception):  # best effort: a failing close is the failure check's to report
                fn()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def describe_error(exc: BaseException) -> str:
    """An exception in words: type, a node failure's reason code, the message (first line of it)."""
    reason = getattr(exc, "reason", None)
    detail = getattr(exc, "detail", None) or "".join(traceback.format_exception_only(exc)).strip().split(": ", 1)[-1]
    first = str(detail).strip().splitlines()[0] if str(detail).strip() else ""
    code = getattr(exc, "exit_code", None)
    return (f"{type(exc).__name__}" + (f" ({reason})" if isinstance(reason, str) else "") + f": {first}"
            + (f" (exit code {code})" if code is not None else ""))


def kill_node(process: Any) -> None:
    """SIGKILL a node process (and its process group, when it has one of its own): a node that dies."""
    pid = process.pid
    try:
        group = os.getpgid(pid)
        if group != os.getpgrp():
            os.killpg(group, signal.SIGKILL)
        else:
            os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def expect_node_failure(what: str, call: Callable[[], Any]) -> str:
    """``call()`` right after its node was killed must raise a named :class:`~proxybench.protocol.NodeFailure`;
    what it said, in words (else :class:`CheckFailed`)."""
    from proxybench.protocol.failures import NodeFailure

    try:
        call()
    except NodeFailure as exc:
        return f"killed mid-episode: {describe_error(exc)}"
    except Exception as exc:
        raise CheckFailed(f"a {what} killed mid-episode must be a named failure (a NodeFailure with a reason), got "
                          f"{describe_error(exc)}", exc) from None
    raise CheckFailed(f"the {what} was killed mid-episode, yet it went on as if alive")


def release(thing: Any, quietly: bool = True) -> None:
    """``thing.close()`` where it has one (a node agent, a plant owning its robot node); ``quietly``: whatever it
    raises is the failure check's to report, not the caller's."""
    close = getattr(thing, "close", None)
    if close is None:
        return
    try:
        close()
    except Exception:
        if not quietly:
            raise


def parametrize_checks(contract: type[Contract] | Contract, argname: str = "check"):
    """``@parametrize_checks(AgentContract)``: one pytest test per check of a contract (pytest imported here)."""
    import pytest

    return pytest.mark.parametrize(argname, contract.CHECKS)
