"""Container images as agents (issue 37): an image built here from Debian's packages (its own Python, not the
host's) drives `proxybench run` and is ranked by `predictivity --quick`, over pipes and over AIDO's FIFOs; its
config (Env, WorkingDir, User) is honoured; an ENTRYPOINT that forks a daemon leaves no process behind; a bad
label or config is a one-line error naming it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.evaluator.image_agent import image_manifest, image_user
from proxybench.evaluator.images import ImageConfig, ImageError, unpack_image
from proxybench.experiments.agent_args import parse_agent
from support.images import agent_image, member, oci_layout, tar_layer
from support.sandbox import AGENT_USER_GROUP, processes_left, require_safe_sandbox

pytestmark = AGENT_USER_GROUP  # its agents run as the agent user: one test at a time
runner = CliRunner()
AGENT = Path(__file__).with_name("image_agents") / "z2_agent.py"


@pytest.fixture(scope="module")
def images(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The images of this module, built once (the Debian root file system is cached between runs)."""
    require_safe_sandbox()
    root = tmp_path_factory.mktemp("images")
    built = {
        "pipe": agent_image(root / "pipe", AGENT),
        "fifo": agent_image(root / "fifo", AGENT, labels={"org.proxybench.agent.transport": "fifo"},
                            env={"GREETING": "hi"}, workdir="/opt/agent", user="4242:4343"),
        "daemon": agent_image(root / "daemon", AGENT, args=("daemon",)),
    }
    archive = root / "docker.tar"  # the same image as `docker save` writes it
    subprocess.run(["skopeo", "--insecure-policy", "copy", "-q", f"oci:{built['pipe']}:latest",
                    f"docker-archive:{archive}:agent:latest"], check=True)
    built["docker"] = archive
    return built


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PROXYBENCH_IMAGE_CACHE", str(tmp_path_factory.getbasetemp() / "image-cache"))


def _run(tmp_path: Path, spec: str) -> str:
    res = runner.invoke(app, ["run", "--agent", spec, "--seconds", "1", "--width", "80", "--height", "60",
                              "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    return res.output


@pytest.mark.parametrize("form", ["pipe", "fifo", "docker"])
def test_an_image_drives_run_with_its_own_interpreter(tmp_path: Path, images: dict[str, Path], form: str) -> None:
    # the agent exits 5 unless it runs on the image's /usr/bin/python3 with no proxybench importable
    out = _run(tmp_path, f"mine=image:{images[form]}")
    assert "agent=mine" in out and "end=timeout" in out and "survival_time=1.00" in out
    isolation = require_safe_sandbox()
    assert processes_left(isolation.uid) == []


def test_an_entrypoint_that_forks_a_daemon_leaves_no_process(tmp_path: Path, images: dict[str, Path]) -> None:
    out = _run(tmp_path, f"d=image:{images['daemon']}")
    assert "end=timeout" in out
    assert processes_left(require_safe_sandbox().uid) == []


def test_the_config_decides_how_it_starts(images: dict[str, Path]) -> None:
    image = unpack_image(images["fifo"])
    spec = parse_agent(f"f=image:{images['fifo']}")
    assert spec.node_options().transport == "fifo"
    command = spec.command
    for part in ("--rootfs", "--chdir /opt/agent", "--inside-uid 4242 --inside-gid 4343", "--env GREETING=hi",
                 "--env HOME=/scratch", "/usr/bin/python3 /opt/agent/agent.py"):
        assert part in command, part
    assert str(image.rootfs) in command and sys.executable not in command.split(" -- ", 1)[1]


def test_a_user_name_the_image_does_not_have_is_named(tmp_path: Path, images: dict[str, Path]) -> None:
    image = unpack_image(images["pipe"])
    with pytest.raises(ImageError, match="User 'agent': no user 'agent' in the image's /etc/passwd"):
        image_user(image.model_copy(update={"config": image.config.model_copy(update={"user": "agent"})}))
    assert image_user(image) == (0, 0)  # no User: root, inside the sandbox's user namespace only


def test_bad_labels_side_files_and_configs_are_one_line_errors(tmp_path: Path) -> None:
    path = tmp_path / "img"
    cases = [
        (ImageConfig(Entrypoint=["/a"], Labels={"org.proxybench.agent.step_timeout": "999"}),
         "label org.proxybench.agent.step_timeout"),
        (ImageConfig(Entrypoint=["/a"], Labels={"org.proxybench.agent.command": "x"}), "unknown key 'command'"),
        (ImageConfig(Labels={}), "neither Entrypoint nor Cmd"),
        (ImageConfig(Cmd=["/a"], Labels={"org.proxybench.agent.protocol": "grpc"}), "'grpc' is not one of"),
        (ImageConfig(Cmd=["/a"], Labels={"org.proxybench.agent.timing": "lockstep"}),
         "label org.proxybench.agent.timing: .*only for protocol duckietown-sdk"),
    ]
    for config, reason in cases:
        with pytest.raises(ImageError, match=reason) as err:
            image_manifest("x", path, config)
        assert "\n" not in str(err.value)
    (tmp_path / "img.proxybench-agent.yaml").write_text("transport: carrier-pigeon\n")
    with pytest.raises(ImageError, match=r"img\.proxybench-agent\.yaml: transport"):
        image_manifest("x", path, ImageConfig(Cmd=["/a"]))
    (tmp_path / "img.proxybench-agent.yaml").write_text("transport: fifo\nstart_timeout: 12\n")
    manifest = image_manifest("x", path, ImageConfig(Cmd=["/a"], Labels={"org.proxybench.agent.transport": "pipe"}))
    assert manifest.transport == "fifo" and manifest.start_timeout == 12  # the side file wins over labels
    sdk = image_manifest("x", tmp_path / "other", ImageConfig(Cmd=["/a"], Labels={
        "org.proxybench.agent.protocol": "duckietown-sdk", "org.proxybench.agent.timing": "lockstep"}))
    assert (sdk.protocol, sdk.timing) == ("duckietown-sdk", "lockstep")  # an SDK image: tests/test_images_sdk.py


@pytest.mark.slow
def test_an_image_is_ranked_by_predictivity(tmp_path: Path, images: dict[str, Path]) -> None:
    out = tmp_path / "p"
    run = subprocess.run([sys.executable, "-m", "proxybench", "predictivity", "--quick", "--agent", "pid",
                          "--agent", "straight", "--agent", f"mine=image:{images['pipe']}", "--episodes", "1",
                          "--seconds", "1.5", "--sweep", "trim=0,0.2", "--pod-seconds", "0", "--backend", "inline",
                          "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:] + run.stdout[-3000:]
    import pandas as pd

    results = pd.read_parquet(next((out / "runs").rglob("results.parquet")))
    assert {"pid", "straight", "mine"} <= set(results.agent)
    assert set(results[results.agent == "mine"].termination) == {"timeout"}


def test_sandbox_check_says_whether_images_run_here(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                    images: dict[str, Path]) -> None:
    def check(cache: Path) -> str:
        monkeypatch.setenv("PROXYBENCH_IMAGE_CACHE", str(cache))
        res = runner.invoke(app, ["sandbox", "check"], env={"COLUMNS": "400"})
        return " ".join(res.output.split())

    out = check(tmp_path / "empty")
    assert "container images" in out and "run in bubblewrap as the agent user" in out, out
    assert "no image cached yet: none started" in out, out
    # a cached image is started (its own true, sh or python3), not only its tools found
    image = unpack_image(images["pipe"], tmp_path / "cache")
    assert f"started cached image {image.digest[:19]}" in check(tmp_path / "cache")
    bare = oci_layout(tmp_path / "bare", [tar_layer([member("etc/hostname", data=b"x")])], {"Cmd": ["/a"]})
    unpack_image(bare, tmp_path / "bare-cache")
    assert "none of the 1 cached images has true, sh or python3" in check(tmp_path / "bare-cache")
    broken = oci_layout(tmp_path / "broken", [tar_layer([member("bin/sh", data=b"not a program", mode=0o644)])],
                        {"Cmd": ["/bin/sh"]})
    unpack_image(broken, tmp_path / "broken-cache")
    out = check(tmp_path / "broken-cache")
    assert "FAILED: cached image sha256:" in out and "(/bin/sh -c :) did not start" in out, out
    monkeypatch.setattr("proxybench.evaluator.images.shutil.which", lambda _tool: None)
    res = runner.invoke(app, ["sandbox", "check"], env={"COLUMNS": "250"})
    assert "refused: skopeo and umoci not installed: apt-get install skopeo umoci" in res.output, res.output


BENCH = """
name: tiny-image
map: loop_3x3
episodes: {count: 1, seed: 1}
duration: 1.0
domain: {params: {image_width: 80, image_height: 60}}
metrics: [survival_time]
scoring:
  - {metric: survival_time_median, tolerance: 0.5}
"""


def test_agent_check_and_evaluate_take_an_image(tmp_path: Path, images: dict[str, Path]) -> None:
    res = runner.invoke(app, ["agent", "check", f"image:{images['fifo']}", "--seconds", "0.5", "--no-contract"])
    assert res.exit_code == 0 and "over fifo" in res.output, res.output
    bench = tmp_path / "bench.yaml"
    bench.write_text(BENCH)
    res = runner.invoke(app, ["evaluate", str(bench), "--agent", f"mine=image:{images['pipe']}", "--backend",
                              "inline", "--run-dir", str(tmp_path / "ev")])
    assert res.exit_code == 0 and "mine" in res.output, res.output
    res = runner.invoke(app, ["agent", "check", f"image:{tmp_path / 'nothing'}"])
    assert res.exit_code == 2 and "no such file or folder" in res.output, res.output
