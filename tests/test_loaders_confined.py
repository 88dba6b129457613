"""Loaders stay in their folder (issue 23 §4, §7; issue 28 §1): every path a recorded target, a benchmark file or
an experiment file names lies inside that file's folder, through no link; names that become file names are
checked as such; the trajectories pattern is a template of {agent} and {episode} only; file sizes and row
counts are checked before reading; every YAML goes through the bounded loader. Each refusal is a clear error
naming the file and the field, never a traceback, and never shows an outside file's content.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from proxybench.targets import recorded
from proxybench.targets.manifest import TargetError, load_manifest
from proxybench.targets.recorded import check_recording, load_recording
from proxybench.tasks.benchmark import Benchmark, BenchmarkError

SECRET = "SECRET-first-line-of-the-users-file"


def _csv(path: Path, n: int = 20, extra: dict[str, str] | None = None) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cols = {"t": [0.1 * k for k in range(n)], "x": [0.3 + 0.01 * k for k in range(n)], "y": [0.9] * n,
            "theta": [0.0] * n, **{k: [v] * n for k, v in (extra or {}).items()}}
    pd.DataFrame(cols).to_csv(path, index=False)


def _target(root: Path, manifest: dict, files: dict[str, Path | None] | None = None) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    data = {"source": "real", "map": "loop_3x3", "seconds": 2.0, "agents": ["a"], "episodes": [0], **manifest}
    (root / "target.yaml").write_text(yaml.safe_dump(data))
    for name, target in (files or {}).items():
        if target is None:
            _csv(root / name)
    return root


@pytest.fixture
def outside(tmp_path: Path) -> Path:
    """A user's file and folder next to the recording (what it must never read)."""
    secret = tmp_path / "home" / "notes.csv"
    secret.parent.mkdir()
    secret.write_text(f"{SECRET}\nt,x,y,theta\n")
    return secret


def _problems(root: Path) -> str:
    report = check_recording(root)
    assert not report.ok
    return "\n".join(report.problems)


@pytest.mark.parametrize("pattern", ["../home/{agent}-{episode}.csv", "/etc/{agent}{episode}", "~/{agent}{episode}",
                                     "{0}/{agent}{episode}", "{agent}/{episode}{agent[99]}",
                                     "{agent}{episode}{agent.__class__}", "{agent}/{episode}{episode:>3000}",
                                     "{agent}{episode}{agent!r}", "{agent}{episode}{episode:x}", "{agent}{episode}{",
                                     "{agent}/{name}{episode}"])
def test_a_trajectories_pattern_is_a_template_of_agent_and_episode_inside_the_folder(tmp_path, outside,
                                                                                      pattern) -> None:
    root = _target(tmp_path / "rec", {"trajectories": pattern})
    with pytest.raises(TargetError) as info:
        load_manifest(root)
    text = str(info.value)
    assert "target.yaml: trajectories:" in text and SECRET not in text, text


@pytest.mark.parametrize("name", ["../../home/notes", "a/b", ".", "..", " a", "a\x00", "x" * 129])
def test_agent_names_are_path_components(tmp_path, name: str) -> None:
    root = _target(tmp_path / "rec", {"agents": [name]})
    with pytest.raises(TargetError, match=r"target\.yaml: agents: .*file names"):
        load_manifest(root)


def test_zero_padded_patterns_and_episode_ids_as_written(tmp_path) -> None:
    root = _target(tmp_path / "padded", {"trajectories": "runs/{agent}/ep{episode:02d}.csv", "episodes": [0, 1, 10]})
    for e in ("00", "01", "10"):
        _csv(root / "runs" / "a" / f"ep{e}.csv")
    assert check_recording(root).ok, check_recording(root).problems
    root = _target(tmp_path / "written", {"trajectories": "runs/{agent}/ep{episode}.csv", "episodes": ["00", "07"]})
    for e in ("00", "07"):
        _csv(root / "runs" / "a" / f"ep{e}.csv")
    report = check_recording(root)
    assert report.ok, report.problems
    assert sorted(e.episode for e in report.episodes) == [0, 7]
    with pytest.raises(TargetError, match="listed twice"):
        load_manifest(_target(tmp_path / "twice", {"episodes": ["0", "00"]}))
    with pytest.raises(TargetError, match="not an episode id"):
        load_manifest(_target(tmp_path / "bad", {"episodes": ["ep1"]}))


@pytest.mark.parametrize("case", ["file link", "folder link", "map outside", "map link", "metrics outside"])
def test_links_and_paths_out_of_the_folder_are_refused(tmp_path, outside, case: str) -> None:
    root = tmp_path / "rec"
    if case == "file link":
        _target(root, {"trajectories": "runs/{agent}-{episode}.csv"})
        (root / "runs").mkdir()
        (root / "runs" / "a-0.csv").symlink_to(outside)
    elif case == "folder link":
        _target(root, {"trajectories": "runs/{agent}-{episode}.csv"})
        _csv(outside.parent / "a-0.csv")
        (root / "runs").symlink_to(outside.parent)
    elif case == "map outside":
        _target(root, {"map": "../home/notes.yaml"})
        outside.with_suffix(".yaml").write_text(SECRET + "\n")
    elif case == "map link":
        outside.with_suffix(".yaml").write_text(SECRET + "\n")
        _target(root, {"map": "my_map.yaml"})
        (root / "my_map.yaml").symlink_to(outside.with_suffix(".yaml"))
    else:
        _target(root, {"metrics_table": "../home/notes.csv"})
    text = _problems(root)
    assert ("is a link" in text or "leaves the folder" in text) and SECRET not in text, text


def test_file_sizes_and_rows_are_checked_before_reading(tmp_path, monkeypatch) -> None:
    import pyarrow.parquet as pq

    root = _target(tmp_path / "rec", {"trajectories": "{agent}-{episode}.parquet", "agents": ["a", "b"]})
    n = 5000
    pd.DataFrame({"t": np.arange(n) * 0.01, "x": np.full(n, 0.3), "y": np.full(n, 0.9),
                  "theta": np.zeros(n)}).to_parquet(root / "a-0.parquet")
    (root / "b-0.parquet").write_bytes((root / "a-0.parquet").read_bytes())
    monkeypatch.setattr(recorded, "LIMITS", recorded.FileLimits(rows=1000))

    def never(*args, **kwargs):
        raise AssertionError("a file over the limits was read")

    monkeypatch.setattr(pq, "read_table", never)
    text = _problems(root)
    assert "a-0.parquet: 5000 rows; a file of a recording holds at most 1000" in text, text
    root = _target(tmp_path / "csv", {"trajectories": "{agent}-{episode}.csv"}, {"a-0.csv": None})
    monkeypatch.setattr(recorded, "LIMITS", recorded.FileLimits(csv_bytes=100))
    assert "a CSV file holds at most 100" in _problems(root)


@pytest.mark.parametrize(("content", "says"), [
    (b"source: real\nmap: \xff\xfe\n", "not UTF-8"),
    (b"source: " + b"[" * 20_000, "nested deeper"),
    (None, "is a folder"),
    (b"x" * (2 << 20), "at most"),
])
def test_a_hostile_target_yaml_is_a_clear_error(tmp_path, content: bytes | None, says: str) -> None:
    root = tmp_path / "rec"
    root.mkdir()
    if content is None:
        (root / "target.yaml").mkdir()
    else:
        (root / "target.yaml").write_bytes(content)
    with pytest.raises(TargetError, match=says):
        load_recording(root)


def test_nan_truth_is_refused(tmp_path) -> None:
    root = _target(tmp_path / "rec", {"truth": {"trim": math.nan}})
    with pytest.raises(TargetError, match=r"truth\.trim"):
        load_manifest(root)


def test_an_extra_text_column_is_caught_by_the_check(tmp_path) -> None:
    root = _target(tmp_path / "rec", {"trajectories": "{agent}-{episode}.csv"})
    _csv(root / "a-0.csv", extra={"notes": "slipped here"})
    text = _problems(root)
    assert "a-0.csv: row 1 (line 2), column 'notes': 'slipped here' is not a finite number" in text, text


# -- benchmark files -------------------------------------------------------------------------------------

BENCH = {"name": "b", "map": "loop_3x3", "episodes": {"count": 1, "seed": 0}, "duration": 1.0,
         "metrics": ["survival_time"], "scoring": [{"metric": "survival_time_median"}]}


@pytest.mark.parametrize(("change", "says"), [
    ({"map": "../home/notes.yaml"}, "map: '../home/notes.yaml' leaves the folder"),
    ({"map": "/etc/passwd.yaml"}, "map: '/etc/passwd.yaml' is not relative"),
    ({"map": "linked.yaml"}, "is a link"),
    ({"agents": [{"name": "n", "command": "x", "cwd": "../home"}]}, "agents: entry 0: cwd: '../home' leaves"),
    ({"agents": [{"name": "n", "command": "x", "cwd": "~nosuchuser/x"}]}, "agents: entry 0: cwd: '~nosuchuser/x'"),
    ({"agents": [{"name": "n", "command": "x", "step_timeout": 1e300}]}, "step_timeout: Input should be less"),
    ({"agents": [{"name": "n", "command": "x", "start_timeout": 2**31}]}, "start_timeout: Input should be less"),
])
def test_benchmark_paths_stay_in_its_folder_and_numbers_are_bounded(tmp_path, outside, change, says) -> None:
    folder = tmp_path / "bench"
    folder.mkdir()
    outside.with_suffix(".yaml").write_text(SECRET + "\n")
    (folder / "linked.yaml").symlink_to(outside.with_suffix(".yaml"))
    path = folder / "b.yaml"
    path.write_text(yaml.safe_dump({**BENCH, **change}))
    with pytest.raises(BenchmarkError) as info:
        Benchmark.load(path)
    assert says in str(info.value) and SECRET not in str(info.value), str(info.value)


def test_a_map_file_nested_20000_deep_is_a_clear_error(tmp_path) -> None:
    (tmp_path / "deep.yaml").write_text("tiles: " + "[" * 20_000)
    path = tmp_path / "b.yaml"
    path.write_text(yaml.safe_dump({**BENCH, "map": "deep.yaml"}))
    with pytest.raises(BenchmarkError, match="nested deeper than 64 levels"):
        Benchmark.load(path)


@pytest.mark.parametrize(("content", "says"), [
    (b"name: \xff\n", "not UTF-8"), (b"name: " + b"[" * 20_000, "nested deeper"), (None, "is a folder")])
def test_a_hostile_benchmark_file_is_a_clear_error(tmp_path, content, says) -> None:
    path = tmp_path / "b.yaml"
    if content is None:
        path.mkdir()
    else:
        path.write_bytes(content)
    with pytest.raises(BenchmarkError, match=says):
        Benchmark.load(path)


# -- experiment files and the command line -----------------------------------------------------------------


@pytest.mark.parametrize(("content", "says"), [
    ("robot_options: {cwd: ../bridge}\n", "robot_options.cwd: '../bridge' leaves the folder"),
    ("agents:\n  - {name: n, command: x, cwd: ../sub}\n", "agents.0.cwd: '../sub' leaves the folder"),
    ("truth: {trim: .nan}\n", "truth.trim"),
    ("target: " + "[" * 20_000, "nested deeper"),
    (None, "is a folder"),
])
def test_a_hostile_experiment_file_is_a_clear_error(tmp_path, content, says) -> None:
    from proxybench.experiments.config import ConfigError, load_config

    path = tmp_path / "exp" / "exp.yaml"
    path.parent.mkdir()
    if content is None:
        path.mkdir()
    else:
        path.write_text(content)
    with pytest.raises(ConfigError, match=says):
        load_config(path)


@pytest.mark.parametrize("value", ["1e300", "2147484"])
def test_absurd_timeouts_on_the_command_line_are_usage_errors(value: str) -> None:
    from proxybench.cli import app

    result = CliRunner().invoke(app, ["agent", "check", "python3 agent.py", "--step-timeout", value],
                                env={"COLUMNS": "200"})
    assert result.exit_code == 2 and "--step-timeout" in result.output and "less than or equal" in result.output
    assert "Traceback" not in result.output and "OverflowError" not in result.output
