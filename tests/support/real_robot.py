"""What the tests of a lab's non-virtual robot share (a DTPS robot, tests/test_autolab_dtps_robot.py; a robot node,
tests/test_autolab_node_robot.py): the lab's description, the operator (a thread answering the desk), and one
Autolab job submitted and taken by the lab's evaluator.

The job helpers need the server (fastapi, uvicorn): they import the server tests' helpers when called, so a test
module that uses only the lab and the operator runs without them.
"""

from __future__ import annotations

import contextlib
import json
import threading
import time
from pathlib import Path

__all__ = ["LAB", "Operator", "answer", "lab_evaluator", "operator_places", "run_lab_job", "submit", "write_lab"]

#: lab.yaml of one DTPS robot at 127.0.0.1:PORT and no watchtowers yet (``streams: []``), placed by its operator
LAB = """\
format: proxybench-lab/1
name: real-lab
map: loop_3x3
robots:
  - {name: db1, dtps: 127.0.0.1:PORT/robot/map_0/vehicle_0}
watchtowers:
  streams: []
reset: {mode: operator}
operator: {timeout_s: 600}
"""


def answer(fn, path: Path, *args) -> threading.Thread:
    """A thread that calls ``fn(*args)`` once ``path`` exists (the operator, reacting to the desk)."""
    def run() -> None:
        while not path.exists():
            time.sleep(0.02)
        fn(*args)
    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def operator_places(lab, robot: str = "db1") -> threading.Thread:
    """The operator confirming ``robot`` placed (``autolab ready``) once the evaluator asks."""
    from proxybench.autolab.operator import confirm_ready

    return answer(confirm_ready, lab.operator.folder / robot / "waiting.json", lab, robot)


class Operator(threading.Thread):
    """The operator confirming every placement the evaluator asks for (``autolab ready``), each request once, until
    :meth:`stop`; :attr:`requests`: what was asked, in order (an invalid run run again is placed again)."""

    def __init__(self, lab, robot: str = "db1"):
        super().__init__(daemon=True)
        self.lab, self.robot = lab, robot
        self.requests: list[str] = []
        self._done = threading.Event()
        self.start()

    def run(self) -> None:
        from proxybench.autolab.operator import OperatorError, confirm_ready

        waiting = self.lab.operator.folder / self.robot / "waiting.json"
        answered = None
        while not self._done.wait(0.02):
            with contextlib.suppress(OSError, ValueError):
                nonce = json.loads(waiting.read_text()).get("nonce")
                if nonce is not None and nonce != answered:
                    with contextlib.suppress(OperatorError):  # the request went away meanwhile
                        self.requests.append(confirm_ready(self.lab, self.robot))
                    answered = nonce

    def stop(self) -> None:
        self._done.set()
        self.join(timeout=60)


def write_lab(tmp_path: Path, port: int, towers: str, layout) -> None:
    """``tmp_path/lab.yaml``: :data:`LAB` with the robot on ``port`` and ``layout``'s watchtowers served at
    ``towers`` (HOST:PORT) as the lab's own DTPS cameras, their calibrations in ``tmp_path/cal``."""
    from proxybench.autolab.calibration import draw_calibrations, write_calibration

    cals, _ = draw_calibrations(layout)  # what the stand-in's watchtowers publish: the lab's calibrations
    (tmp_path / "cal").mkdir()
    lines = []
    for w in layout.watchtowers:
        write_calibration(tmp_path / "cal" / f"{w.name}.yaml", cals[w.name])
        lines.append(f"    - {{name: {w.name}, dtps: {towers}/{w.name}, calibration: cal/{w.name}.yaml}}")
    tags = ", ".join(f"{{id: {g.id}, x: {g.x}, y: {g.y}, heading: {g.heading}, size: {g.size}}}"
                     for g in layout.ground_tags)
    text = LAB.replace("PORT", str(port)).replace("  streams: []", "  streams:\n" + "\n".join(lines)
                                                  + f"\n  ground_tags: [{tags}]")
    (tmp_path / "lab.yaml").write_text(text)


def submit(served, tmp_path: Path, *, bench: str | None = None, package: bytes | None = None,
           name: str = "sdk-lane") -> dict:
    """The Autolab benchmark (tests/test_autolab_evaluator.py's ``BENCH`` unless ``bench``) and a submission to it:
    ``package`` (default: the lane-following SDK package), as ``name``."""
    from test_autolab_evaluator import BENCH, sdk_package

    served.admin.post("/benchmarks", {"yaml": BENCH if bench is None else bench, "features": ["autolab"],
                                      "hidden_split": False})
    archive = tmp_path / f"{name}.zip"
    archive.write_bytes(sdk_package() if package is None else package)
    return served.developer.submit_archive(archive, name, benchmark="autolab_tiny")


def lab_evaluator(served, tmp_path: Path, lab):
    """The lab's evaluator (simulation and Autolab jobs, no video)."""
    from test_evaluator import evaluator

    return evaluator(served, tmp_path, name="lab", video=False, features=("sim", "autolab"), autolab=lab)


def run_lab_job(served, tmp_path: Path, lab, sub: dict,
                requests: list[str] | None = None) -> tuple[str | None, dict, list[dict]]:
    """The lab's evaluator takes one job while the operator places the robot as often as asked: (its status, the
    submission's job, its results); ``requests``, where given, gets the placement requests the operator answered."""
    from test_evaluator import the_job

    operator = Operator(lab)
    try:
        status = lab_evaluator(served, tmp_path, lab).take_one()
    finally:
        operator.stop()
    if requests is not None:
        requests.extend(operator.requests)
    job, results = the_job(served, sub["id"])
    return status, job, results
