"""Benchmark files: the built-ins load, every mistake is reported with file and field path, episodes are fixed."""

from __future__ import annotations

import copy
import shutil
from importlib import resources
from pathlib import Path

import pytest
import yaml

from proxybench.domain.params import DomainParams
from proxybench.domain.reality import reality_params
from proxybench.tasks.benchmark import (
    NAMED_DOMAINS,
    Benchmark,
    BenchmarkError,
    EpisodeSpec,
    builtin_benchmark_names,
    parse_scoring_metric,
)
from proxybench.tasks.scoring import Criterion


def builtin_data(name: str) -> dict:
    return yaml.safe_load((resources.files("proxybench") / "benchmarks" / f"{name}.yaml").read_text())


def write(tmp_path: Path, data: dict, name: str = "bench.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_builtins_load():
    assert {"aido_lf", "thesis_loop"} <= set(builtin_benchmark_names())
    for name in builtin_benchmark_names():
        b = Benchmark.load(name)
        assert b.name == name and b.description
        assert b.episode_specs() and b.criteria()


def test_aido_lf_contents():
    b = Benchmark.load("aido_lf")
    assert b.criteria() == [
        Criterion("driven_lanedir_consec_median", True, 0.62),
        Criterion("survival_time_median", True, 2.0),
        Criterion("deviation_center_line_median", False, 0.01),
        Criterion("in_drivable_lane_median", False, 0.2),
    ]
    p = b.domain_params()
    assert (p.physics_rate, p.frame_rate, p.command_delay, p.substeps) == (60.0, 15.0, 0.15, 4)
    assert b.duration == 60.0 and b.frames == 900 and b.camera_only
    assert b.load_map().name == "loop_3x3"
    assert len(b.episode_specs()) == 5


def test_thesis_loop_contents():
    b = Benchmark.load("thesis_loop")
    assert b.metrics == ["distance", "survival_time"]
    assert [c.metric for c in b.criteria()] == ["distance_mean", "survival_time_mean"]
    assert all(c.higher_is_better for c in b.criteria())
    assert len(b.episode_specs()) == 10 and b.domain_params() == DomainParams()


def _set(path: str, value):
    """A change to the aido_lf data: set (or add) the value at a dotted path."""
    def apply(d):
        *parents, last = path.split(".")
        for p in parents:
            d = d[int(p)] if isinstance(d, list) else d[p]
        if isinstance(d, list):
            d[int(last)] = value
        else:
            d[last] = value
    return apply


INVALID = [
    # (change, field path, words in the message)
    (_set("durration", 60), "durration", "unknown key (did you mean duration"),
    (_set("episodes.cuont", 3), "episodes.cuont", "unknown key"),
    (_set("domain.params.trimm", 0.1), "domain.params", "unknown domain parameter 'trimm' (did you mean 'trim'?)"),
    (_set("scoring.1.tol", 1.0), "scoring.1.tol", "allowed: metric, higher_is_better, tolerance"),
    (_set("duration", -5), "duration", "greater than 0"),
    (_set("scoring.0.tolerance", -0.1), "scoring.0.tolerance", "Input should be greater than or equal to 0"),
    (_set("metrics.1", "speed"), "metrics.1", "unknown metric 'speed'"),
    (_set("metrics.4", "survival_time"), "metrics.4", "listed twice"),
    (_set("scoring.3.metric", "lane_score_median"), "scoring.3.metric", "not in metrics"),
    (_set("scoring.1.metric", "survival_time_p90"), "scoring.1.metric", "unknown statistic 'p90'"),
    (_set("scoring.1.metric", "speed_median"), "scoring.1.metric", "unknown metric"),
    (_set("scoring.2.higher_is_better", True), "scoring.2.higher_is_better", "deviation_center_line is ↓"),
    (_set("episodes", {"poses": [[0.3, 0.3, 1.57], [0.8775, 0.8775, 0.0]]}), "episodes.poses.1", "grass tile"),
    (_set("episodes", {"poses": [[5.0, 5.0, 0.0]]}), "episodes.poses.0", "not on the road"),
    (_set("episodes", {"poses": [[0.3, 0.3, 1.57]], "seeds": [1, 2]}), "episodes", "seeds has 2 entries"),
    (_set("episodes", {"count": 2, "poses": [[0.3, 0.3, 1.57]]}), "episodes", "either count"),
    (_set("episodes.count", 0), "episodes.count", "greater than 0"),
    (_set("physics_rate", 50.0), "frame_rate", "whole multiple of frame_rate"),
    (_set("domain.params.frame_rate", 30.0), "domain.params", "at the top level"),
    (_set("domain", {"named": "mars"}), "domain.named", "unknown domain 'mars'"),
    (_set("map", "loop_4x4"), "map", "no such map file or built-in map"),
    (_set("npcs", [{"speed": 0.2}]), "npcs.0", "needs a 'kind'"),
    (_set("duration", 0.01), "duration", "shorter than one frame"),
]


@pytest.mark.parametrize("change, field, words", INVALID, ids=[case[1] + ":" + case[2][:20] for case in INVALID])
def test_invalid_files_name_file_and_field(tmp_path, change, field, words):
    data = copy.deepcopy(builtin_data("aido_lf"))
    change(data)
    path = write(tmp_path, data, "aido_lf.yaml")
    with pytest.raises(BenchmarkError) as exc_info:
        Benchmark.load(path)
    msg = str(exc_info.value)
    assert f"{path}: {field}: " in msg, msg
    assert words in msg, msg


def test_error_message_format_and_several_problems_at_once(tmp_path):
    data = builtin_data("aido_lf")
    data["scoring"][0]["tolerance"] = -1
    data["durationn"] = 3
    path = write(tmp_path, data, "aido_lf.yaml")
    with pytest.raises(BenchmarkError) as exc_info:
        Benchmark.load(path)
    lines = str(exc_info.value).splitlines()
    assert f"{path}: scoring.0.tolerance: Input should be greater than or equal to 0" in lines
    assert any(line.startswith(f"{path}: durationn: unknown key") for line in lines)


def test_bad_map_file_reports_its_map_error(tmp_path):
    (tmp_path / "broken.yaml").write_text("tiles:\n- [straight/W, lava]\ntile_size: 0.585\n")
    data = {**builtin_data("aido_lf"), "map": "broken.yaml"}
    with pytest.raises(BenchmarkError, match=r"bench\.yaml: map: .*broken\.yaml.*lava"):
        Benchmark.load(write(tmp_path, data))


def test_relative_map_path_is_relative_to_the_benchmark_file(tmp_path, monkeypatch):
    (tmp_path / "maps").mkdir()
    shutil.copy(resources.files("proxybench") / "maps" / "loop_3x3.yaml", tmp_path / "maps" / "my_loop.yaml")
    path = write(tmp_path, {**builtin_data("thesis_loop"), "map": "maps/my_loop.yaml"})
    monkeypatch.chdir("/")
    assert Benchmark.load(path).load_map().name == "my_loop"


def test_file_level_problems(tmp_path):
    with pytest.raises(BenchmarkError, match=r"no such benchmark file or built-in benchmark .*aido_lf"):
        Benchmark.load("no_such_benchmark")
    bad_yaml = tmp_path / "syntax.yaml"
    bad_yaml.write_text("name: x\nepisodes: [1, 2\n")
    with pytest.raises(BenchmarkError, match=r"syntax\.yaml:\d+:\d+: not valid YAML"):
        Benchmark.load(bad_yaml)
    listing = tmp_path / "list.yaml"
    listing.write_text("- 1\n- 2\n")
    with pytest.raises(BenchmarkError, match=r"list\.yaml: expected a mapping"):
        Benchmark.load(listing)


# ---------------------------------------------------------------------------------------------------
# episodes, domain, scoring names


def test_episode_specs_are_deterministic_and_seed_dependent():
    a, b = Benchmark.load("thesis_loop"), Benchmark.load("thesis_loop")
    specs = a.episode_specs()
    assert specs == b.episode_specs() == a.episode_specs()
    assert [s.index for s in specs] == list(range(10)) and all(s.pose is None for s in specs)
    assert len({s.seed for s in specs}) == 10
    other = Benchmark.from_dict({**builtin_data("thesis_loop"), "episodes": {"count": 10, "seed": 1}})
    assert {s.seed for s in other.episode_specs()}.isdisjoint({s.seed for s in specs})
    # episode i's seed depends on (seed, i) only: more episodes keep the first ones
    more = Benchmark.from_dict({**builtin_data("thesis_loop"), "episodes": {"count": 12, "seed": 0}})
    assert more.episode_specs()[:10] == specs


def test_explicit_poses_with_and_without_seeds():
    data = builtin_data("thesis_loop")
    poses = [[0.3, 0.3, 1.57], [1.0, 0.17, 0.0]]
    b = Benchmark.from_dict({**data, "episodes": {"poses": poses, "seeds": [7, 8]}})
    assert b.episode_specs() == [EpisodeSpec(0, 7, (0.3, 0.3, 1.57)), EpisodeSpec(1, 8, (1.0, 0.17, 0.0))]
    derived = Benchmark.from_dict({**data, "episodes": {"poses": poses}}).episode_specs()
    counted = Benchmark.load("thesis_loop").episode_specs()
    assert [s.seed for s in derived] == [s.seed for s in counted[:2]]


def test_named_domains_and_extension(monkeypatch):
    data = builtin_data("thesis_loop")
    b = Benchmark.from_dict({**data, "frame_rate": 30.0, "domain": {"named": "reality"}})
    assert b.domain_params() == reality_params().replace(frame_rate=30.0)
    monkeypatch.setitem(NAMED_DOMAINS, "laggy", lambda: DomainParams(command_delay=0.3))
    assert Benchmark.from_dict({**data, "domain": {"named": "laggy"}}).domain_params().command_delay == 0.3
    with pytest.raises(BenchmarkError, match="domain: give either params or named"):
        Benchmark.from_dict({**data, "domain": {"named": "laggy", "params": {"trim": 0.1}}})


def test_scoring_names_and_default_direction():
    assert parse_scoring_metric("driven_lanedir_consec_median") == ("driven_lanedir_consec", "median")
    assert parse_scoring_metric("driven_any_max") == ("driven_any", "max")
    assert parse_scoring_metric("survival_time") == ("survival_time", "mean")
    data = builtin_data("aido_lf")
    data["scoring"] = [{"metric": "deviation_heading"}, {"metric": "survival_time_min", "tolerance": 1.0}]
    b = Benchmark.from_dict(data)
    assert b.criteria() == [Criterion("deviation_heading_mean", False, 0.0), Criterion("survival_time_min", True, 1.0)]


def test_camera_only_refuses_privileged_agents():
    class Expert:
        name, privileged = "pure_pursuit", True

    class Camera:
        name, privileged = "vision", False

    aido, thesis = Benchmark.load("aido_lf"), Benchmark.load("thesis_loop")
    with pytest.raises(BenchmarkError, match=r"camera-only.*pure_pursuit"):
        aido.check_agent(Expert())
    aido.check_agent(Camera())
    thesis.check_agent(Expert())
