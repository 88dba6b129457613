"""An invalid run retried as the benchmark says (issue 36): an episode the DTA's validation finds invalid (a stream
stopped, the robot lost) is the lab's fault, so the Autolab evaluator resets the robot and runs that episode again,
up to the benchmark's ``invalid_retries`` times within the job, keeping every attempt in the report and the
artifacts; only when the retries are spent does the job end ``host-error`` (back to the queue), saying each
attempt's verdict.

The drill ``streams_stop_attempts`` stops the watchtowers' streams in the first attempts only, so a retry is valid.
The server and package helpers are test_evaluator's and test_autolab_evaluator's (one 3-s episode).
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import pytest
import yaml

from proxybench.tasks.benchmark import Benchmark

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

from support.dtps import sdk
from support.real_robot import check_retries_spent
from support.sandbox import AGENT_USER_GROUP, require_safe_sandbox
from test_autolab_evaluator import BENCH, LAB, sdk_package
from test_evaluator import Served, evaluator, served, the_job  # noqa: F401 - served: test_evaluator's fixture

DRILL = "drills: {streams_stop_s: 1.5}\n"  # every watchtower's stream ends 1.5 s into the 3-s episode


def _bench(**change: object) -> Benchmark:
    return Benchmark.from_dict({**yaml.safe_load(BENCH), **change}, origin="autolab_tiny")


def test_a_benchmark_says_how_often_an_invalid_run_is_retried() -> None:
    from proxybench.tasks.benchmark import BenchmarkError

    assert _bench().invalid_retries == 2 and _bench(invalid_retries=0).invalid_retries == 0
    for bad in (-1, 11, "twice", 1.5, "2", True):  # a count, written as one
        with pytest.raises((BenchmarkError, ValueError), match="invalid_retries"):
            _bench(invalid_retries=bad)


def test_the_drill_can_spare_later_attempts_and_needs_its_time() -> None:
    from proxybench.autolab.lab import Drills

    drill = Drills(streams_stop_s=1.5, streams_stop_attempts=1)
    assert drill.stops_streams(1) and not drill.stops_streams(2)
    assert Drills(streams_stop_s=1.5).stops_streams(3) and not Drills().stops_streams(1)
    with pytest.raises(ValueError, match="streams_stop_attempts: give streams_stop_s"):
        Drills(streams_stop_attempts=1)


def test_the_api_shows_an_autolab_benchmarks_retries(served: Served) -> None:  # noqa: F811
    served.admin.post("/benchmarks", {"yaml": BENCH.replace("camera_only: true", "camera_only: true\n"
                                                            "invalid_retries: 3"), "features": ["autolab"],
                                      "hidden_split": False})
    assert served.developer.get("/benchmarks/autolab_tiny")["invalid_retries"] == 3
    plain = served.developer.get("/benchmarks")
    assert all("invalid_retries" not in b for b in plain if "autolab" not in b["features"])


def test_a_host_error_after_the_retries_names_every_attempt() -> None:
    from proxybench.evaluator.autolab import AutolabEpisode
    from proxybench.evaluator.autolab_attempts import unfit

    def attempt(k: int, reasons: list[str]) -> AutolabEpisode:
        return AutolabEpisode(0, None, {}, False, reasons, False, 0, 10, attempt=k)

    last = attempt(3, ["robot 'db1' never localised"])
    last.earlier = [attempt(1, ["ended prematurely"]), attempt(2, [])]
    text = unfit(last, "validation", 2)
    assert text.startswith("tracking_lost: validation episode 0 is not fit to be scored (the DTA's validation): "
                           "robot 'db1' never localised; after 3 attempts (the benchmark's invalid_retries: 2): ")
    assert ("attempt 1: tracking_lost (ended prematurely); attempt 2: tracking_lost (the watchtowers localised the "
            "robot fewer than twice); attempt 3: tracking_lost (robot 'db1' never localised)") in text
    assert [a["attempt"] for a in last.report()["attempts"]] == [1, 2, 3]


def test_every_robots_retries_give_the_job_the_labs_time_and_keep_each_attempt() -> None:
    """The loop a virtual robot's, a DTPS robot's and a robot node's jobs share (evaluator/autolab_attempts.py)."""
    from proxybench.evaluator.autolab import AutolabEpisode
    from proxybench.evaluator.autolab_attempts import retry_invalid

    class Job:
        extra = 0.0

        def allow_extra_wall(self, seconds: float) -> None:
            self.extra += seconds

    bench, job = _bench(invalid_retries=2), Job()
    ran: list[tuple[int, int]] = []

    def run_again(bad: list[AutolabEpisode], attempt: int) -> list[AutolabEpisode]:
        ran.extend((e.episode, attempt) for e in bad)
        return [AutolabEpisode(e.episode, None, {}, False, ["lost"], True, 0, 5, attempt=attempt) for e in bad]

    fit = AutolabEpisode(0, Path("fit.parquet"), {}, True, [], False, 9, 9)
    bad = AutolabEpisode(1, None, {}, False, ["lost"], True, 0, 5)
    done = retry_invalid(job, bench, "validation", "db1", [fit, bad], run_again)
    assert ran == [(1, 2), (1, 3)] and done[0] is fit  # only the invalid episode, twice more
    assert [a.attempt for a in [*done[1].earlier, done[1]]] == [1, 2, 3]
    assert job.extra == pytest.approx(2 * bench.duration * bench.wall_time_factor)  # one episode's time per re-run


def _run(srv: Served, tmp_path: Path, lab: str, bench: str = BENCH) -> tuple[str, dict]:
    from proxybench.autolab.lab import load_lab

    srv.admin.post("/benchmarks", {"yaml": bench, "features": ["autolab"], "hidden_split": False})
    (tmp_path / "lab.yaml").write_text(lab)
    archive = tmp_path / "agent.zip"
    archive.write_bytes(sdk_package())
    sub = srv.developer.submit_archive(archive, "sdk-lane", benchmark="autolab_tiny")
    ev = evaluator(srv, tmp_path, name="lab", video=False, features=("sim", "autolab"),
                   autolab=load_lab(tmp_path / "lab.yaml"))
    return ev.take_one(), sub


@sdk
@AGENT_USER_GROUP
def test_an_invalid_first_attempt_is_run_again_and_the_valid_second_scores_the_job(
        served: Served, tmp_path: Path) -> None:  # noqa: F811
    require_safe_sandbox()
    status, sub = _run(served, tmp_path, LAB + "drills: {streams_stop_s: 1.5, streams_stop_attempts: 1}\n")
    job, (result,) = the_job(served, sub["id"])
    assert status == job["status"] == "success", result["message"]
    report = result["public_report"]
    (loc,) = report["localization"]
    assert report["invalid_retries"] == 2 and loc["attempt"] == 2 and loc["valid"]
    first, second = loc["attempts"]
    assert first["attempt"] == 1 and first["verdict"] == "invalid"
    assert "ended prematurely: recorded 1.4 s of 3 s" in first["reasons"][0]
    assert second == {**second, "attempt": 2, "verdict": "valid", "reasons": []}
    assert report["localization_median_error_m"] <= 0.02  # scored from the valid attempt's localisation
    assert result["public_scores"]["survival_time_median"] == 3.0  # it ran the whole episode
    assert len(report["episodes"]) == 1  # the episode once: its last attempt
    zipped = next(a for a in result["artifacts"] if a["name"] == "trajectories-validation.zip")
    with zipfile.ZipFile(io.BytesIO(served.admin.http.get(f"/artifacts/{zipped['sha256']}").content)) as zf:
        names = set(zf.namelist())
        attempts = json.loads(zf.read("attempts.json"))
    assert {"episode-0.parquet", "episode-0-track.csv", "robot-episode-0.parquet",  # the attempt that was scored
            "episode-0-attempt-1-track.csv", "robot-episode-0-attempt-1.parquet"} <= names  # and the one before
    assert [(a["attempt"], a["verdict"]) for a in attempts["0"]] == [(1, "invalid"), (2, "valid")]


@sdk
@AGENT_USER_GROUP
def test_a_run_invalid_in_every_attempt_ends_host_error_after_the_retries(served: Served,  # noqa: F811
                                                                          tmp_path: Path) -> None:
    require_safe_sandbox()
    status, sub = _run(served, tmp_path, LAB + DRILL,
                       BENCH.replace("camera_only: true", "camera_only: true\ninvalid_retries: 1"))
    message = check_retries_spent(served, status, *the_job(served, sub["id"]))  # a virtual robot: no operator
    assert "attempt 2: invalid (ended prematurely: recorded 1.4 s of 3 s" in message
