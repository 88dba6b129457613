"""The lab's operator desk: where an Autolab evaluator asks a person to place a robot, and hears of interventions.

A real robot cannot be teleported, and a person may have to step in while it drives (it is stuck, it is about to
fall off the table). An evaluator is often headless, one of several, and runs each job in a worker process, so
the desk is a folder, one per robot (``lab.yaml``'s ``operator.folder``, default ``<lab name>.operator`` beside
it), not a terminal:

- **placement** (``reset: {mode: operator}``): before an episode the evaluator writes ``<robot>/waiting.json``
  (where to put the robot, which episode, a fresh nonce) and says so in its log and, where it has one, on its
  terminal; the operator places the robot and runs ``proxybench autolab ready lab.yaml ROBOT``, which writes
  ``ready-<nonce>``. A confirmation therefore answers this request only: one left over from an earlier episode
  (another nonce) is never taken. No confirmation within ``operator.timeout_s`` → :class:`OperatorTimeout`, which
  the evaluator turns into the job's ``host-error`` ``robot_failure: operator-timeout: …``.
- **intervention**: while an episode runs the evaluator keeps ``<robot>/episode.json`` (its nonce);
  ``proxybench autolab intervene lab.yaml ROBOT --reason TEXT`` writes ``intervention-<nonce>.json``, and the
  evaluator ends that episode and the job as ``host-error`` ``manual_intervention: …``: a run someone touched
  measures no agent. With no episode running the command refuses (exit 1), so an intervention never lands on a
  later episode.

The folder is the evaluator's (mode 700, its user's, no links followed): the operator runs the commands as that
user (or root). An agent never sees it (the sandbox shows it its package only), so nothing an agent writes can
confirm a placement or end an episode. What the operator writes is still read as a stranger's input: bounded,
one line, printable.
"""

from __future__ import annotations

import json
import os
import secrets
import stat
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["OperatorDesk", "OperatorError", "OperatorTimeout", "confirm_ready", "intervene"]

_MAX_FILE = 64 << 10
_MAX_REASON = 300


class OperatorError(RuntimeError):
    """The desk cannot be used or has nothing to answer; one line naming the file or robot."""


class OperatorTimeout(OperatorError):
    """No one confirmed a placement in time."""


def _one_line(text: Any, limit: int = _MAX_REASON) -> str:
    flat = " ".join(str(text).split())
    return "".join(c if c.isprintable() else "?" for c in flat)[:limit]


def _private_folder(path: Path) -> Path:
    """``path`` made (mode 700) or checked: a real folder of this user that no one else may write to."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = os.lstat(path)
    if not stat.S_ISDIR(st.st_mode):
        raise OperatorError(f"operator folder {path} is not a folder (a link?): refusing it")
    if st.st_uid != os.geteuid() or st.st_mode & 0o022:
        raise OperatorError(f"operator folder {path} belongs to another user or is writable by others: refusing it")
    return path


def _write(path: Path, data: dict[str, Any]) -> None:
    """``data`` as JSON at ``path``, whole or not at all (a temporary file created O_EXCL, renamed)."""
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(json.dumps(data, sort_keys=True) + "\n")
    os.replace(tmp, path)


def _read(path: Path) -> dict[str, Any] | None:
    """The JSON object at ``path`` (None: no such file); :class:`OperatorError` for a link or unreadable file."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise OperatorError(f"{path}: cannot be read ({exc.strerror})") from None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
            raise OperatorError(f"{path}: not a regular file")
        raw = fh.read(_MAX_FILE + 1)
    try:
        data = json.loads(raw[:_MAX_FILE])
    except ValueError:
        raise OperatorError(f"{path}: not JSON") from None
    if not isinstance(data, dict):
        raise OperatorError(f"{path}: not a JSON object")
    return data


def _nonce(data: dict[str, Any] | None) -> str | None:
    value = (data or {}).get("nonce")
    return value if isinstance(value, str) and value.isalnum() and len(value) <= 64 else None


@dataclass
class OperatorDesk:
    """The desk of one robot of a lab (see the module); the evaluator's side."""

    folder: Path
    robot: str
    lab: str = "lab"

    @classmethod
    def of(cls, lab, robot: str) -> OperatorDesk:
        """The desk of ``lab``'s robot ``robot`` (the folder made and checked)."""
        if lab.operator.folder is None:
            raise OperatorError(f"lab {lab.name!r}: operator.folder is not set (load the lab with load_lab)")
        return cls(_private_folder(Path(lab.operator.folder) / robot), robot, lab.name)

    def _clear(self, *patterns: str) -> None:
        for pattern in patterns:
            for p in self.folder.glob(pattern):
                p.unlink(missing_ok=True)

    def place(self, request: str, timeout: float, *, tell: Callable[[str], None] | None = None,
              poll: float = 0.1) -> float:
        """Ask for the robot to be placed (``request``: where, for which episode) and wait for the operator's
        ``ready``; the seconds waited. :class:`OperatorTimeout` after ``timeout`` s without one."""
        self._clear("ready-*", "waiting.json")
        nonce = secrets.token_hex(8)
        _write(self.folder / "waiting.json", {"nonce": nonce, "robot": self.robot, "lab": self.lab,
                                              "request": request, "since": time.time()})
        if tell is not None:
            tell(f"lab {self.lab!r}: {request}; then run `proxybench autolab ready LAB.yaml {self.robot}` "
                 f"(waiting up to {timeout:g} s)")
        began = time.monotonic()
        try:
            while not (self.folder / f"ready-{nonce}").exists():
                if time.monotonic() - began > timeout:
                    raise OperatorTimeout(f"operator-timeout: no one confirmed robot {self.robot!r} placed within "
                                          f"lab {self.lab!r}'s operator.timeout_s ({timeout:g} s): {request}")
                time.sleep(poll)
        finally:
            self._clear("ready-*", "waiting.json")
        return time.monotonic() - began

    def open_episode(self, what: str) -> str:
        """An episode of the robot begins (``what``: which); interventions from now on end it."""
        self._clear("intervention-*.json", "episode.json")
        nonce = secrets.token_hex(8)
        _write(self.folder / "episode.json", {"nonce": nonce, "robot": self.robot, "lab": self.lab,
                                              "episode": what, "since": time.time()})
        return nonce

    def intervention(self, nonce: str) -> str | None:
        """The operator's reason when they intervened in the episode ``nonce``; None while no one has."""
        path = self.folder / f"intervention-{nonce}.json"
        if not path.exists():
            return None
        try:
            data = _read(path) or {}
        except OperatorError as exc:
            return f"(an intervention that could not be read: {exc})"
        return _one_line(data.get("reason") or "no reason given")

    def close_episode(self) -> None:
        """The episode ended: later interventions are refused."""
        self._clear("episode.json", "intervention-*.json")


def _desk(lab, robot: str) -> OperatorDesk:
    lab.robot(robot)  # a KeyError naming the lab's robots
    return OperatorDesk.of(lab, robot)


def confirm_ready(lab, robot: str) -> str:
    """The operator's ``ready``: robot ``robot`` stands where the evaluator asked; what it had asked."""
    desk = _desk(lab, robot)
    waiting = _read(desk.folder / "waiting.json")
    nonce = _nonce(waiting)
    if nonce is None:
        raise OperatorError(f"lab {lab.name!r}: no evaluator is waiting for robot {robot!r} to be placed "
                            f"({desk.folder / 'waiting.json'} is absent)")
    _write(desk.folder / f"ready-{nonce}", {"nonce": nonce, "at": time.time()})
    return _one_line((waiting or {}).get("request", ""), 500)


def intervene(lab, robot: str, reason: str) -> str:
    """The operator stepped in: the episode robot ``robot`` runs now ends (and its job, as the lab's fault);
    which episode it was."""
    desk = _desk(lab, robot)
    episode = _read(desk.folder / "episode.json")
    nonce = _nonce(episode)
    if nonce is None:
        raise OperatorError(f"lab {lab.name!r}: robot {robot!r} runs no episode now ({desk.folder / 'episode.json'} "
                            "is absent): nothing to intervene in")
    _write(desk.folder / f"intervention-{nonce}.json", {"reason": _one_line(reason), "at": time.time()})
    return _one_line((episode or {}).get("episode", ""))
