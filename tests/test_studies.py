"""Studies are registered: every study command is generated from its ``Study`` (config → options, the shared
--quick/--out/--backend/--workers/--config once), and every registered study passes the study contract."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import typer
from pydantic import Field
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.cli.studies import add_study_commands, study_command
from proxybench.experiments.study import BUILTIN, Study, StudyConfig, register, studies, study
from proxybench.testing import StudyContract

ENV = {"COLUMNS": "200", "NO_COLOR": "1"}
ALL = sorted(studies())


def test_every_builtin_family_registers_its_studies_and_each_is_a_command():
    assert {"predictivity", "score-proxy", "optimize", "plan", "heldout", "repeatability", "plv", "plv-vs-prpv",
            "validate", "rank", "rank-check"} <= set(ALL) and len(BUILTIN) == 11
    commands = {c.name for c in app.registered_commands}
    assert set(ALL) <= commands


def test_every_study_gives_a_canned_result():
    assert [name for name in ALL if study(name).example() is None] == []


@pytest.mark.parametrize("name", ALL)
def test_every_registered_study_passes_the_study_contract(name):
    st = study(name)
    StudyContract(st, study_command(st)).run().raise_if_failed()


def test_the_contract_catches_a_study_that_accepts_unknown_keys_or_has_no_name():
    class Loose(StudyConfig):
        model_config = {"extra": "ignore", "frozen": True}  # noqa: RUF012 - pydantic's
        n: int = 1

    class Bad(Study[Loose, dict]):
        """h"""

        name = "Bad Name"
        config = Loose
        out = "out/bad"

        def run(self, config, out, backend, progress, *, quick=False):
            return {}

        def write_report(self, result, out, *, wall=0.0):
            return [out / "missing.txt"]

        def example(self):
            return {}

    report = StudyContract(Bad()).run()
    failed = {r.name: r.reason for r in report.failures}
    assert set(failed) == {"identity", "config", "command", "report"}
    assert "no_such_field" in failed["config"] and "missing.txt" in failed["report"]


def test_an_unknown_study_name_lists_the_registered_ones():
    from proxybench.experiments.study import ConfigError

    with pytest.raises(ConfigError, match=r"registered: .*predictivity"):
        study("predictivty")


class _CountConfig(StudyConfig):
    seconds: float = Field(2.0, gt=0)
    """episode length [s]"""
    label: str = "demo"
    """what the report calls the run"""


def test_a_registered_study_runs_through_its_generated_command(tmp_path):
    """A study of a user's own (as an entry point would register it): options, --config, --quick, the report."""

    class Count(Study[_CountConfig, dict]):
        """Count to a number (a study of a user's own)."""

        name = "count-demo"
        config = _CountConfig
        out = str(tmp_path / "default")

        def run(self, config, out, backend, progress, *, quick=False):
            progress("counting", 1, 1)
            return {"seconds": config.seconds, "label": config.label, "quick": quick, "backend": type(backend).__name__}

        def write_report(self, result, out, *, wall=0.0):
            out.mkdir(parents=True, exist_ok=True)
            (out / "result.json").write_text(json.dumps(result))
            return [out / "result.json"]

        def show(self, result, console, *, wall=0.0):
            console.print(f"counted {result['label']}", markup=False)

    local = typer.Typer()
    try:
        register(Count)
        add_study_commands(local)
        local.command("other")(lambda: None)
        f = tmp_path / "s.yaml"
        f.write_text("seconds: 5\nlabel: from-file\n")
        res = CliRunner().invoke(local, ["count-demo", "--config", str(f), "--label", "cli", "--quick", "--backend",
                                         "inline", "--out", str(tmp_path / "o")], env=ENV)
        assert res.exit_code == 0, res.output
        assert json.loads((tmp_path / "o" / "result.json").read_text()) == {
            "seconds": 5.0, "label": "cli", "quick": True, "backend": "InlineBackend"}  # the option beats the file
        assert "counted cli" in res.output and "wrote" in res.output
        bad = CliRunner().invoke(local, ["count-demo", "--seconds", "-1"], env=ENV)
        assert bad.exit_code == 2 and "--seconds" in bad.output
        f.write_text("secondz: 5\n")
        bad = CliRunner().invoke(local, ["count-demo", "--config", str(f)], env=ENV)
        assert bad.exit_code == 2 and "secondz: unknown key (did you mean 'seconds'?)" in bad.output
    finally:
        from proxybench.experiments import study as registry

        registry._REGISTRY.pop("count-demo", None)


def test_validate_takes_a_config_file(tmp_path: Path):
    """validate --config FILE: its fields as the options' (an interim look, run from the file, finds no study)."""
    f = tmp_path / "validate.yaml"
    f.write_text("family: heldout\ntargets: 4\ninterim: true\nmethods: [prpv, nominal]\n")
    res = CliRunner().invoke(app, ["validate", "--config", str(f), "--out", str(tmp_path / "v")], env=ENV)
    assert res.exit_code == 2 and "no study to look at" in res.output, res.output
    f.write_text("family: heldout\ntargetss: 4\n")
    res = CliRunner().invoke(app, ["validate", "--config", str(f), "--out", str(tmp_path / "v")], env=ENV)
    assert res.exit_code == 2 and "targetss: unknown key (did you mean 'targets'?)" in res.output, res.output
    f.write_text("methods: [prpv]\n")
    res = CliRunner().invoke(app, ["validate", "--config", str(f), "--out", str(tmp_path / "v")], env=ENV)
    assert res.exit_code == 2 and "nominal is missing" in res.output, res.output
