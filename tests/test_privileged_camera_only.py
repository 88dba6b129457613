"""A camera-only benchmark asks `runner.jobs.is_privileged` of every agent, in `evaluate` and in the evaluator:
a checkpoint (camera only) runs, an SDK program asking for the true pose is refused by name, and nothing raises a
KeyError for an agent that is not in the zoo (issue 33)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.evaluator.outcome import SubmissionFault
from proxybench.evaluator.run import _admitted
from proxybench.runner.evaluate import evaluate_benchmark
from proxybench.runner.jobs import AgentSpec, is_privileged
from proxybench.tasks.benchmark import Benchmark
from support.checkpoints import untrained_checkpoint

runner = CliRunner()

BENCH = """
name: camera-only
map: loop_3x3
camera_only: true
episodes: {count: 1, seed: 1}
duration: 0.5
domain: {params: {image_width: 80, image_height: 60}}
metrics: [survival_time]
scoring:
  - {metric: survival_time_median, tolerance: 0.5}
"""


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An untrained behaviour-cloning network: a real checkpoint agent, camera only."""
    return untrained_checkpoint(tmp_path_factory.mktemp("bc"))


def test_is_privileged_knows_every_flavour(checkpoint: Path) -> None:
    assert is_privileged(AgentSpec("pid")) and not is_privileged(AgentSpec("vision"))
    assert not is_privileged(AgentSpec(str(checkpoint)))  # not a zoo name: camera only, no KeyError
    assert is_privileged(AgentSpec.sdk("p", "python3 p.py", _sdk(privileged=True)))
    assert not is_privileged(AgentSpec.sdk("c", "python3 c.py"))
    assert not is_privileged(AgentSpec.node("n", "python3 n.py"))  # says so at its handshake, if at all


def test_evaluate_refuses_a_privileged_sdk_program_by_name(tmp_path: Path) -> None:
    bench = tmp_path / "bench.yaml"
    bench.write_text(BENCH + """agents:
  - vision
  - name: peeker
    sdk: python3 never_started.py
    privileged: true
""")
    res = runner.invoke(app, ["evaluate", str(bench), "--backend", "inline", "--run-dir", str(tmp_path / "run")],
                        env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    board = json.loads((tmp_path / "run" / "leaderboard.json").read_text())
    assert [r["agent"] for r in board] == ["vision"]
    assert "not admitted: peeker: privileged (reads the true lane pose)" in " ".join(res.output.split())


def test_a_checkpoint_runs_on_a_camera_only_benchmark_beside_a_refused_sdk_program(tmp_path: Path,
                                                                                    checkpoint: Path) -> None:
    bench = Benchmark.from_dict({**_bench_dict(), "camera_only": True})
    peeker = AgentSpec.sdk("peeker", "python3 never_started.py", _sdk(privileged=True))
    ev = evaluate_benchmark(bench, [AgentSpec(str(checkpoint)), peeker], tmp_path / "run", privileged=is_privileged)
    assert list(ev.refused) == ["peeker"]
    (res,) = ev.sweep.results
    assert res.agent == str(checkpoint) and res.termination == "timeout", res.message


def test_the_evaluator_admits_a_checkpoint_and_refuses_a_privileged_sdk_package(checkpoint: Path) -> None:
    bench = Benchmark.from_dict({**_bench_dict(), "camera_only": True})
    camera = AgentSpec(str(checkpoint))
    assert _admitted(bench, camera) is camera
    with pytest.raises(SubmissionFault, match=r"agent 'peeker' is privileged .* admits camera-only agents"):
        _admitted(bench, AgentSpec.sdk("peeker", "python3 a.py", _sdk(privileged=True)))
    assert _admitted(bench.model_copy(update={"camera_only": False}), AgentSpec("pid")) == AgentSpec("pid")


def _sdk(**options):
    from proxybench.dtps.options import SdkOptions

    return SdkOptions(**options)


def _bench_dict() -> dict:
    import yaml

    return yaml.safe_load(BENCH)
