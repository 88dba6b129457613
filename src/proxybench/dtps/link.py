"""proxybench's end of a DTPS bridge process (``bridge.py`` run by the SDK environment's interpreter).

Every wait has a deadline and watches the process, so nothing hangs on a bridge that died or stalled; a
bridge failure raises :class:`BridgeError` with its last stderr lines. What the bridge sends is checked like
any input from outside (:mod:`.pipe`): the events it forwards carry what an SDK agent or a robot wrote.
"""

from __future__ import annotations

import contextlib
import os
import select
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from proxybench.dtps import pipe
from proxybench.dtps.env import sdk_python
from proxybench.private import LockTimeout, PrivateFileError, hold_lock, make_private_folder, user_folder
from proxybench.protocol.transport import Launch

__all__ = ["BRIDGE", "PORT_LOCK_TIMEOUT_S", "BridgeError", "BridgeLink", "PortLock", "PortLockError"]

#: the bridge script (runs in the SDK environment; never imports proxybench)
BRIDGE = Path(__file__).with_name("bridge.py")


class BridgeError(RuntimeError):
    """The bridge process failed (could not start, could not serve, ended); ``stderr_tail``: its last lines."""

    def __init__(self, detail: str, stderr_tail: list[str] | None = None, exit_code: int | None = None):
        self.detail, self.stderr_tail, self.exit_code = detail, list(stderr_tail or []), exit_code
        tail = "".join(f"\n  {line}" for line in self.stderr_tail[-8:])
        super().__init__(detail + (f" (exit code {exit_code})" if exit_code is not None else "") + tail)


class PortLockError(BridgeError):
    """The port's lock could not be had: another run of this user still holds it at the deadline, or its file or
    folder is not safely ours (one line naming the holder or the path)."""


#: how long a virtual robot waits for its port by default (another episode of this user may be serving it)
PORT_LOCK_TIMEOUT_S = 600.0


class PortLock:
    """One virtual robot per TCP port for this user at a time (an unchanged SDK agent always connects to 7501): an
    exclusive ``flock`` on ``dtps-<port>.lock`` in the user's private folder (:mod:`proxybench.private`: 0700,
    checked, no links followed, so another local user can neither hold it nor redirect it), released when the
    holder closes it or dies; waited for with a deadline."""

    def __init__(self, port: int, *, folder: Path | None = None):
        self.port = port
        self._folder = folder
        self.path: Path | None = None
        self.fd: int | None = None

    def acquire(self, timeout: float = PORT_LOCK_TIMEOUT_S) -> None:
        """Hold the port's lock, waiting up to ``timeout`` s; :class:`PortLockError` (one line) if it cannot."""
        try:
            folder = make_private_folder(self._folder) if self._folder is not None else user_folder("dtps")
            self.path = folder / f"port-{int(self.port)}.lock"
            self.fd = hold_lock(self.path, timeout=timeout, what=f"port {self.port}'s virtual robot")
        except (LockTimeout, PrivateFileError) as exc:
            raise PortLockError(str(exc)) from None

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


class BridgeLink:
    """A running bridge: ``args`` after ``script`` (default ``bridge.py``: role and options), started with the SDK
    interpreter."""

    def __init__(self, args: list[str], *, python: str | Path | None = None, start_timeout: float = 30.0,
                 env: dict[str, str] | None = None, script: Path = BRIDGE):
        py = Path(python) if python is not None else sdk_python()
        self.reader = pipe.Reader()
        self.events: list[dict[str, Any]] = []
        # not under the subreaper launcher: a robot in a namespace of its own is joined at /proc/<its pid>/ns/net
        self._os = Launch([str(py), "-I", str(script), *args], transport="pipes", env=env, stderr_lines=40,
                          reap=False)
        self.ready = self.wait_for("ready", time.monotonic() + start_timeout)

    # ------------------------------------------------------------------------------------------ I/O
    def send(self, **message: Any) -> None:
        deadline = time.monotonic() + 10.0

        def wait() -> None:
            if time.monotonic() > deadline:
                self._fail("the bridge read nothing for 10 s")
            self._pump(0.005)  # read its output meanwhile: it may be blocked writing to us

        self._os.write(pipe.pack(message), wait, lambda: self._fail("the bridge closed its input"))

    def poll(self, deadline: float) -> list[dict[str, Any]]:
        """Events that arrived by ``deadline`` (returns as soon as there is at least one, or at the deadline); what
        the bridge wrote already is always taken, even when the deadline has passed."""
        while select.select([self._os.out_fd], [], [], 0)[0]:
            self._pump(0.0)
        while not self.events:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            self._pump(left)
        out, self.events = self.events, []
        return out

    def drain(self, deadline: float, handle: Callable[[dict[str, Any]], None]) -> None:
        """Every event that arrives until ``deadline`` (monotonic) handed to ``handle``, in order; :class:`BridgeError`
        when the bridge ends."""
        while True:
            for ev in self.poll(deadline):
                handle(ev)
            if time.monotonic() >= deadline:
                return

    def wait_for(self, kind: str, deadline: float) -> dict[str, Any]:
        """The first event ``kind`` (the others stay queued for :meth:`poll`); :class:`BridgeError` at the deadline
        or on an ``error`` event."""
        seen = 0
        while True:
            for k in range(seen, len(self.events)):
                ev = self.events[k]
                if ev.get("ev") == "error":
                    self._fail(str(ev.get("detail")))
                if ev.get("ev") == kind:
                    return self.events.pop(k)
            seen = len(self.events)
            left = deadline - time.monotonic()
            if left <= 0:
                self._fail(f"no {kind!r} event from the bridge in time")
            self._pump(left)

    def _pump(self, timeout: float) -> None:
        fds = [self._os.out_fd] + ([self._os.pidfd] if self._os.pidfd is not None else [])
        ready, _, _ = select.select(fds, [], [], max(0.0, timeout))
        if self._os.out_fd in ready:
            self.reader.read_from(self._os.out_fd)
        try:
            while (msg := self.reader.next()) is not None:
                self.events.append(msg)
        except pipe.PipeError as exc:
            self._fail(f"the bridge wrote garbage: {exc}")
        if self.reader.eof or (self._os.pidfd is not None and self._os.pidfd in ready and not self.events):
            self._fail("the bridge ended")

    # -------------------------------------------------------------------------------------- life
    @property
    def pid(self) -> int:
        return self._os.pid

    @property
    def alive(self) -> bool:
        return self._os.returncode is None and not self._os.exited()

    def stderr_tail(self) -> list[str]:
        return self._os.stderr.tail()

    def _fail(self, detail: str) -> None:
        code = self._os.terminate(0.5)
        raise BridgeError(detail, self._os.stderr.finish(), code)

    def close(self, timeout: float = 2.0) -> None:
        if self._os.returncode is None:
            with contextlib.suppress(OSError, BridgeError):
                self.send(op="quit")
            self._os.close_input()
            self._os.terminate(timeout, term_first=True)
            self._os.stderr.finish()
