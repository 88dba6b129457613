"""The Autolab evaluator records its watchtowers over DTPS (issue 36 item 4): a job of an SDK agent package in a lab
whose simulated watchtowers are served as DTPS camera topics and read back by the lab's reader (autolab/live.py),
as a lab's own watchtowers are. The harness is test_autolab_evaluator's (a server in a thread, SQLite)."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

from support.dtps import sdk
from support.sandbox import AGENT_USER_GROUP, require_safe_sandbox
from test_autolab_evaluator import BENCH, LAB, sdk_package
from test_evaluator import Served, evaluator, served, the_job  # noqa: F401 - served: test_evaluator's fixture

pytestmark = AGENT_USER_GROUP


@sdk
def test_the_autolab_evaluator_records_served_watchtowers_over_dtps_and_scores_from_them(
        served: Served, tmp_path: Path) -> None:  # noqa: F811
    from proxybench.autolab.lab import load_lab

    require_safe_sandbox()
    served.admin.post("/benchmarks", {"yaml": BENCH, "features": ["autolab"], "hidden_split": False})
    (tmp_path / "lab.yaml").write_text(LAB.replace("{layout: auto}", "{layout: auto, serve: dtps}"))
    archive = tmp_path / "sdk-lane.zip"
    archive.write_bytes(sdk_package())
    sub = served.developer.submit_archive(archive, "sdk-lane", benchmark="autolab_tiny")
    lab_ev = evaluator(served, tmp_path, name="lab", video=False, features=("sim", "autolab"),
                       autolab=load_lab(tmp_path / "lab.yaml"))
    status = lab_ev.take_one()
    job, (result,) = the_job(served, sub["id"])
    assert status == job["status"] == "success", result["message"]
    report = result["public_report"]
    (streams,) = report["watchtower_streams"]  # what the DTPS reader received: every frame published, none bad
    assert streams["missing"] == {} and streams["bad"] == {} and sum(streams["frames"].values()) >= 150
    assert report["watchtowers"] == 12 and report["measured_by"] == "watchtowers"
    assert report["localization_median_error_m"] <= 0.02
    (loc,) = report["localization"]  # detected online as the reader wrote them: all of them (the queue holds 512)
    online = loc["online_detection"]
    assert online["frames"] == online["localised"] == sum(streams["frames"].values()) and online["dropped"] == {}
    assert result["public_scores"]["survival_time_median"] == 3.0
