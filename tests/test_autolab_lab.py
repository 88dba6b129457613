"""The lab description (``lab.yaml``, docs/autolab.md "A lab"): strict fields, paths from its folder, the check."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from proxybench.autolab.lab import LabError, check_lab, load_lab
from proxybench.cli import app

LAB = """\
format: proxybench-lab/1
name: home
map: loop_3x3
robots:
  - {name: db1, virtual: true}
watchtowers: {layout: auto}
reset: {mode: teleport}
limits: {lost_s: 0.5}
"""


def write(tmp_path: Path, text: str, name: str = "lab.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_a_virtual_lab_loads_and_checks(tmp_path: Path) -> None:
    lab = load_lab(write(tmp_path, LAB))
    assert lab.robot().kind == "virtual" and lab.roof_tags() == {400: "db1"}
    assert lab.limits.thresholds().lost_s == 0.5
    lines = check_lab(lab)
    assert any(line.startswith("watchtowers: 12 simulated") for line in lines)
    result = CliRunner().invoke(app, ["autolab", "check", str(tmp_path / "lab.yaml")])
    assert result.exit_code == 0, result.output
    assert "lab 'home' is usable" in result.output


@pytest.mark.parametrize(("change", "words"), [
    (("robots:\n  - {name: db1, virtual: true}", "robots:\n  - {name: db1, virtual: true, colour: red}"),
     "robots.0.colour: unknown key"),
    (("virtual: true}", "virtual: true, dtps: 10.0.0.2/db1}"), "exactly one of virtual"),
    (("virtual: true}", "dtps: 'not an address'}"), "not a DTPS robot address"),
    (("name: db1", "name: ../db1"), "a name is 1 to 64 letters"),
    (("{mode: teleport}", "{mode: pose_file}"), "poses: give a file exactly when mode is pose_file"),
    (("lost_s: 0.5", "lost_s: -1"), "limits.lost_s"),
    (("{layout: auto}", "{layout: auto, streams: [{name: w, dtps: x/y, calibration: c.yaml}]}"),
     "exactly one of layout"),
])
def test_a_bad_lab_is_refused_naming_the_field(tmp_path: Path, change: tuple[str, str], words: str) -> None:
    old, new = change
    assert old in LAB
    path = write(tmp_path, LAB.replace(old, new))
    with pytest.raises(LabError, match=r"lab\.yaml") as info:
        load_lab(path)
    assert words in str(info.value)
    result = CliRunner().invoke(app, ["autolab", "check", str(path)])
    assert result.exit_code == 1 and words in result.output


def test_teleport_is_for_virtual_robots_only(tmp_path: Path) -> None:
    text = LAB.replace("{name: db1, virtual: true}",
                       "{name: db1, virtual: true}\n  - {name: real, dtps: 10.0.0.2/real}")
    with pytest.raises(LabError, match=r"teleport moves virtual robots only; robot\(s\) real"):
        load_lab(write(tmp_path, text))
    lab = load_lab(write(tmp_path, text.replace("{mode: teleport}", "{mode: operator}")))
    assert lab.roof_tags() == {400: "db1", 401: "real"} and lab.robot("real").kind == "dtps"


def test_paths_are_from_the_lab_files_folder_and_checked(tmp_path: Path) -> None:
    from proxybench.autolab.watchtowers import auto_layout, write_layout
    from proxybench.domain.maps import load_map

    (tmp_path / "lab").mkdir()
    write_layout(tmp_path / "lab" / "towers.yaml", auto_layout(load_map("loop_3x3")))
    (tmp_path / "lab" / "poses.yaml").write_text("[0.3, 0.9, 1.57]\n")
    text = LAB.replace("{layout: auto}", "{layout: towers.yaml}").replace(
        "{mode: teleport}", "{mode: pose_file, poses: poses.yaml}")
    lab = load_lab(write(tmp_path / "lab", text))
    assert Path(lab.watchtowers.layout) == (tmp_path / "lab" / "towers.yaml").resolve()
    assert lab.reset.poses == (tmp_path / "lab" / "poses.yaml").resolve()
    assert any("12 simulated" in line for line in check_lab(lab))
    other = LAB.replace("map: loop_3x3", "map: small_loop").replace("{layout: auto}", "{layout: towers.yaml}")
    with pytest.raises(LabError, match=r"watchtowers\.layout: .*the layout is for 'loop_3x3'"):
        check_lab(load_lab(write(tmp_path / "lab", other, "other.yaml")))
    streams = LAB.replace("{layout: auto}", "{streams: [{name: wt1, recorded: rec/wt1, calibration: cal/wt1.yaml}]}")
    with pytest.raises(LabError, match=r"streams\[wt1\]\.calibration"):
        check_lab(load_lab(write(tmp_path / "lab", streams.replace("teleport", "operator"), "s.yaml")))


def test_a_roof_tag_that_is_a_ground_tag_is_refused(tmp_path: Path) -> None:
    from proxybench.autolab.watchtowers import auto_layout
    from proxybench.domain.maps import load_map

    layout = auto_layout(load_map("loop_3x3"))
    tag = layout.ground_tags[0].id
    lab = load_lab(write(tmp_path, LAB.replace("virtual: true}", f"virtual: true, roof_tag: {tag}}}")))
    with pytest.raises(LabError, match=f"tag id\\(s\\) {tag} are also ground tags"):
        check_lab(lab)
