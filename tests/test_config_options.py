"""A study's command-line options are generated from its config model: a field is declared once, its docstring
is its help, its bounds are checked before anything runs, and ``--config FILE`` takes every field (an option
beats the file, the file beats the default)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Literal

import pytest
import typer
import yaml
from pydantic import Field
from typer.testing import CliRunner

from proxybench.cli.config_options import option_table, study_options
from proxybench.experiments.study import Cli, StudyConfig

runner = CliRunner()
ENV = {"COLUMNS": "220"}


def flat(text: str) -> str:
    return " ".join(re.sub(r"[│╭╮╰╯─]", " ", text).split())


class Search(StudyConfig):
    """A nested section."""

    trials: int = Field(10, ge=1)
    """trials of the search"""
    sampler: Literal["tpe", "random"] = "tpe"
    """the sampler"""


class Study(StudyConfig):
    """A throwaway study with one field of each kind the generator spells."""

    seconds: float | None = Field(None, gt=0.0, le=600.0)
    """episode length [s]"""
    seed: int = Field(0, ge=0)
    """the seed"""
    agents: Annotated[tuple[str, ...], Cli("--agent")] = ("pid",)
    """an agent to run"""
    ladder: tuple[int, ...] = (1, 2)
    """rungs"""
    sweep: dict[str, tuple[float, ...]] = Field(default_factory=dict)
    """values of a parameter"""
    space: Annotated[dict[str, tuple[float, float]], Cli("--param", sep=":")] = Field(default_factory=dict)
    """a range"""
    image_size: Annotated[tuple[int, int], Cli(sep="x")] = (160, 120)
    """image [px]"""
    fisheye: bool = True
    """a lens"""
    search: Annotated[Search, Cli(prefix="")] = Field(default_factory=Search)
    """what to search"""


def _app(model: type[StudyConfig], seen: list, **kw) -> typer.Typer:
    app = typer.Typer()

    @app.command()
    @study_options(model, **kw)
    def study(cfg: model, out: Path = typer.Option(Path("out"))) -> None:  # type: ignore[valid-type]
        seen.append((cfg, out))

    @app.command()
    def other() -> None:  # two commands: `study` is a subcommand
        pass

    return app


def test_every_field_is_an_option_with_its_docstring_and_default():
    seen: list = []
    res = runner.invoke(_app(Study, seen, defaults={"seconds": "20; --quick 8"}), ["study", "--help"], env=ENV)
    out = flat(res.output)
    assert res.exit_code == 0, out
    for text in ("--seconds", "episode length [s] (default: 20; --quick 8)", "--seed", "--agent", "--ladder",
                 "--sweep", "--param", "NAME=V1:V2", "--image-size", "(default: 160x120)", "--fisheye", "--no-fisheye",
                 "--trials", "trials of the search (default: 10)", "--sampler", "tpe|random", "--config", "--out"):
        assert text in out, text


def test_options_parse_every_kind_of_field():
    seen: list = []
    args = ["study", "--seconds", "5", "--seed", "3", "--agent", "a=python3 x.py,y", "--agent", "b", "--ladder", "5,6",
            "--ladder", "7", "--sweep", "trim=-0.1,0,0.1", "--param", "trim=-0.3:0.3", "--image-size", "80x60",
            "--no-fisheye", "--trials", "4", "--sampler", "random"]
    res = runner.invoke(_app(Study, seen), args)
    assert res.exit_code == 0, res.output
    cfg, _ = seen[0]
    assert cfg == Study(seconds=5.0, seed=3, agents=("a=python3 x.py,y", "b"), ladder=(5, 6, 7),
                        sweep={"trim": (-0.1, 0.0, 0.1)}, space={"trim": (-0.3, 0.3)}, image_size=(80, 60),
                        fisheye=False, search=Search(trials=4, sampler="random"))


@pytest.mark.parametrize(("args", "option", "says"), [
    (["--seconds", "0"], "--seconds", "must be a finite number > 0 and <= 600, got 0.0"),
    (["--seconds", "nan"], "--seconds", "got nan"),
    (["--seed", "-1"], "--seed", "Invalid value"),
    (["--trials", "0"], "--trials", "Invalid value"),
    (["--sampler", "gp"], "--sampler", "must be one of tpe, random, got 'gp'"),
    (["--sweep", "trim=a,b"], "--sweep", "expected NAME=V1,V2,…"),
    (["--param", "trim"], "--param", "expected NAME=V1:V2"),
    (["--image-size", "80"], "--image-size", "image_size"),
])
def test_bad_values_are_usage_errors_naming_the_option(args, option, says):
    seen: list = []
    res = runner.invoke(_app(Study, seen), ["study", *args], env=ENV)
    out = flat(res.output)
    assert res.exit_code == 2 and option in out and says in out, out
    assert not seen


def test_an_option_beats_the_file_and_the_file_beats_the_default(tmp_path):
    f = tmp_path / "study.yaml"
    f.write_text(yaml.safe_dump({"seed": 7, "seconds": 9.0, "fisheye": False, "search": {"trials": 3}}))
    seen: list = []
    res = runner.invoke(_app(Study, seen), ["study", "--config", str(f), "--seconds", "2", "--sampler", "random"])
    assert res.exit_code == 0, res.output
    cfg, _ = seen[0]
    assert (cfg.seed, cfg.seconds, cfg.fisheye, cfg.image_size) == (7, 2.0, False, (160, 120))
    assert cfg.search == Search(trials=3, sampler="random")  # a section merges key by key
    f.write_text("sead: 1\n")
    res = runner.invoke(_app(Study, seen), ["study", "--config", str(f)])
    assert res.exit_code == 2 and f"{f}: sead: unknown key (did you mean 'seed'?)" in res.output


def test_a_field_added_to_a_config_is_on_the_command_line_with_no_other_edit():
    class Grown(Study):
        lanes: int = Field(2, ge=1, le=4)
        """lanes of the road"""

    seen: list = []
    app = _app(Grown, seen)
    assert "--lanes" in flat(runner.invoke(app, ["study", "--help"], env=ENV).output)
    res = runner.invoke(app, ["study", "--lanes", "3"])
    assert res.exit_code == 0 and seen[0][0].lanes == 3
    res = runner.invoke(app, ["study", "--lanes", "5"], env=ENV)
    assert res.exit_code == 2 and "--lanes" in res.output


def test_two_fields_spelt_alike_are_refused_when_the_command_is_defined():
    class Clash(StudyConfig):
        agents: Annotated[tuple[str, ...], Cli("--agent")] = ()
        agent: str = "pid"

    with pytest.raises(ValueError, match="--agent"):
        study_options(Clash)


# --------------------------------------------------------------------------- the commands of proxybench


def test_the_experiment_commands_offer_every_field_of_their_config():
    from proxybench.cli.studies import study_command
    from proxybench.experiments.config import ExperimentConfig
    from proxybench.experiments.study import study

    def table(name: str) -> dict[str, str]:
        return option_table(study_command(study(name)))

    fields = set(ExperimentConfig.model_fields) - {"search", "plan", "robot_options"}
    for command, excluded in (("predictivity", {"plv"}), ("optimize", {"sweep", "pod_seconds"}),
                              ("plan", {"n_boot", "pod_seconds", "truth", "plv"})):
        assert fields - excluded <= set(table(command)), command
    assert table("optimize")["search.space"] == "--param"
    assert table("predictivity")["robot_options.reflection"] == "--robot-reflection"
    assert table("plan")["plan.width"] == "--width"
    assert table("heldout")["agents"] == "--agent"
    assert table("plv")["use_dagger"] == "--dagger"
    assert table("repeatability")["robots"] == "--robot-cmd"
    assert table("score-proxy")["param"] == "--param" and table("score-proxy")["vs_param"] == "--vs-param"
    assert table("validate")["agents"] == "--agent" and table("validate")["interim"] == "--interim"


def test_optimize_help_does_not_promise_defaults_a_recorded_target_overrides():
    """Issue 28, item 8: `optimize --help` said "episodes 4, seconds 20", which a recorded target does not use."""
    from proxybench.cli import app

    out = flat(runner.invoke(app, ["optimize", "--help"], env=ENV).output)
    assert "(default: a recorded target's (all of them), else 4; --quick 2)" in out
    assert "(default: a recorded target's (it fixes it), else 20; --quick 12)" in out


def test_a_bad_command_line_value_names_its_option(tmp_path):
    from proxybench.cli import app

    res = runner.invoke(app, ["predictivity", "--target", "robot:x", "--robot-cwd", str(tmp_path / "nope"),
                              "--out", str(tmp_path / "o")], env=ENV)
    assert res.exit_code == 2 and "robot_options.cwd (--robot-cwd)" in res.output and "is not a directory" in res.output
    res = runner.invoke(app, ["predictivity", "--metric", "survival", "--out", str(tmp_path / "o")], env=ENV)
    assert res.exit_code == 2 and "metrics (--metric): unknown metric 'survival'" in res.output


def test_plv_settings_merge_the_quick_mode_the_file_and_the_command_line(tmp_path):
    from proxybench.experiments.plv.config import PLVConfig

    f = tmp_path / "plv.json"
    f.write_text('{"ladder": [10, 20], "train": {"max_steps": 7}}')
    cfg = PLVConfig.load(f, {"eta_on": 2.0, "train": {"lr": 0.01}}, base=PLVConfig.quick().to_dict())
    assert cfg.ladder == (10, 20) and cfg.eta_on == 2.0 and cfg.width == 40
    assert (cfg.train.max_steps, cfg.train.min_steps, cfg.train.lr) == (7, 60, 0.01)
    f.write_text('{"train": {"max_stepz": 7}}')
    with pytest.raises(ValueError, match=r"train\.max_stepz"):
        PLVConfig.load(f)


# --------------------------------------------------------------------------- the experiment file's documentation


def _documented_file() -> dict:
    text = (Path(__file__).parents[1] / "docs" / "targets.md").read_text()
    block = text.split("```yaml\ntarget: ", 1)[1].split("```", 1)[0]
    return yaml.safe_load("target: " + block)


def test_docs_show_every_field_of_the_experiment_file():
    from proxybench.experiments.config import ExperimentConfig

    doc = _documented_file()

    def keys(model, data: dict, where: str) -> None:
        assert set(data) == set(model.model_fields), f"{where}: documented {sorted(data)}"
        for name, field in model.model_fields.items():
            sub = getattr(field.annotation, "model_fields", None) or next(
                (a.model_fields for a in getattr(field.annotation, "__args__", ()) if hasattr(a, "model_fields")),
                None)
            if sub is not None and isinstance(data[name], dict):
                keys(type("M", (), {"model_fields": sub}), data[name], f"{where}{name}.")

    keys(ExperimentConfig, doc, "")
    del doc["robot_options"]["cwd"], doc["target"]  # a folder and a target of the example's lab
    doc["agents"] = [a for a in doc["agents"] if isinstance(a, str)]
    ExperimentConfig.model_validate(doc)  # and every documented value is valid
