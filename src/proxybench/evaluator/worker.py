"""The evaluator's side of a job's worker process: start it (ahead of its job), hand it the job, take its outcome.

A worker (:mod:`.run`) is started as a *spare* before there is a job: it imports the simulator, runner
and protocol while the evaluator uploads the previous result and asks for the next lease, then waits for
its job folder on stdin. Its outcome comes back through a pipe that only it holds (``--outcome-fd``):
an agent, running as another user in its own namespaces, can neither write it nor forge a file in its
place. Only a worker that exited normally and sent a complete outcome is believed.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

from proxybench.evaluator.outcome import Outcome

__all__ = ["Worker", "job_artifacts_only"]

log = logging.getLogger("proxybench.evaluator")
_MAX_OUTCOME = 64 << 20
_ARTIFACT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")


class _Channel(threading.Thread):
    """Reads the worker's outcome pipe to its end (bounded), so a large outcome never blocks the worker."""

    def __init__(self, fd: int):
        super().__init__(name="outcome-reader", daemon=True)
        self.fd, self.data, self.too_big = fd, bytearray(), False
        self.start()

    def run(self) -> None:
        with open(self.fd, "rb", closefd=True) as pipe:
            while chunk := pipe.read(1 << 16):
                if len(self.data) + len(chunk) > _MAX_OUTCOME:
                    self.too_big = True
                    continue  # keep draining; the outcome is refused
                self.data += chunk

    def result(self, timeout: float) -> str | None:
        """The text sent, once the pipe is closed (None if it never was, or it was too large)."""
        self.join(timeout)
        if self.is_alive() or self.too_big:
            return None
        return self.data.decode("utf-8", "replace")


class Worker:
    """One worker process, started ahead of its job (``python -m proxybench.evaluator.run --spare``).

    ``log_fd``: an open file it writes to until it has a job (then: the job's ``worker.log``), closed here;
    ``env``: its environment (the evaluator's, without tokens).
    """

    def __init__(self, log_fd: int, env: dict[str, str]):
        read_fd, write_fd = os.pipe()
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "proxybench.evaluator.run", "--spare", "--parent", str(os.getpid()),
                 "--outcome-fd", str(write_fd)],
                stdin=subprocess.PIPE, stdout=log_fd, stderr=subprocess.STDOUT, env=env, start_new_session=True,
                pass_fds=(write_fd,))
        except BaseException:
            os.close(read_fd)
            raise
        finally:
            os.close(write_fd)
            os.close(log_fd)
        self._channel = _Channel(read_fd)
        self.given = False

    @property
    def ready(self) -> bool:
        """Alive and still waiting for a job."""
        return not self.given and self.proc.poll() is None

    def give(self, job_dir: Path) -> None:
        """Start the job in ``job_dir`` (its ``job.json`` must be written)."""
        self.given = True
        try:
            assert self.proc.stdin is not None
            self.proc.stdin.write(f"{job_dir}\n".encode())
            self.proc.stdin.close()
        except OSError:
            pass  # it died meanwhile: the caller sees it exit without an outcome

    def outcome_text(self, timeout: float = 30.0) -> str | None:
        """What the worker sent, if it exited normally (status 0) and closed its pipe; else None."""
        text = self._channel.result(timeout)
        return text if self.proc.poll() == 0 and text else None

    def kill(self) -> None:
        """End the worker and everything it started (agents also die with it: PR_SET_PDEATHSIG)."""
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=3)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(timeout=10)
        with contextlib.suppress(OSError):
            if self.proc.stdin is not None:
                self.proc.stdin.close()


def job_artifacts_only(outcome: Outcome, job_dir: Path) -> Outcome:
    """Keep only artifacts the worker made: files directly in the job folder, named as listed (the rest is
    dropped, and the message says so)."""
    kept = []
    for a in outcome.artifacts:
        if _ARTIFACT_NAME.fullmatch(a.name) and Path(a.path) == job_dir / a.name and a.name != "agent.archive":
            kept.append(a)
        else:
            log.error("artifact %r at %r is not a file of the job folder: not uploaded", a.name, a.path)
            outcome.message += f"\nartifact {a.name!r} refused: not a file of the job folder"
    outcome.artifacts = kept
    return outcome
