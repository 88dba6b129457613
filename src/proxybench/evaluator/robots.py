"""A lease per robot of an Autolab (issue 36 item 3): the evaluator runs up to one job per free robot at once.

An Autolab evaluator (``--autolab lab.yaml``) runs one job per robot it can drive, each in a worker process of
its own: before it leases a job from the server it takes a free robot here, and gives it back when the job's
result is posted (or its lease lost). A robot is held by one job at a time, so a job never runs on a busy robot,
and with every robot busy the evaluator leases nothing: the server's queue holds the job for another lab.

The robots it drives are the lab's **virtual** DB21Js (each a simulator of the worker's own behind its own DTPS
server, in a network namespace of its own under the safe sandbox, so that each SDK agent finds *its* robot at
127.0.0.1:7501). They do not yet share a world: each robot is the ego of a world of its own (docs/autolab.md,
"Several robots"). Their leases live in this process: another evaluator started with the same ``lab.yaml``
simulates robots of its own. A lab without virtual robots offers its first robot, whose job the worker refuses
with a host error saying why (a DTPS or robot-node robot is described but not yet driven).
"""

from __future__ import annotations

import threading

from proxybench.autolab.lab import Lab

__all__ = ["RobotLeases"]


class RobotLeases:
    """The lab's drivable robots and which of them a job holds now (thread-safe: one evaluator slot per robot)."""

    def __init__(self, lab: Lab):
        virtual = [r.name for r in lab.robots if r.kind == "virtual"]
        self.lab = lab.name
        self.robots: tuple[str, ...] = tuple(virtual or [lab.robots[0].name])
        self._held: set[str] = set()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self.robots)

    def take(self) -> str | None:
        """A free robot, now held by the caller (in the lab's order, so the first robot is used first); None when
        every robot is busy."""
        with self._lock:
            for name in self.robots:
                if name not in self._held:
                    self._held.add(name)
                    return name
        return None

    def give_back(self, name: str) -> None:
        """Free a robot taken with :meth:`take`; giving back one that is not held is a bug, and says so."""
        with self._lock:
            if name not in self._held:
                raise RuntimeError(f"lab {self.lab!r}: robot {name!r} is not held; it cannot be given back")
            self._held.remove(name)

    @property
    def busy(self) -> list[str]:
        """The robots held now, in the lab's order."""
        with self._lock:
            return [r for r in self.robots if r in self._held]
