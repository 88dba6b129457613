"""A newcomer's smaller frictions (issue 39 item 7): what `target check` says of proxybench's own localised runs,
progress lines that end at 100 % with steady times remaining, `--metric a,b`, the nominal θ in predictivity's
tables, a θ scored against itself, and a video writer that keeps ffmpeg's warnings out of progress lines."""

from __future__ import annotations

import io
import json
import logging

import numpy as np
import pandas as pd
import pytest
import yaml
from rich.console import Console
from rich.progress import MofNCompleteColumn, TextColumn
from typer.testing import CliRunner

from proxybench.cli import app

runner = CliRunner()
ENV = {"COLUMNS": "200"}
Y_LANE = 0.585 * 0.5 - 0.22 * 0.585  # the right lane of loop_3x3's bottom row


def _localised_like(root, end: float, seconds: float = 10.0):
    """A recorded target shaped like `localize`'s output of `run --watchtowers --seconds 10`: source simulation,
    poses sampled unevenly (43 watchtowers at 5 frames/s merged) from 0.13 s to ``end``."""
    steps = np.resize([0.068, 0.132, 0.2], 400)
    t = 0.13 + np.concatenate([[0.0], np.cumsum(steps)])
    t = t[t <= end]
    t[-1] = end
    (root / "episodes" / "pid").mkdir(parents=True)
    pd.DataFrame({"t": t, "x": 0.3 + 0.05 * t, "y": np.full(t.size, Y_LANE), "theta": 0.0 * t}).to_csv(
        root / "episodes" / "pid" / "0.csv", index=False)
    (root / "target.yaml").write_text(yaml.safe_dump({
        "source": "simulation", "description": "localised by proxybench localize from 1 run(s) of 43 watchtower(s)",
        "map": "loop_3x3", "seconds": seconds, "agents": ["pid"], "episodes": [0],
        "trajectories": "episodes/{agent}/{episode}.csv", "recorded_with": "proxybench 0.1.0 (localize)"}))
    return root


def _ended_early(output: str) -> str:
    row = next(line for line in output.splitlines() if line.startswith("│ pid"))
    return row.rstrip("│ ").split("│")[-1].strip()


def test_target_check_of_a_localised_simulated_run_says_what_it_is(tmp_path):
    """It said "SIMULATED runs of another simulator" (the run was proxybench's own), "1 agents × 1 episodes", and
    counted a run that timed out at 10 s as ended early, its samples stopping a frame before the end."""
    root = _localised_like(tmp_path / "T", end=9.80)
    res = runner.invoke(app, ["target", "check", str(root)], env=ENV)
    assert res.exit_code == 0, res.output
    assert "another simulator" not in res.output and "SIMULATED runs" in res.output
    assert "proxybench's own or another" in res.output
    assert "1 agent × 1 episode " in res.output and "agents ×" not in res.output
    assert _ended_early(res.output) == "0", res.output
    short = _localised_like(tmp_path / "S", end=9.0)  # a second short of the end: that did end early
    res = runner.invoke(app, ["target", "check", str(short)], env=ENV)
    assert res.exit_code == 0 and _ended_early(res.output) == "1", res.output


def test_a_localised_run_that_ran_to_the_end_survived_the_whole_episode(tmp_path):
    """Its samples stop a frame inside the episode (9.80 s of 10 s): survival_time is the episode's 10 s, not the
    last pose's time; a run that stops a second short survived only as long as its samples."""
    from proxybench.targets.recorded import check_recording

    whole = check_recording(_localised_like(tmp_path / "T", end=9.80), ("survival_time",))
    assert whole.ok and whole.episodes[0].scores["survival_time"] == 10.0
    short = check_recording(_localised_like(tmp_path / "S", end=9.0), ("survival_time",))
    assert short.ok and short.episodes[0].scores["survival_time"] == pytest.approx(9.0 - 0.13)


def test_target_check_takes_metrics_separated_by_commas(tmp_path):
    root = _localised_like(tmp_path / "T", end=9.80)
    res = runner.invoke(app, ["target", "check", str(root), "--metric", "survival_time,deviation_center_line"],
                        env=ENV)
    assert res.exit_code == 0, res.output
    assert "survival_time" in res.output and "deviation_center_line" in res.output


def test_a_study_takes_metrics_separated_by_commas_as_well_as_repeated(tmp_path):
    """`--metric a,b` was refused ("unknown metric 'a,b'"); the flag had to be repeated."""
    from proxybench.cli.config_options import overrides_of, study_option_list
    from proxybench.experiments.config import ExperimentConfig

    options = study_option_list(ExperimentConfig)
    metric = next(o for o in options if o.option == "--metric")
    both = overrides_of(options, {metric.param: ["survival_time,driven_lanedir_consec", "lane_score"]})
    assert both["metrics"] == ["survival_time", "driven_lanedir_consec", "lane_score"]
    agent = next(o for o in options if o.option == "--agent")  # a command may hold a comma: never split
    assert overrides_of(options, {agent.param: ["a=python x.py --w 1,2"]})["agents"] == ["a=python x.py --w 1,2"]
    res = runner.invoke(app, ["predictivity", "--metric", "survival_time,survival", "--out", str(tmp_path / "o")],
                        env=ENV)
    assert res.exit_code == 2 and "unknown metric 'survival'" in res.output, res.output


def _plain(**kw):
    from proxybench.cli.progress import PlainProgress

    out = Console(file=io.StringIO(), width=200)
    return PlainProgress(TextColumn("episodes"), MofNCompleteColumn(), console=out, **kw), out


def test_plain_progress_prints_where_the_work_ended(monkeypatch):
    """Off a terminal the lines stopped at 70 % ("429/612") and never printed the end."""
    monkeypatch.setenv("PROXYBENCH_PROGRESS_SECONDS", "3600")
    bar, out = _plain()
    with bar:
        task = bar.add_task("", total=100)
        bar.update(task, completed=55)  # a tenth: printed
        bar.update(task, completed=57)  # not a tenth, not 30 s later: not yet printed
    lines = out.file.getvalue().splitlines()
    assert lines[-1] == "episodes 57/100 (57%)", lines


def test_sweep_progress_reaches_the_total_when_jobs_share_episodes(tmp_path):
    """A sweep value equal to the nominal θ is the same episode as the nominal θ's: it runs once, and the progress
    counted it once (429 of 612 done at the end); results.parquet lists each job as itself (the nominal θ too)."""
    from proxybench.domain.params import DomainParams
    from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
    from proxybench.runner.sweep import run_jobs

    theta = DomainParams(image_width=32, image_height=24)
    doms = [DomainSpec("trim=0.0", theta), DomainSpec("nominal θ", theta)]  # the same θ: the same episodes
    jobs = [Job(AgentSpec("straight"), d, "loop_3x3", e, e, 0.5, metrics=("survival_time",))
            for d in doms for e in range(2)]
    seen: list[tuple[int, int]] = []
    sweep = run_jobs(jobs, tmp_path / "run", progress=lambda done, total, _r: seen.append((done, total)))
    assert seen[-1] == (4, 4), seen
    assert [r.domain for r in sweep.results] == ["trim=0.0"] * 2 + ["nominal θ"] * 2
    table = pd.read_parquet(tmp_path / "run" / "results.parquet")
    assert set(table["domain"]) == {"trim=0.0", "nominal θ"}


def test_times_remaining_hold_steady_when_episodes_finish_in_batches():
    """rich's 30-s window gave 6 min → 12 min → 1.5 min as batches of 8 episodes landed; the moving average of the
    rate stays near the truth (a batch every 40 s: 0.2 episodes/s) from the second batch on."""
    from proxybench.cli.progress import RateEstimate

    rate = RateEstimate()
    total, done, etas = 200, 0, []
    rate.observe(0.0, 0)
    for batch in range(1, 20):
        for k in range(8):  # a batch lands within a fraction of a second; the display samples each step
            done += 1
            rate.observe(40.0 * batch + 0.01 * k, done)
        if batch >= 2:
            etas.append(rate.eta(total - done) / ((total - done) / 0.2))  # estimate / truth
    assert min(etas) > 0.6 and max(etas) < 1.6, etas


def test_predictivity_tables_hold_the_nominal_theta_the_report_shows(tmp_path):
    from proxybench.experiments.baselines import NOMINAL
    from proxybench.experiments.study import study

    st = study("predictivity")
    res = st.example()
    st.write_report(res, tmp_path)
    table = pd.read_parquet(tmp_path / "usefulness.parquet")
    nominal = table[table["domain"] == NOMINAL]
    assert len(nominal) == 1 and nominal["parameter"].iloc[0] == "nominal"
    assert nominal["prpv"].iloc[0] == pytest.approx(res.baselines[NOMINAL]["prpv"].value)
    assert len(table) == len(res.rows) + 1
    assert NOMINAL in pd.read_csv(tmp_path / "usefulness.csv")["domain"].tolist()


def test_scoring_the_nominal_theta_against_itself_is_a_valid_question(tmp_path):
    """A user scoring a list of θ that holds the nominal one got exit 2; the answer is a difference of 0."""
    from proxybench.runner.jobs import AgentSpec
    from proxybench.targets import RealityTarget
    from proxybench.targets.record import record_target

    rec = tmp_path / "rec"
    record_target(rec, RealityTarget(), [AgentSpec(a) for a in ("pid", "straight", "random")], episodes=2,
                  seconds=1.0)
    res = runner.invoke(app, ["score-proxy", "--target", str(rec), "--n-boot", "20", "--out", str(tmp_path / "s"),
                              "--backend", "inline"], env=ENV)
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "s" / "score.json").read_text())
    c = data["comparison"]
    assert (c["delta"], c["low"], c["high"], c["separated"]) == (0.0, 0.0, 0.0, False)
    assert "no difference" in res.output


def test_the_video_writer_pads_frames_instead_of_letting_ffmpeg_warn(tmp_path, caplog, capfd):
    """`run --watchtowers` printed imageio's "not divisible by macro_block_size" warning among its progress
    lines: the camera | top-down frame is 1564 × 714."""
    import imageio.v2 as imageio

    from proxybench.media import VideoWriter

    with caplog.at_level(logging.DEBUG), VideoWriter(tmp_path / "v.mp4", 15) as video:
        for k in range(3):
            video.append(np.full((714, 1564, 3), 60 * k, np.uint8))
    captured = capfd.readouterr()
    assert "macro_block_size" not in caplog.text + captured.err + captured.out
    reader = imageio.get_reader(tmp_path / "v.mp4")
    assert tuple(reader.get_meta_data()["size"]) == (1568, 720)  # padded to the codec's blocks, not resized
    reader.close()


def test_readme_install_lines_name_the_autolab_extra_and_only_extras_that_exist():
    """The `autolab` extra was mentioned only in a comment; every extra the install lines name must exist."""
    import re
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    extras = set(tomllib.loads((root / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    block = (root / "README.md").read_text().split("```bash", 1)[1].split("```", 1)[0]
    named = {e.strip() for group in re.findall(r"'\.\[([\w,-]+)\]'", block) for e in group.split(",")}
    assert "autolab" in named and named <= extras, (named, extras)
