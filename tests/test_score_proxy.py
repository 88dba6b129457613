"""`proxybench score-proxy` and episode splits (issue 28, item 4): one θ scored against a target, two θ compared
paired, and a recording split into fit / held-out halves by episode ids, with no copies."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.experiments.config import ExperimentConfig
from proxybench.runner.jobs import AgentSpec
from proxybench.targets import RealityTarget
from proxybench.targets.base import parse_episodes
from proxybench.targets.record import record_target

runner = CliRunner()
AGENTS = ["straight", "pid", "pid-fast", "random"]


@pytest.mark.parametrize(("text", "ids"), [("5", 5), ("0-4,7", (0, 1, 2, 3, 4, 7)), ("7-7", (7,)), ([3, 1], (3, 1)),
                                           (" 2 - 3 ", (2, 3))])
def test_episodes_are_a_count_or_ids(text, ids):
    assert parse_episodes(text) == ids


@pytest.mark.parametrize(("text", "says"), [("4-2", "runs backwards"), ("a-b", "at 'a-b'"), ([], "no episode ids"),
                                            ("1,1", "repeat: 1"), ([-1], ">= 0"), (True, "a count or ids")])
def test_bad_episodes_say_what_is_wrong(text, says):
    with pytest.raises(ValueError, match=says):
        parse_episodes(text)
    with pytest.raises(ValueError, match="episodes"):  # the config names its field
        ExperimentConfig(episodes=text)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rec = tmp_path_factory.mktemp("score") / "rec"
    record_target(rec, RealityTarget(), [AgentSpec(a) for a in AGENTS], episodes=4, seconds=3.0)
    return rec


def _score(rec, out, *args):
    return runner.invoke(app, ["score-proxy", "--target", str(rec), "--n-boot", "30", "--out", str(out),
                               "--backend", "inline", *args])


def test_score_proxy_on_a_split_matches_predictivity_and_compares_paired(recording, tmp_path):
    from proxybench.experiments.predictivity.run import run_predictivity

    res = _score(recording, tmp_path / "s", "--episodes", "2-3", "--param", "trim=0.25")
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "s" / "score.json").read_text())
    assert data["experiment"]["episodes"] == [2, 3] and data["episodes_per_agent"] == 2
    assert data["target_kind"] == "recorded" and "recording" in data["target"]
    assert data["scored"]["label"] == "trim=0.25" and data["versus"]["label"] == "nominal θ"
    c = data["comparison"]
    assert c["delta"] == pytest.approx(data["scored"]["prpv"]["value"] - data["versus"]["prpv"]["value"])
    assert c["low"] <= c["delta"] <= c["high"]
    assert "ΔPRPV (trim=0.25) − (nominal θ)" in res.output and "2 episodes per agent" in res.output
    # the same θ on the same split, swept by predictivity: the same PRPV, from the same cached episodes
    pred = run_predictivity(ExperimentConfig(target=str(recording), episodes="2-3", sweep={"trim": (0.25,)},
                                             n_boot=30, pod_seconds=0.0), tmp_path / "s" / "runs")
    assert pred.proxy_episodes == 0 and [e.episode for e in pred.target.episodes_of("pid")] == [2, 3]
    assert pred.rows[0]["prpv"] == pytest.approx(data["scored"]["prpv"]["value"])


def test_score_proxy_against_another_theta_also_says_how_it_does_against_nominal(recording, tmp_path):
    res = _score(recording, tmp_path / "s", "--episodes", "0-1", "--param", "trim=0.25", "--vs-param",
                 "command_delay=0.1")
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "s" / "score.json").read_text())
    assert data["versus"]["label"] == "command_delay=0.1"
    assert data["versus_nominal"]["b"] == "nominal θ" and data["comparison"]["b"] == "command_delay=0.1"


def test_score_proxy_refuses_bad_input_by_name(recording, tmp_path):
    res = _score(recording, tmp_path / "s", "--episodes", "3-6", "--param", "trim=0.1")
    assert res.exit_code == 2 and "episodes: 4, 5, 6 not in the recording" in res.output and "0-3" in res.output
    res = _score(recording, tmp_path / "s", "--param", "motion_blur=0.1")
    assert res.exit_code == 2 and "param" in res.output and "blur_time" in res.output  # did you mean
    # (a θ compared with itself is a valid question since issue 39: tests/test_newcomer.py)
    res = _score(recording, tmp_path / "s", "--episodes", "4-2")
    assert res.exit_code == 2 and "runs backwards" in res.output and "--episodes" in res.output
