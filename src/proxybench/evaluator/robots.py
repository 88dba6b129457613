"""A lease per robot of an Autolab (issue 36 item 3): the evaluator runs up to one job per free robot at once.

An Autolab evaluator (``--autolab lab.yaml``) runs one job per robot it can drive, each in a worker process of
its own: before it leases a job from the server it takes a free robot here, and gives it back when the job's
result is posted (or its lease lost). A robot is held by one job at a time, so a job never runs on a busy robot,
and with every robot busy the evaluator leases nothing: the server's queue holds the job for another lab.

A robot's lease is also a **file lock** that every evaluator process of this user on this machine respects: two
evaluators started with one ``lab.yaml`` never drive one robot at once; the second takes only the robots the first
left free, leases nothing while all are taken, and says so in its log, naming the holder. The lock is an
``flock`` on ``<tmp>/proxybench-<uid>/autolab-robots/<lab>/<robot>.lock`` (:mod:`proxybench.private`: a folder of
ours only, mode 700; a link or anything else planted where the lock file goes is refused, never opened through), so
it dies with its holder: the robots of an evaluator killed with -9 are free at once. Its key is the lab's name
and the robot's name (two labs of one name describe one lab). ``PROXYBENCH_AUTOLAB_LOCKS=DIR`` puts the locks in
``DIR/<lab>/`` instead (checked the same way): the test suite gives each of its processes its own, so that tests
running at once with one lab's name do not wait for each other's robots.

It offers every robot of the lab, in the lab's order: **virtual** DB21Js (each a simulator of the worker's own
behind its own DTPS server, in a network namespace of its own under the safe sandbox, so that each SDK agent
finds *its* robot at 127.0.0.1:7501; with ``world: shared`` robots of the lab's one world, :mod:`.lab_world`,
else each the ego of a world of its own: docs/autolab.md, "Several robots"), **DTPS** robots (a relay into the
agent's namespace, :mod:`.autolab_dtps`) and **robot nodes** (:mod:`.autolab_node`). What a robot cannot do for a
job (an AIDO node on a DTPS robot) the worker refuses with a host error saying why.
"""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path

from proxybench.autolab.lab import Lab
from proxybench.private import LockTimeout, hold_lock, make_private_folder, user_folder

__all__ = ["LOCKS_ENV", "RobotLeases"]

log = logging.getLogger("proxybench.evaluator")
#: the environment variable that moves the robots' locks (see the module)
LOCKS_ENV = "PROXYBENCH_AUTOLAB_LOCKS"


class RobotLeases:
    """The lab's drivable robots and which of them a job holds now: thread-safe within this process (one evaluator
    slot per robot) and locked across the processes of this user (see the module). ``lock_dir``: where the locks
    of this lab's robots live (default ``<tmp>/proxybench-<uid>/autolab-robots/<lab>``; tests give their own)."""

    def __init__(self, lab: Lab, lock_dir: Path | None = None):
        self.lab = lab.name
        self.robots: tuple[str, ...] = tuple(r.name for r in lab.robots)
        self._lock_dir = lock_dir
        self._held: dict[str, int] = {}  # robot -> descriptor of its lock file (closing it frees the robot)
        self._elsewhere: dict[str, str] = {}  # robot -> its holder in another process, as last seen
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self.robots)

    def _folder(self) -> Path:
        """The private folder of this lab's robot locks, checked on every use (never a link, ours, mode 700)."""
        if self._lock_dir is not None:
            return make_private_folder(self._lock_dir)
        root = os.environ.get(LOCKS_ENV)
        return make_private_folder((make_private_folder(Path(root)) if root else user_folder("autolab-robots"))
                                   / self.lab)

    def take(self) -> str | None:
        """A free robot, now held by the caller (in the lab's order, so the first robot is used first); None when
        every robot is busy here or held by another evaluator process. A lock file that is not safely ours (a link
        planted there) is :class:`~proxybench.private.PrivateFileError`, naming it."""
        with self._lock:
            folder = self._folder()
            seen: dict[str, str] = {}
            try:
                for name in self.robots:
                    if name in self._held:
                        continue
                    try:
                        self._held[name] = hold_lock(folder / f"{name}.lock", timeout=0.0,
                                                     what=f"lab {self.lab!r}'s robot {name!r}")
                    except LockTimeout as exc:
                        seen[name] = _holder(str(exc))
                        continue
                    return name
                return None
            finally:
                self._note_elsewhere(seen)

    def _note_elsewhere(self, seen: dict[str, str]) -> None:
        """Log the robots another evaluator process holds, once per change (not at every poll)."""
        if seen == self._elsewhere:
            return
        gone = sorted(set(self._elsewhere) - set(seen))
        self._elsewhere = seen
        if seen:
            free = [r for r in self.robots if r not in seen and r not in self._held]
            log.info("lab %r: robot(s) held by another evaluator on this machine: %s; %s", self.lab,
                     "; ".join(f"{r} ({who})" for r, who in seen.items()),
                     f"free here: {', '.join(free)}" if free else "no robot free: leasing nothing until one is")
        elif gone:
            log.info("lab %r: robot(s) %s free again", self.lab, ", ".join(gone))

    def give_back(self, name: str) -> None:
        """Free a robot taken with :meth:`take` (its lock too); giving back one that is not held is a bug."""
        with self._lock:
            fd = self._held.pop(name, None)
            if fd is None:
                raise RuntimeError(f"lab {self.lab!r}: robot {name!r} is not held; it cannot be given back")
            os.close(fd)

    def close(self) -> None:
        """Free every robot this process still holds (the evaluator's end; a killed process frees them anyway)."""
        with self._lock:
            for fd in self._held.values():
                os.close(fd)
            self._held.clear()

    @property
    def busy(self) -> list[str]:
        """The robots held by this process now, in the lab's order."""
        with self._lock:
            return [r for r in self.robots if r in self._held]

    @property
    def elsewhere(self) -> dict[str, str]:
        """The robots another evaluator process held when this one last looked, with their holder."""
        with self._lock:
            return dict(self._elsewhere)


def _holder(message: str) -> str:
    """The holder named in a :class:`LockTimeout`'s message (``pid N: command``), for the log."""
    _, sep, rest = message.partition(" by ")
    return rest.rsplit(" (lock file", 1)[0] if sep else message
