"""gym-duckietown's parameters and environment as proxybench checks them: no gym environment needed."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.gym.cpus import CpuError, check_cpus, claim_cpu, parse_cpus
from proxybench.gym.params import DEFAULTS, GymParamError, gym_params, parse_param_items
from proxybench.targets.manifest import SimulatorInfo


@pytest.mark.parametrize(("item", "words"), [
    ("trimm=0.1", "unknown parameter 'trimm'; did you mean 'trim'"),
    ("camera_widht=80", "did you mean 'camera_width'"),
    ("gain=1.2", "DuckietownEnv's velocity → PWM conversion"),
    ("map_name=udem1", "--map"),
    ("frame_skip=0", "frame_skip=0: out of range [1, 100]"),
    ("frame_skip=1.5", "frame_skip=1.5: must be an integer"),
    ("domain_rand=maybe", "domain_rand='maybe': must be true or false"),
    ("style=cartoon", "must be one of photos, synthetic"),
    ("color_sky=[2, 0, 0]", "three numbers in [0, 1]"),
    ("trim=.nan", "must be a number"),
    ("trim", "is not NAME=VALUE"),
])
def test_a_bad_parameter_is_named_with_what_would_be_valid(item: str, words: str) -> None:
    with pytest.raises(GymParamError, match=None) as info:
        parse_param_items([item])
    assert words in str(info.value)


def test_values_are_read_as_yaml_and_defaults_are_gyms() -> None:
    p = gym_params(["trim=0.1", "domain_rand=false", "color_ground=[0.1, 0.2, 0.3]", "max_steps=300"])
    assert p.changed == {"trim": 0.1, "domain_rand": False, "color_ground": (0.1, 0.2, 0.3), "max_steps": 300}
    assert (DEFAULTS["delay"], DEFAULTS["frame_rate"], DEFAULTS["cam_angle"], DEFAULTS["domain_rand"]) == (
        0.15, 30.0, 19.15, True)


def test_hidden_parameters_show_only_a_hash_that_the_nonce_salts(tmp_path) -> None:
    f = tmp_path / "theta.yaml"
    f.write_text("trim: 0.1\nnonce: s3cret-0123456789abcdef\n")
    hidden = gym_params([], f, secret=True)
    assert hidden.public() == {"hidden": True, "sha256": hidden.sha256} and hidden.values["trim"] == 0.1
    f.write_text("trim: 0.1\nnonce: other-0123456789abcdef\n")
    assert gym_params([], f, secret=True).sha256 != hidden.sha256  # not guessable from trim alone
    assert gym_params(["trim=0.1"]).sha256 != hidden.sha256
    with pytest.raises(GymParamError, match="--param is visible in the command"):
        gym_params(["trim=0.1"], f, secret=True)
    with pytest.raises(GymParamError, match="--secret needs --param-file"):
        gym_params([], None, secret=True)
    for nonce in ("", "nonce: short\n"):  # a hidden θ's hash without a long nonce can be brute-forced (issue 38)
        f.write_text("trim: 0.1\n" + nonce)
        with pytest.raises(GymParamError, match="--secret needs a random `nonce:` of 16 characters"):
            gym_params([], f, secret=True)
    f.write_text("trim: 2\n")
    with pytest.raises(GymParamError, match=rf"--param-file {f}: parameter trim=2: out of range"):
        gym_params([], f)
    assert SimulatorInfo(name="gym-duckietown", version="6.1.34", hidden=True, sha256=hidden.sha256
                         ).describe().startswith("gym-duckietown 6.1.34, parameters hidden (sha256 ")


def test_the_cli_refuses_bad_parameters_before_starting_gym() -> None:
    res = CliRunner().invoke(app, ["gym", "serve", "--param", "trimm=0.1", "--path", "/nonexistent"])
    assert res.exit_code == 2 and "did you mean 'trim'" in res.output
    res = CliRunner().invoke(app, ["gym", "params"])
    assert res.exit_code == 0 and "cam_fov_y" in res.output and "not taken:" in res.output


def test_cpus_are_read_as_taskset_takes_them_and_checked_against_this_machine() -> None:
    assert parse_cpus("3") == [3] and parse_cpus("2,3") == [2, 3] and parse_cpus("0-2, 5") == [0, 1, 2, 5]
    bad_values = (("x", "'x' is not a CPU number"), ("3-1", "'3-1' is not"), ("-1", "'-1' is not"),
                  ("", "'' is not a CPU number"))
    for bad, words in bad_values:
        with pytest.raises(CpuError, match=words):
            parse_cpus(bad)
    mine = sorted(os.sched_getaffinity(0))
    with pytest.raises(CpuError, match="CPU 4096 is not available here"):
        check_cpus([4096])
    with pytest.raises(CpuError, match="leaves no CPU for the node itself"):
        check_cpus(mine)


def test_cpus_auto_claims_the_last_free_cpu_until_released(tmp_path: Path) -> None:
    mine = sorted(os.sched_getaffinity(0))
    if len(mine) < 2:
        assert claim_cpu(tmp_path) is None, "one CPU: none to give gym alone"
        return
    claims = [claim_cpu(tmp_path) for _ in mine[1:]] + [claim_cpu(tmp_path)]  # each leaves the node another CPU
    assert [c.cpu for c in claims] == mine[::-1]
    assert claim_cpu(tmp_path) is None  # every CPU held
    claims[1].release()
    again = claim_cpu(tmp_path)
    assert again is not None and again.cpu == mine[-2]
    for c in (*claims, again):
        c.release()


def test_cpus_auto_trusts_no_planted_folder_or_lock_file(tmp_path: Path) -> None:
    mine = sorted(os.sched_getaffinity(0))
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    with pytest.raises(CpuError, match="is a symbolic link: refused"):  # a symlink where the folder should be
        claim_cpu(tmp_path / "link")
    if len(mine) < 2:
        return
    victim = tmp_path / "victim"
    victim.write_text("keep")
    (tmp_path / "locks").mkdir()
    (tmp_path / "locks" / f"cpu{mine[-1]}.lock").symlink_to(victim)
    claim = claim_cpu(tmp_path / "locks")
    assert claim is not None and claim.cpu == mine[-2] and victim.read_text() == "keep"
    claim.release()


def test_the_cli_refuses_bad_cpus_before_starting_gym() -> None:
    res = CliRunner().invoke(app, ["gym", "serve", "--cpus", "4096", "--path", "/nonexistent"])
    assert res.exit_code == 2 and "--cpus: CPU 4096 is not available here" in res.output
    res = CliRunner().invoke(app, ["gym", "serve", "--cpus", "one", "--path", "/nonexistent"])
    assert res.exit_code == 2 and "'one' is not a CPU number" in res.output


def test_check_says_what_is_missing(tmp_path) -> None:
    res = CliRunner().invoke(app, ["gym", "check", "--path", str(tmp_path / "none")])
    assert res.exit_code == 1 and "run: proxybench gym setup --path" in res.output
