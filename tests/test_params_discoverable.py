"""Parameter names are discoverable: every "unknown parameter" error lists the valid names with units and a
"did you mean"; `proxybench params` lists them with units, ranges and sign conventions."""

from __future__ import annotations

import pytest
from pydantic import ValidationError
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.domain.params import DomainParams, ParamSpace, ParamSpaceError, closest_parameter, describe_params
from proxybench.experiments.config import ConfigError, load_config


@pytest.mark.parametrize(("wrong", "meant"), [("motion_blur", "blur_time"), ("trimm", "trim"),
                                              ("delay", "command_delay"), ("camera_pitc", "camera_pitch"),
                                              ("fov", "camera_fov_y")])
def test_a_wrong_name_suggests_the_meant_one(wrong, meant):
    assert closest_parameter(wrong) == meant
    with pytest.raises(ValidationError) as exc:
        DomainParams.model_validate({wrong: 0.1})
    text = str(exc.value)
    assert f"did you mean {meant!r}" in text and "trim [-]" in text and "camera_pitch [deg]" in text


def test_every_entry_point_names_the_valid_parameters(tmp_path):
    with pytest.raises(ParamSpaceError, match=r"did you mean .blur_time..*command_delay \[s\]"):
        ParamSpace.from_dict({"motion_blur": {"uniform": [0, 0.1]}})
    with pytest.raises(ConfigError, match=r"did you mean .blur_time..*command_delay \[s\]"):
        load_config(None, {"sweep": {"motion_blur": [0.0, 0.1]}})
    with pytest.raises(ConfigError, match="did you mean 'blur_time'"):
        load_config(None, {"proxy": {"motion_blur": 0.1}})
    res = CliRunner().invoke(app, ["robot", "serve", "--param", "motion_blur=0.1"], env={"COLUMNS": "300"})
    assert res.exit_code == 2 and "blur_time" in res.output and "command_delay [s]" in res.output


def test_params_lists_every_field_with_units_ranges_and_the_trim_convention():
    rows = {r["name"]: r for r in describe_params()}
    assert set(rows) == set(DomainParams.model_fields)
    assert rows["camera_pitch"]["unit"] == "deg" and (rows["trim"]["low"], rows["trim"]["high"]) == (-1.0, 1.0)
    assert "drifts the robot left" in rows["trim"]["description"]
    res = CliRunner().invoke(app, ["params"], env={"COLUMNS": "250"})
    assert res.exit_code == 0 and "blur_time" in res.output and "drifts the robot left" in res.output
    bad = CliRunner().invoke(app, ["params", "motion_blur"], env={"COLUMNS": "250"})
    assert bad.exit_code == 2 and "blur_time" in bad.output
