"""The shipped evidence (issue 35, item 4): `proxybench results rebuild --check` holds on the shipped tables and
fails, naming the number, when a shipped table, numbers.json or a tagged README quote is edited; `results export`
ships a finished quick validate study whose numbers rebuild to its own summary, and refuses an interim study, a
failed pre-registration check and an overwrite without --replace."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from proxybench.cli import app
from proxybench.experiments.evidence import readme_quotes

ENV = {"COLUMNS": "200", "NO_COLOR": "1"}
REPO = Path(__file__).resolve().parents[1]
#: 4 agents of two families (half of --quick's pool, two a side in every family split): what is checked here does
#: not depend on the pool's size, and the study runs half the episodes
VALIDATE = ["validate", "--quick", "--targets", "3", "--seconds", "2", "--agent", "pid", "--agent", "pid-twitchy",
            "--agent", "vision", "--agent", "vision-fast", "--backend", "inline"]


def _cli(*args: str):
    return CliRunner().invoke(app, list(args), env=ENV)


@pytest.fixture
def shipped(tmp_path: Path) -> Path:
    """A copy of the repository's results/ and README.md."""
    shutil.copytree(REPO / "results", tmp_path / "results")
    shutil.copyfile(REPO / "README.md", tmp_path / "README.md")
    return tmp_path


def test_rebuild_check_passes_on_the_shipped_tables():
    res = _cli("results", "rebuild", "--check", "--root", str(REPO))
    assert res.exit_code == 0, res.output
    quotes, problems = readme_quotes((REPO / "README.md").read_text())
    assert not problems and len(quotes) >= 30  # README §5's rank-check figures are tagged


def test_an_edited_shipped_table_fails_the_check_naming_the_number(shipped: Path):
    csv = shipped / "results" / "rank_check_gym" / "targets.csv"
    lines = csv.read_text().splitlines()
    head, row = lines[0].split(","), lines[1].split(",")
    i = head.index("decided_with")
    row[i] = str(int(row[i]) + 5)
    csv.write_text("\n".join([lines[0], ",".join(row), *lines[2:]]) + "\n")
    was = json.loads((shipped / "results" / "numbers.json").read_text())["numbers"]["rank_check_gym.decided_with"]
    res = _cli("results", "rebuild", "--check", "--root", str(shipped))
    assert res.exit_code == 1, res.output
    assert (f"rank_check_gym.decided_with: results/numbers.json says {was['value']}, recomputed {was['value'] + 5}"
            in res.output)
    assert "results/rank_check_gym/summary.json is not its recomputation" in res.output
    assert "README.md line" in res.output and f"rank_check_gym.decided_with is quoted as {was['value']}" in res.output


def test_an_edited_number_or_quote_fails_the_check_naming_it(shipped: Path):
    numbers = shipped / "results" / "numbers.json"
    doc = json.loads(numbers.read_text())
    doc["numbers"]["rank_check_heldout.worth.max"]["value"] = 1.6
    numbers.write_text(json.dumps(doc))
    readme = shipped / "README.md"
    text = readme.read_text()
    quoted = "[0, 0.09]<!-- n:rank_check_heldout.targets_wrong_with.count"
    assert text.count(quoted) == 1
    readme.write_text(text.replace(quoted, quoted.replace("0.09", "0.08")))
    res = _cli("results", "rebuild", "--check", "--root", str(shipped))
    assert res.exit_code == 1, res.output
    assert "rank_check_heldout.worth.max: results/numbers.json says 1.6, recomputed 1.49" in res.output
    assert "rank_check_heldout.targets_wrong_with.interval.1 is quoted as 0.08" in res.output
    assert res.output.count("✗ ") == 2  # nothing else differs


def test_readme_quotes_pair_names_with_the_last_figures_before_each_marker():
    text = ("K−1 of **0 of 40** [0, 0.09]<!-- n:r.a .b .c .d --> then 1,322 vs −0.5<!-- n:s.x s.y*100 -->\n"
            "52<!-- n:s.w/60 --> and 7<!-- n:s.p s.q -->")
    quotes, problems = readme_quotes(text)
    assert [(q.name, q.text) for q in quotes] == [("r.a", "0"), ("r.b", "40"), ("r.c", "0"), ("r.d", "0.09"),
                                                   ("s.x", "1,322"), ("s.y", "−0.5"), ("s.w", "52")]
    assert quotes[5].scale == 100 and quotes[6].scale == pytest.approx(1 / 60) and quotes[6].line == 2
    assert problems == ["README.md line 2: the marker names 2 numbers but only 1 figures precede it"]


# -- export of a finished quick validate study ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("evidence") / "study"
    res = _cli(*VALIDATE, "--out", str(out))
    assert res.exit_code == 0, res.output
    return out


def _leaves(obj, prefix=""):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _leaves(v, f"{prefix}{k}.")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _leaves(v, f"{prefix}{i}.")
    else:
        yield prefix[:-1], obj


@pytest.mark.slow
def test_export_lands_the_files_and_rebuilds_the_study_s_own_numbers(study: Path, tmp_path: Path):
    (tmp_path / "results").mkdir()
    res = _cli("results", "export", str(study), "quick_validate", "--root", str(tmp_path), "--machine", "CI")
    assert res.exit_code == 0, res.output
    run = tmp_path / "results" / "quick_validate"
    names = {p.relative_to(run).as_posix() for p in run.rglob("*") if p.is_file()}
    assert names == {"README.md", "criteria.json", "looks.jsonl", "summary.json", "targets.csv", "episodes.csv.gz",
                     "targets/000.json", "targets/001.json", "targets/002.json"}
    for name in ("criteria.json", "looks.jsonl", "summary.json", "targets/001.json"):
        assert (run / name).read_bytes() == (study / name).read_bytes()  # the look log's hashes still hold
    import pandas as pd

    episodes = pd.read_csv(run / "episodes.csv.gz")
    assert set(episodes["target"]) == {0, 1, 2} and {"target", "candidate"} <= set(episodes["role"])
    assert len(episodes) == len(list((study / "runs").rglob("episodes/*.json")))
    readme = (run / "README.md").read_text()
    assert "Machine**: CI" in readme and "criteria.json's commit" in readme

    res = _cli("results", "rebuild", "--root", str(tmp_path))
    assert res.exit_code == 0, res.output
    numbers = json.loads((tmp_path / "results" / "numbers.json").read_text())["numbers"]
    summary = json.loads((study / "summary.json").read_text())
    compared = 0
    for path, value in _leaves(summary):
        if isinstance(value, bool) or not isinstance(value, int | float) or path.startswith("criteria.") \
                or value != value:  # NaN
            continue
        assert numbers[f"quick_validate.{path}"]["value"] == pytest.approx(value, rel=1e-9, abs=1e-12), path
        compared += 1
    assert compared > 100 and "quick_validate.primary.mean" in numbers
    assert _cli("results", "rebuild", "--check", "--root", str(tmp_path)).exit_code == 0

    again = _cli("results", "export", str(study), "quick_validate", "--root", str(tmp_path))
    assert again.exit_code == 1 and "give --replace" in again.output
    assert _cli("results", "export", str(study), "quick_validate", "--root", str(tmp_path),
                "--replace").exit_code == 0


@pytest.mark.slow
def test_export_refuses_an_interim_study(study: Path, tmp_path: Path):
    """The study as it stood after 2 of its 3 targets (record and log line of the third gone), then looked at."""
    copy = Path(shutil.copytree(study, tmp_path / "study"))
    (copy / "targets" / "002.json").unlink()
    lines = (copy / "looks.jsonl").read_text().splitlines()
    cut = next(i for i, line in enumerate(lines) if json.loads(line).get("target") == 2)
    (copy / "looks.jsonl").write_text("\n".join(lines[:cut]) + "\n")
    look = _cli(*VALIDATE, "--out", str(copy), "--interim")
    assert look.exit_code == 0, look.output
    assert json.loads((copy / "summary.json").read_text())["interim"] is True
    (tmp_path / "results").mkdir()
    res = _cli("results", "export", str(copy), "early", "--root", str(tmp_path))
    assert res.exit_code == 1
    assert "is an interim look (2 of 3 targets): the study is unfinished" in res.output
    assert not (tmp_path / "results" / "early").exists()


@pytest.mark.slow
def test_export_refuses_a_failed_pre_registration_check(study: Path, tmp_path: Path):
    copy = Path(shutil.copytree(study, tmp_path / "study"))
    record = copy / "targets" / "001.json"
    record.write_bytes(record.read_bytes() + b"\n")  # still a valid record, no longer the one logged
    (tmp_path / "results").mkdir()
    res = _cli("results", "export", str(copy), "edited", "--root", str(tmp_path))
    assert res.exit_code == 1
    assert "pre-registration check failed: targets/001.json is not the record looks.jsonl holds" in res.output
    assert not (tmp_path / "results" / "edited").exists()


def test_export_refuses_a_rank_check_study_that_is_still_running(tmp_path: Path):
    study = Path(shutil.copytree(REPO / "results" / "rank_check_gym", tmp_path / "study"))
    covered = json.loads((study / "summary.json").read_text())["targets"]
    for k in range(covered + 2):  # the folder already holds targets past those its summary covers
        (study / "targets" / str(k) / "runs").mkdir(parents=True)
    (tmp_path / "results").mkdir()
    res = _cli("results", "export", str(study), "gym", "--root", str(tmp_path))
    assert res.exit_code == 1
    assert (f"holds {covered + 2} targets' episodes but its summary covers {covered}: the study is running or was "
            "extended") in res.output


# -- a PLV run (the 15-seed full run is shipped the same way) ---------------------------------------------------------

def _plv_study(folder: Path) -> Path:
    """A finished `proxybench plv` report folder: the registered study's canned result (nothing trains), each
    training run given three evaluation episodes whose mean is its score, written by the PLV report itself."""
    from proxybench.experiments.plv.study import PLVStudy

    study = PLVStudy()
    res = study.example()
    for r in res.runs:
        r["scores"] = [r["score"] - 0.5, r["score"], r["score"] + 0.5]
        r["terminations"] = ["timeout", "timeout", "out-of-lane"]
    study.write_report(res, folder)
    return folder


def test_a_plv_run_exports_and_rebuilds_to_its_own_table(tmp_path: Path):
    study = _plv_study(tmp_path / "plv-out")
    (tmp_path / "results").mkdir()
    res = _cli("results", "export", str(study), "plv_example", "--root", str(tmp_path))
    assert res.exit_code == 0, res.output
    shipped = tmp_path / "results" / "plv_example"
    assert {p.name for p in shipped.iterdir()} == {"plv.json", "runs.csv.gz", "episodes.csv.gz", "README.md"}
    assert "runs" not in json.loads((shipped / "plv.json").read_text())  # the runs travel as tables
    res = _cli("results", "rebuild", "--root", str(tmp_path))
    assert res.exit_code == 0, res.output
    numbers = json.loads((tmp_path / "results" / "numbers.json").read_text())["numbers"]
    report = json.loads((study / "plv.json").read_text())["summary"]
    row = next(r for r in report["rows"] if r["proxy"] == "pitch-19")
    assert numbers["plv_example.reference"]["value"] == pytest.approx(report["reference"])
    assert numbers["plv_example.rows.pitch-19.plv"]["value"] == pytest.approx(row["plv"])
    assert numbers["plv_example.rows.pitch-19.plv"]["source"] == "results/plv_example/runs.csv.gz"


def test_an_edited_plv_episode_table_fails_the_check_naming_the_run(tmp_path: Path):
    import gzip

    study = _plv_study(tmp_path / "plv-out")
    (tmp_path / "results").mkdir()
    assert _cli("results", "export", str(study), "plv_example", "--root", str(tmp_path)).exit_code == 0
    assert _cli("results", "rebuild", "--root", str(tmp_path)).exit_code == 0
    table = tmp_path / "results" / "plv_example" / "episodes.csv.gz"
    lines = gzip.decompress(table.read_bytes()).decode().splitlines()
    head, first = lines[0].split(","), lines[1].split(",")
    first[head.index("score")] = "99.0"  # one evaluation episode of arm pitch-19, n=250, seed 0
    table.write_bytes(gzip.compress("\n".join([lines[0], ",".join(first), *lines[2:]]).encode() + b"\n"))
    res = _cli("results", "rebuild", "--check", "--root", str(tmp_path))
    assert res.exit_code == 1
    assert f"run {first[0]} n={first[1]} seed={first[2]}" in res.output


def test_export_refuses_a_plv_run_missing_a_proxy_s_training(tmp_path: Path):
    study = _plv_study(tmp_path / "plv-out")
    blob = json.loads((study / "plv.json").read_text())
    blob["runs"] = [r for r in blob["runs"] if r["arm"] != "pitch-35"]
    (study / "plv.json").write_text(json.dumps(blob))
    (tmp_path / "results").mkdir()
    res = _cli("results", "export", str(study), "plv_example", "--root", str(tmp_path))
    assert res.exit_code == 1
    assert "no training run of arm 'pitch-35': the run is unfinished" in res.output
    assert not (tmp_path / "results" / "plv_example").exists()


# -- plv-vs-prpv ----------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def choice_study(tmp_path_factory) -> Path:
    """A finished plv-vs-prpv comparison on the reality model: PLV read from a canned PLV run, PRPV from 8 agents
    (not in alphabetical order: the shipped table is sorted, the bootstrap resamples in the run's order) × 3
    episodes replayed in its two proxies (the nominal and camera pitch 35°)."""
    import yaml

    from proxybench.cli import learning  # noqa: F401 - registers the command

    tmp = tmp_path_factory.mktemp("choice")
    run = _plv_study(tmp / "plv")
    exp = {"agents": ["straight", "bang-bang", "pid", "pid-fast", "pid-twitchy", "pure-pursuit", "pid-sluggish",
                      "random"], "episodes": 3, "seconds": 3.0, "image_size": [32, 24], "n_boot": 100,
           "plv": {"from_run": str(run)}}
    (tmp / "exp.yaml").write_text(yaml.safe_dump(exp))
    res = _cli("plv-vs-prpv", "--config", str(tmp / "exp.yaml"), "--out", str(tmp / "out"), "--backend", "inline")
    assert res.exit_code == 0, res.output
    return tmp / "out"


def test_a_plv_vs_prpv_comparison_exports_and_rebuilds_its_picks(choice_study: Path, tmp_path: Path):
    (tmp_path / "results").mkdir()
    res = _cli("results", "export", str(choice_study), "plv_vs_prpv", "--root", str(tmp_path))
    assert res.exit_code == 0, res.output
    shipped = tmp_path / "results" / "plv_vs_prpv"
    assert {p.name for p in shipped.iterdir()} == {"choice.json", "episodes.csv.gz", "README.md"}
    assert "episode_scores" not in json.loads((shipped / "choice.json").read_text())["extra"]
    res = _cli("results", "rebuild", "--root", str(tmp_path))
    assert res.exit_code == 0, res.output
    numbers = json.loads((tmp_path / "results" / "numbers.json").read_text())["numbers"]
    written = {c["label"]: c for c in json.loads((choice_study / "choice.json").read_text())["candidates"]}
    assert numbers["plv_vs_prpv.candidates.camera_pitch-35.prpv"]["value"] == pytest.approx(
        written["camera_pitch=35"]["prpv"])
    assert numbers["plv_vs_prpv.candidates.nominal.prpv"]["source"] == "results/plv_vs_prpv/episodes.csv.gz"


def test_an_edited_plv_vs_prpv_episode_fails_the_check(choice_study: Path, tmp_path: Path):
    import gzip

    (tmp_path / "results").mkdir()
    assert _cli("results", "export", str(choice_study), "plv_vs_prpv", "--root", str(tmp_path)).exit_code == 0
    assert _cli("results", "rebuild", "--root", str(tmp_path)).exit_code == 0
    table = tmp_path / "results" / "plv_vs_prpv" / "episodes.csv.gz"
    lines = gzip.decompress(table.read_bytes()).decode().splitlines()
    head = lines[0].split(",")
    edited = []
    for line in lines[1:]:  # the straight agent drives 100 m in every candidate's replay: it now wins everywhere
        cells = line.split(",")
        if cells[head.index("domain")] != "target" and cells[head.index("agent")] == "straight":
            cells[head.index("driven_lanedir_consec")] = "100.0"
        edited.append(",".join(cells))
    table.write_bytes(gzip.compress("\n".join([lines[0], *edited]).encode() + b"\n"))
    res = _cli("results", "rebuild", "--check", "--root", str(tmp_path))
    assert res.exit_code == 1
    assert "plv_vs_prpv: results/plv_vs_prpv/choice.json is not its recomputation" in res.output
