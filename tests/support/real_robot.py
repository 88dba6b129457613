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

__all__ = ["LAB", "Operator", "answer", "check_retried_once", "check_retries_spent", "drilled", "lab_evaluator",
           "operator_places", "run_drilled", "run_lab_job", "submit", "write_lab"]

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


def drilled(lab_yaml: Path, attempts: int | None = None):
    """The lab at ``lab_yaml`` with the drill on its own streams: the evaluator's recording of every watchtower ends
    1.5 s into the 3-s episode, in the first ``attempts`` attempts at an episode (None: in every one); loaded."""
    from proxybench.autolab.lab import load_lab

    with open(lab_yaml, "a") as fh:
        fh.write("drills: {streams_stop_s: 1.5" + ("" if attempts is None else f", streams_stop_attempts: {attempts}")
                 + "}\n")
    return load_lab(lab_yaml)


def check_retried_once(served, result: dict, asked: list[str], record_suffix: str) -> dict:
    """What a job whose one episode was invalid at first and valid when run again shows: the operator asked twice,
    the second attempt scored, both in the report (the robot's record of each too) and in the zip (the earlier
    attempt's track and robot record, ``robot-episode-0-attempt-1<record_suffix>``; ``attempts.json``). The
    report."""
    import io
    import json
    import zipfile

    assert len(asked) == 2 and "for validation episode 0, attempt 2" in asked[1], asked  # placed again
    report = result["public_report"]
    (loc,) = report["localization"]
    assert report["invalid_retries"] == 2 and loc["attempt"] == 2 and loc["valid"]
    first, second = loc["attempts"]
    assert first["attempt"] == 1 and first["verdict"] == "invalid" and "ended prematurely" in first["reasons"][0]
    assert second == {**second, "attempt": 2, "verdict": "valid", "reasons": []}
    assert [r["attempt"] for r in report["robot_record"]] == [1, 2]  # the robot's record of each attempt
    assert result["public_scores"]["survival_time_median"] == 3.0  # scored from the valid attempt: the whole episode
    zipped = next(a for a in result["artifacts"] if a["name"] == "trajectories-validation.zip")
    with zipfile.ZipFile(io.BytesIO(served.admin.http.get(f"/artifacts/{zipped['sha256']}").content)) as zf:
        names = set(zf.namelist())
        attempts = json.loads(zf.read("attempts.json"))
    assert {"episode-0.parquet", "episode-0-track.csv", f"robot-episode-0{record_suffix}",  # the scored attempt
            "episode-0-attempt-1-track.csv", f"robot-episode-0-attempt-1{record_suffix}"} <= names  # the one before
    assert [(a["attempt"], a["verdict"]) for a in attempts["0"]] == [(1, "invalid"), (2, "valid")]
    return report


def run_drilled(served, tmp_path: Path, lab, retries: int | None = None) -> tuple[str | None, dict, list[dict],
                                                                                  list[str]]:
    """The lane-following SDK package submitted to the benchmark (``invalid_retries: retries``; None: its default)
    and run by ``lab`` (:func:`drilled`): (the status, the job, its results, the placements the operator was
    asked for)."""
    from test_autolab_evaluator import BENCH

    bench = BENCH if retries is None else BENCH.replace("camera_only: true",
                                                        f"camera_only: true\ninvalid_retries: {retries}")
    asked: list[str] = []
    status, job, results = run_lab_job(served, tmp_path, lab, submit(served, tmp_path, bench=bench), asked)
    return status, job, results, asked


def check_retries_spent(served, status: str | None, job: dict, results: list[dict],
                        asked: list[str] | None = None) -> str:
    """What a job whose one episode was invalid in both attempts (``invalid_retries: 1``) shows: ``host-error``
    naming both attempts, nothing stored, the job queued again; the operator asked twice (``asked``; None: a
    virtual robot, reset without one). The host error's message."""
    assert status == "host-error", status
    assert asked is None or len(asked) == 2, asked
    assert job["status"] == "queued" and results == []  # the lab's fault: nothing stored, another lab may run it
    (event,) = [e for e in served.admin.get(f"/jobs/{job['id']}")["events"] if e["kind"] == "host-error"]
    message = event["message"]
    assert message.startswith("invalid: validation episode 0 is not fit to be scored (the DTA's validation)"), message
    assert "after 2 attempts (the benchmark's invalid_retries: 1): attempt 1: invalid (ended prematurely" in message
    assert "; attempt 2: invalid (ended prematurely" in message
    return message
