"""The shipped evidence (``results/`` at the repository root; docs/results.md).

:func:`export_study` condenses a *finished* study's folder into ``results/NAME/``: what a reviewer needs to
recompute its numbers — no caches, no trajectories — with a ``README.md`` saying what it is and how it was made.
:func:`rebuild` recomputes every number that README.md can quote from what is shipped, through each study's own
summary code (the validation study's :func:`~proxybench.experiments.validate.scoring.summarize`, rank-check's
:func:`~proxybench.experiments.rank_check.run.write_rank_check`), and checks the shipped files against their
recomputation; :func:`check` compares it with ``results/numbers.json`` and with README.md's tagged quotes.

README.md ties a quoted figure to a number with an HTML comment right after it: ``<!-- n:NAME -->``. Several
figures in a row take several names, ``<!-- n:NAME1 NAME2 -->``: the last figures before the comment (after the
previous comment), in order; a name that starts with a dot is in the run last named (``<!-- n:rank_check_gym.pairs
.decided_with -->``). ``NAME*100`` compares a share quoted in per cent, ``NAME/60`` seconds quoted in
minutes. A quote holds when the recomputed
value, rounded to the decimals the quote shows, is the quote. NAME is ``RUN.PATH``: the run's folder in
``results/`` and the number's path in the recomputed summary (``rank_check_gym.targets_wrong_with.share``,
``validate_gym.primary.mean``), as ``results/numbers.json`` lists them.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import math
import platform
import re
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

__all__ = ["EPISODES", "NUMBERS", "RESULTS", "EvidenceError", "Exported", "Number", "Quote", "Rebuilt", "check",
           "export_study", "find_root", "readme_quotes", "rebuild", "study_kind", "write_numbers"]

RESULTS = "results"
NUMBERS = "numbers.json"
#: the per-episode score table of a run (gzip with no time stamp: the same episodes give the same bytes)
EPISODES = "episodes.csv.gz"
Kind = Literal["validate", "rank-check", "plv", "plv-vs-prpv"]
#: a PLV run's training runs (one row each) beside the per-episode table (:mod:`proxybench.experiments.plv.stored`)
RUNS = "runs.csv.gz"
_NAME = re.compile(r"[a-z0-9][a-z0-9_-]{0,63}")
_MARKER = re.compile(r"<!--\s*n:(.*?)-->", re.S)
#: a quoted figure: optional sign (ASCII or typographic minus), thousands separated by commas, decimals; not
#: part of a word or of a longer figure (``K−1``, ``v2``)
_FIGURE = re.compile(r"(?<![\w.,+\-−])[+\-−]?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?![\w])")
#: summary fields that are not the study's result (where and when it was recomputed)
#: fields of a validate summary.json that are not recomputed numbers: the checks of the day, and the verdict sentence
#: the report adds (the report's words about the numbers, which are compared themselves)
_NOT_COMPARED = ("criteria.commit_now", "criteria.scoring_unchanged", "criteria.problems", "verdict")


class EvidenceError(Exception):
    """A study that cannot be shipped, or shipped evidence that cannot be read; one line naming the problem."""


@dataclass(frozen=True)
class Number:
    """A recomputed number and the shipped file it comes from (relative to the repository root)."""

    value: float | int
    source: str


@dataclass
class Rebuilt:
    """Every number recomputed from ``results/``, and what disagreed on the way (empty: the shipped files agree
    with their recomputation)."""

    numbers: dict[str, Number]
    problems: list[str] = field(default_factory=list)


@dataclass
class Exported:
    """A run written to ``results/NAME/``: its files and their sizes in bytes, and notes for the user."""

    folder: Path
    files: dict[str, int]
    notes: list[str] = field(default_factory=list)

    @property
    def size(self) -> int:
        return sum(self.files.values())


@dataclass(frozen=True)
class Quote:
    """A figure README.md quotes and the number it is tagged with."""

    name: str
    text: str  # the figure as written
    line: int
    scale: float = 1.0


# -- small helpers --------------------------------------------------------------------------------------------------

def find_root(start: Path | None = None) -> Path:
    """The repository root: the first folder from ``start`` (the working directory) upwards holding ``results/``."""
    here = (start or Path.cwd()).resolve()
    for p in (here, *here.parents):
        if (p / RESULTS).is_dir():
            return p
    raise EvidenceError(f"no {RESULTS}/ folder in {here} or above it; run from the repository or give --root")


def _json(path: Path) -> Any:
    try:
        return json.loads(path.read_bytes())
    except FileNotFoundError:
        raise EvidenceError(f"{path} is missing") from None
    except (OSError, ValueError) as exc:
        raise EvidenceError(f"{path}: unreadable ({exc.__class__.__name__}: {exc})") from None


def _flatten(obj: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """(dotted path, leaf) of a JSON-like tree; dataclasses as dicts, list items by index."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        obj = dataclasses.asdict(obj)
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _flatten(v, f"{prefix}{k}.")
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            yield from _flatten(v, f"{prefix}{i}.")
    else:
        yield prefix[:-1], obj


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _same(a: Any, b: Any) -> bool:
    if _is_number(a) and _is_number(b):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)
    return a == b


def _differences(shipped: dict[str, Any], recomputed: dict[str, Any], what: str) -> list[str]:
    """``what``'s fields whose shipped value is not the recomputed one (at most three named, then a count)."""
    keys = sorted({*shipped, *recomputed} - {k for k in {*shipped, *recomputed} if k.startswith(_NOT_COMPARED)})
    bad = [k for k in keys if k not in shipped or k not in recomputed or not _same(shipped[k], recomputed[k])]
    words = [f"{k}: {_show(shipped.get(k, 'absent'))} shipped, {_show(recomputed.get(k, 'absent'))} recomputed"
             for k in bad[:3]]
    if not bad:
        return []
    more = f" (and {len(bad) - 3} more)" if len(bad) > 3 else ""
    return [f"{what} is not its recomputation: {'; '.join(words)}{more}"]


def _show(v: Any) -> str:
    return repr(v) if isinstance(v, float) else str(v)


def _as_json(v: float | int) -> float | int | str:
    """A number for numbers.json: non-finite ones as strings (strict JSON has none)."""
    if isinstance(v, float) and not math.isfinite(v):
        return "NaN" if math.isnan(v) else ("Infinity" if v > 0 else "-Infinity")
    return v


def _from_json(v: Any) -> Any:
    return float(v) if v in ("NaN", "Infinity", "-Infinity") else v


# -- what a study folder is ----------------------------------------------------------------------------------------

def study_kind(folder: Path) -> Kind:
    """``validate`` (a folder with criteria.json), ``plv`` (plv.json), ``plv-vs-prpv`` (choice.json) or
    ``rank-check`` (summary.json with rank-check's fields and targets.csv)."""
    if (folder / "criteria.json").is_file():
        return "validate"
    if (folder / "plv.json").is_file():
        return "plv"
    if (folder / "choice.json").is_file():
        return "plv-vs-prpv"
    if (folder / "summary.json").is_file() and (folder / "targets.csv").is_file():
        summary = _json(folder / "summary.json")
        if isinstance(summary, dict) and "decided_with" in summary:
            return "rank-check"
    raise EvidenceError(f"{folder}: neither a validate study (criteria.json), a PLV run (plv.json), a plv-vs-prpv "
                        "comparison (choice.json) nor a rank-check study (summary.json and targets.csv)")


@dataclass
class _ValidateStudy:
    """A validation study's shipped parts, loaded with this code's models."""

    criteria: dict[str, Any]
    settings: Any  # ValidateSettings
    record_bytes: dict[int, bytes]
    records: list[Any]  # TargetRecord
    shipped: dict[str, Any]  # summary.json


def _load_validate(folder: Path, *, finished: bool) -> _ValidateStudy:
    from pydantic import ValidationError

    from proxybench.experiments.validate.config import ValidateSettings
    from proxybench.experiments.validate.measures import TargetRecord

    criteria = _json(folder / "criteria.json")
    try:
        settings = ValidateSettings.model_validate((criteria or {}).get("settings"))
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(map(str, err["loc"]))
        raise EvidenceError(f"{folder / 'criteria.json'}: its settings do not load with this code ({where}: "
                            f"{err['msg']})") from None
    if not (folder / "summary.json").is_file():
        raise EvidenceError(f"{folder / 'summary.json'} is missing: the study has not reported (unfinished)")
    shipped = _json(folder / "summary.json")
    if finished and shipped.get("interim"):
        raise EvidenceError(f"{folder / 'summary.json'} is an interim look ({shipped.get('targets')} of "
                            f"{settings.targets} targets): the study is unfinished")
    record_bytes, records = {}, []
    for k in range(settings.targets):
        path = folder / "targets" / f"{k:03d}.json"
        try:
            data = path.read_bytes()
            records.append(TargetRecord.model_validate_json(data))
        except FileNotFoundError:
            raise EvidenceError(f"{path} is missing: {len(records)} of {settings.targets} targets finished (the "
                                "study is unfinished)") from None
        except (OSError, ValueError) as exc:
            raise EvidenceError(f"{path}: not a target record ({exc.__class__.__name__})") from None
        record_bytes[k] = data
    return _ValidateStudy(criteria, settings, record_bytes, records, shipped)


class _Revealed:
    """A finished target as summarize sees it: its θ, revealed by the study's final report (summary.json)."""

    def __init__(self, truth: dict[str, float]):
        self._truth = truth

    def reveal(self) -> dict[str, float]:
        return dict(self._truth)


def _scoring_changes(criteria: dict[str, Any]) -> list[str]:
    """Files of the scoring code that differ now from those criteria.json hashed."""
    from proxybench.experiments.validate.registration import scoring_hash

    written, now = criteria.get("scoring_sha256") or {}, scoring_hash()
    return sorted(f for f in {*written, *now} if written.get(f) != now.get(f))


def _registration_problems(folder: Path, st: _ValidateStudy) -> list[str]:
    """The pre-registration's checks on the shipped files (the look log's chain, every record against it, the
    minimum detectable effect, criteria older than the episodes), with the scoring code left out (it is compared
    apart: code may change after a study without changing its data), and summary.json against its logged look."""
    from proxybench.experiments.validate.measures import ValidationSummary
    from proxybench.experiments.validate.registration import (
        check_registration,
        read_looks,
        scoring_hash,
        summary_sha256,
    )

    problems, _ = check_registration(folder, st.settings, {**st.criteria, "scoring_sha256": scoring_hash()},
                                     st.record_bytes)
    if problems:
        return problems
    looks = [e for e in read_looks(folder)[0] if e.get("look") in ("interim", "final")]
    if not looks or looks[-1].get("look") != "final":
        return ["looks.jsonl holds no final look: the study never reported on all its targets"]
    try:
        parsed = ValidationSummary.model_validate({k: v for k, v in st.shipped.items()
                                                   if k in ValidationSummary.model_fields})
        sha = summary_sha256(parsed)
    except ValueError as exc:
        return [f"summary.json does not load with this code ({exc.__class__.__name__}): cannot check it against "
                "the final look"]
    if sha != looks[-1].get("summary_sha256"):
        return ["summary.json is not the summary the final look logged in looks.jsonl (edited, or written by "
                "another look)"]
    return []


def _validate_summary(folder: Path, st: _ValidateStudy) -> Any:
    """The study's summary recomputed from the shipped records and criteria, by the study's own summarize."""
    from proxybench.experiments.validate.scoring import ValidationRun, summarize

    truths = st.shipped.get("truths") or []
    targets = [_Revealed(truths[i] if i < len(truths) else {}) for i in range(len(st.records))]
    run = ValidationRun(settings=st.settings, criteria_file=folder / "criteria.json", records=st.records,
                        targets=targets, wall_s=float(st.shipped.get("wall_s") or 0.0),
                        indices=list(range(len(st.records))), scoring_unchanged=not _scoring_changes(st.criteria))
    return summarize(run, st.criteria)


def _rank_check_result(folder: Path) -> Any:
    """rank-check's result rebuilt from its shipped targets.csv and summary.json (settings, statement, wall)."""
    import pandas as pd

    from proxybench.experiments.rank_check.config import RankCheckConfig
    from proxybench.experiments.rank_check.run import RankCheckResult, TargetCheck

    summary = _json(folder / "summary.json")
    try:
        frame = pd.read_csv(folder / "targets.csv", dtype={"target": str})
    except (OSError, ValueError) as exc:
        raise EvidenceError(f"{folder / 'targets.csv'}: unreadable ({exc.__class__.__name__})") from None
    cast = {"int": int, "float": float, "str": str}
    fields = dataclasses.fields(TargetCheck)
    missing = [f.name for f in fields if f.name not in frame.columns]
    if missing:
        raise EvidenceError(f"{folder / 'targets.csv'}: no column {', '.join(missing)}")
    rows = [TargetCheck(**{f.name: cast[str(f.type)](row[f.name]) for f in fields})
            for row in frame.to_dict("records")]
    try:
        config = RankCheckConfig.model_validate(summary.get("config"))
    except ValueError as exc:
        raise EvidenceError(f"{folder / 'summary.json'}: its config does not load ({exc.__class__.__name__})") from None
    return RankCheckResult(config, rows, str(summary.get("statement", "")), float(summary.get("wall_s") or 0.0),
                           list(summary.get("notes") or []))


def _rank_check_summary(res: Any) -> dict[str, Any]:
    """summary.json as rank-check's own writer makes it from ``res``."""
    from proxybench.experiments.rank_check.run import write_rank_check

    with tempfile.TemporaryDirectory() as tmp:
        write_rank_check(res, tmp)
        return json.loads((Path(tmp) / "summary.json").read_text())


def _rank_check_extras(res: Any) -> dict[str, float]:
    """Figures README quotes that rank-check's summary does not hold, from its per-target rows: the decisions the
    proxy adds per target (mean, and the paired percentile bootstrap over targets of
    :func:`proxybench.usefulness.validation.compare`: 2000 resamples, seed 0), pair decisions per target, the
    worth's mean and maximum over targets, the agents ranked, and the proxy's weight λ (each target's median
    pair) over targets."""
    import numpy as np

    from proxybench.usefulness.validation import compare

    rows = res.rows
    extra = compare("with the proxy", "target alone", [r.decided_with for r in rows],
                    [r.decided_alone for r in rows], seed=0)
    worth = np.array([r.worth for r in rows], float)
    weight = np.array([r.median_weight for r in rows], float)
    n = len(rows)
    return {"agents": len(res.config.agents or []), "extra_decisions_per_target.mean": extra.mean,
            "extra_decisions_per_target.low": extra.low, "extra_decisions_per_target.high": extra.high,
            "pairs_per_target": sum(r.pairs for r in rows) / n if n else float("nan"),
            "worth.mean": float(np.nanmean(worth)) if n else float("nan"),
            "worth.max": float(np.nanmax(worth)) if n else float("nan"),
            "median_weight.median": float(np.nanmedian(weight)) if n else float("nan"),
            "median_weight.mean": float(np.nanmean(weight)) if n else float("nan")}


# -- the per-episode score table -----------------------------------------------------------------------------------

def _episode_files(runs: Path) -> Iterator[Path]:
    if runs.is_dir():
        yield from (p for p in runs.rglob("*.json") if p.parent.name == "episodes")


def _episode_rows(files: Iterator[Path], describe) -> list[dict[str, Any]]:
    rows, seen = [], set()
    for path in files:
        try:
            ep = json.loads(path.read_bytes())
        except (OSError, ValueError):
            continue  # a damaged cache file is redone by the runner, never trusted
        where = describe(ep, path)
        if (where["target"], ep["key"]) in seen:  # one episode per target (two targets may share a proxy episode)
            continue
        seen.add((where["target"], ep["key"]))
        rows.append({**where, "agent": ep["agent"], "domain": ep["domain"], "episode": ep["episode"],
                     "seed": ep["seed"], "termination": ep["termination"], **ep["scores"], "key": ep["key"]})
    return rows


def _write_table(rows: list[dict[str, Any]], order: list[str], path: Path) -> int:
    """``rows`` as a gzip'd CSV in a fixed order (no time stamp in the gzip header): the same episodes give the
    same bytes. Returns the rows written."""
    import pandas as pd

    frame = pd.DataFrame(rows)
    frame = frame.sort_values([c for c in order if c in frame.columns], kind="stable")
    text = frame.to_csv(index=False, lineterminator="\n")
    with path.open("wb") as raw, gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0, compresslevel=9) as gz:
        gz.write(text.encode())
    return len(frame)


def _validate_episodes(folder: Path, st: _ValidateStudy, dest: Path) -> int:
    """Every cached episode of the study (OUT/runs): its target (from its seed, as the study seeds them), whether it
    ran on the target or replayed a candidate θ, which split (E1: tuning agents, E2: held-out), its scores."""
    by_seed = {r.seed: (k, r.target) for k, r in enumerate(st.records)}
    tune = st.settings.episodes_tune

    def describe(ep: dict[str, Any], _path: Path) -> dict[str, Any]:
        k, name = by_seed.get(ep["seed"] // 10_000, (-1, ""))  # targets.base.episode_seed: seed × 10 000 + id
        dom = str(ep["domain"])
        cand = int(dom.split()[-1]) if dom.startswith("candidate ") else -1
        return {"target": k, "target_name": name, "role": "candidate" if cand >= 0 else
                "target" if dom == name else "other", "candidate": cand, "split": "E1" if ep["episode"] < tune
                else "E2"}

    rows = _episode_rows(_episode_files(folder / "runs"), describe)
    if not rows:
        return 0
    return _write_table(rows, ["target", "role", "candidate", "agent", "episode", "domain", "key"], dest)


def _rank_check_episodes(folder: Path, res: Any, dest: Path) -> int:
    """Every cached episode under OUT/targets/K/runs: its target, whether it ran on the target or the proxy."""
    names = {k: r.target for k, r in enumerate(res.rows)}

    def describe(ep: dict[str, Any], path: Path) -> dict[str, Any]:
        k = int(path.relative_to(folder / "targets").parts[0])
        return {"target": k, "target_name": names.get(k, ""), "role": "target" if ep["domain"] == names.get(k)
                else "proxy"}

    files = (p for d in sorted((folder / "targets").glob("*")) if d.name.isdigit()
             for p in _episode_files(d / "runs"))
    rows = _episode_rows(files, describe)
    if not rows:
        return 0
    return _write_table(rows, ["target", "role", "agent", "episode", "domain", "key"], dest)


# -- a PLV run (``proxybench plv``) -----------------------------------------------------------------------------------

#: a training run's columns in runs.csv.gz (its evaluation episodes are in episodes.csv.gz)
_PLV_RUN_COLUMNS = ("arm", "n", "seed", "off_policy", "on_policy", "cost", "score", "final_loss", "train_s", "eval_s")
#: summary fields that are the bootstrap's per-seed draws or run-time bookkeeping, not numbers README quotes
_PLV_SKIP = (".scores.", "zero_shot_scores", "method")


def _word(name: str) -> str:
    return re.sub(r"[^a-z0-9_-]+", "-", name.lower()).strip("-") or "-"


def _plv_record(res: Any) -> dict[str, Any]:
    """plv.json's summary, findings and proxies as the PLV report writes them, through JSON (as shipped)."""
    from proxybench.experiments.plv.report import summary_record

    return json.loads(json.dumps(summary_record(res), default=str))


def _plv_differences(shipped: dict[str, Any], recomputed: dict[str, Any], rel: str) -> list[str]:
    return _differences(dict(_flatten({k: shipped.get(k) for k in ("summary", "findings")})),
                        dict(_flatten({k: recomputed[k] for k in ("summary", "findings")})), f"{rel}/plv.json")


def _plv_episode_rows(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per evaluation episode of every training run: which run (arm, rung n, seed), its score, its end."""
    rows = []
    for r in runs:
        ends = r.get("terminations") or [""] * len(r.get("scores") or [])
        for k, (score, end) in enumerate(zip(r.get("scores") or [], ends, strict=False)):
            rows.append({"arm": r["arm"], "n": r["n"], "seed": r["seed"], "episode": k, "score": score,
                         "termination": end})
    return rows


def _export_plv(study: Path, dest: Path, command: str | None, commit: str | None, machine: str | None,
                notes: list[str]) -> list[str]:
    blob = _json(study / "plv.json")
    runs = blob.get("runs") if isinstance(blob, dict) else None
    if not runs:
        raise EvidenceError(f"{study / 'plv.json'} holds no training runs (not a finished `proxybench plv` report)")
    res = _plv_result(blob, runs, study / "plv.json")
    differ = _plv_differences(blob, _plv_record(res), str(study))
    if differ:
        raise EvidenceError(f"{study}: {differ[0]}")
    shipped = {k: blob[k] for k in ("config", "summary", "findings", "proxies", "wall_s", "stage_s") if k in blob}
    (dest / "plv.json").write_text(json.dumps(shipped, indent=1, default=str) + "\n")
    n_runs = _write_table([{k: r.get(k) for k in _PLV_RUN_COLUMNS} for r in runs], ["arm", "n", "seed"],
                          dest / RUNS)
    episodes = _write_table(_plv_episode_rows(runs), ["arm", "n", "seed", "episode"], dest / EPISODES)
    cfg = res.config
    facts = "".join(f"- {f}\n" for f in blob.get("findings") or [])
    command = command or "`proxybench plv` with the config in plv.json (the run does not record its command line)"
    extra = "".join(f"- {n}\n" for n in notes)
    text = f"""# {dest.name}: proxy learning value (`proxybench plv`)

Target: {blob["summary"].get("target", "?")}. Proxies: {", ".join(f"{k} ({v})" for k, v in cfg.proxies.items())}.

{facts}
- **What**: a behaviour-cloning network trained on the target alone and after pre-training on each proxy, ladder
  {", ".join(f"{n:,}" for n in cfg.ladder)} target samples × {len(cfg.seeds)} seeds, each scored on
  {cfg.eval.episodes} evaluation episodes of {cfg.eval.seconds:g} s; PLV from fitted learning curves with bootstrap
  intervals over seeds (docs/learning.md).
- **Command**: {command}
- **Code**: {commit or "not recorded by the run"}.
- **Machine**: {machine or _machine_default()}.
- **Time**: {float(blob.get("wall_s") or 0.0) / 3600:.1f} h of wall time in the invocation that wrote plv.json
  (an interrupted run resumes from its cache; earlier invocations are not counted).
- **Tables**: {n_runs:,} training runs in `{RUNS}` (arm, rung n, seed, target samples off/on policy, cost, mean
  score, final loss, seconds); {episodes:,} evaluation episodes in `{EPISODES}` (arm, n, seed, episode, score,
  termination).
{extra}
Recompute: `proxybench results rebuild --check` (each run's score from its episodes, then plv.json's summary and
findings through the PLV report's own `summary_record`). Files:

{_files_table(dest)}
"""
    (dest / "README.md").write_text(text)
    return []


def _plv_result(blob: dict[str, Any], runs: list[dict[str, Any]], where: Path) -> Any:
    from proxybench.experiments.plv.stored import StoredRunError, result_of

    try:
        return result_of(blob, runs, where)
    except StoredRunError as exc:
        raise EvidenceError(str(exc)) from None


def _plv_runs_from_tables(folder: Path) -> tuple[list[dict[str, Any]], list[str]]:
    from proxybench.experiments.plv.stored import StoredRunError, runs_from_tables

    try:
        return runs_from_tables(folder)
    except StoredRunError as exc:
        raise EvidenceError(str(exc)) from None


def _plv_numbers(name: str, folder: Path, rel: str) -> Rebuilt:
    shipped = _json(folder / "plv.json")
    runs, problems = _plv_runs_from_tables(folder)
    record = _plv_record(_plv_result(shipped, runs, folder / "plv.json"))
    problems = [f"{name}: {p}" for p in problems + _plv_differences(shipped, record, rel)]
    summary = dict(record["summary"])
    # by the arm's name, not position, as one word that a README tag can hold ("pitch 19°" → "pitch-19")
    summary["rows"] = {_word(row["proxy"]): row for row in summary.get("rows") or []}
    summary["curves"] = {_word(arm): c for arm, c in (summary.get("curves") or {}).items()}
    numbers = {}
    for path, v in _flatten({"summary": summary, "wall_s": shipped.get("wall_s")}):
        if _is_number(v) and not any(s in f".{path}." for s in _PLV_SKIP):
            source = "plv.json" if path == "wall_s" else RUNS
            numbers[f"{name}.{path.removeprefix('summary.')}"] = Number(v, f"{rel}/{source}")
    return Rebuilt(numbers, problems)


# -- argmin PRPV against argmax PLV (``proxybench plv-vs-prpv``) -------------------------------------------------------

def _choice_scores_rows(scores: Any) -> list[dict[str, Any]]:
    """One row per episode: ``domain`` (``target``, or the candidate θ it replays), agent, episode, each metric."""
    rows = []
    for domain, by in [("target", scores.target), *scores.candidates.items()]:
        for agent, eps in by.items():
            for k, ep in enumerate(eps):
                rows.append({"domain": domain, "agent": agent, "episode": k,
                             **{m: float(v) for m, v in zip(scores.metrics, ep, strict=True)}})
    return rows


def _choice_scores_from_table(folder: Path, metrics: list[str]) -> Any:
    import numpy as np
    import pandas as pd

    from proxybench.experiments.plv_prpv.run import EpisodeScores

    try:
        frame = pd.read_csv(folder / EPISODES)
    except (OSError, ValueError) as exc:
        raise EvidenceError(f"{folder / EPISODES}: unreadable ({exc.__class__.__name__})") from None
    missing = [c for c in ("domain", "agent", "episode", *metrics) if c not in frame.columns]
    if missing:
        raise EvidenceError(f"{folder / EPISODES}: no column {', '.join(missing)}")
    by: dict[str, dict[str, np.ndarray]] = {}
    for (domain, agent), g in frame.groupby(["domain", "agent"], sort=False):
        by.setdefault(str(domain), {})[str(agent)] = g.sort_values("episode")[metrics].to_numpy(float)
    target = by.pop("target", {})
    return EpisodeScores(target, by, tuple(metrics))


def _choice_differences(shipped: dict[str, Any], recomputed: Any, what: str) -> list[str]:
    fresh = json.loads(json.dumps(recomputed.to_dict(), default=str))
    drop = ("extra", "wall_s")
    return _differences(dict(_flatten({k: v for k, v in shipped.items() if k not in drop})),
                        dict(_flatten({k: v for k, v in fresh.items() if k not in drop})), what)


def _export_choice(study: Path, dest: Path, command: str | None, commit: str | None, machine: str | None,
                   notes: list[str]) -> list[str]:
    from proxybench.experiments.plv_prpv.run import EpisodeScores, recompute_choice

    shipped = _json(study / "choice.json")
    extra = shipped.get("extra") or {}
    if "episode_scores" not in extra:
        raise EvidenceError(f"{study / 'choice.json'} holds no episode scores (written before they were kept): rerun "
                            "`proxybench plv-vs-prpv` with this code (its cached episodes are reused)")
    scores = EpisodeScores.from_dict(extra["episode_scores"])
    differ = _choice_differences(shipped, recompute_choice(shipped, scores), str(study / "choice.json"))
    if differ:
        raise EvidenceError(differ[0])
    # the bootstrap resamples agents in the order the run held them: keep that order (the table is sorted)
    slim = {**shipped, "extra": {**{k: v for k, v in extra.items() if k != "episode_scores"},
                                 "episode_agents": list(scores.target)}}
    (dest / "choice.json").write_text(json.dumps(slim, indent=1, default=str) + "\n")
    episodes = _write_table(_choice_scores_rows(scores), ["domain", "agent", "episode"], dest / EPISODES)
    source = extra.get("plv_from_run")
    plv = (f"read from the PLV run `{source}` (`--plv from_run`), shipped and rebuilt on its own where it is in "
           "results/" if source else "trained by this run (its networks are not shipped; PLV figures are "
           "taken as the run wrote them)")
    command = command or "`proxybench plv-vs-prpv` with the settings in choice.json (no command line recorded)"
    extra_lines = "".join(f"- {n}\n" for n in notes)
    text = f"""# {dest.name}: argmin PRPV against argmax PLV (`proxybench plv-vs-prpv`)

{shipped.get("verdict", "")}

- **What**: {len(shipped["candidates"])} candidate θ ({", ".join(c["label"] for c in shipped["candidates"])}) on
  {shipped["target"]}; PRPV from {len(shipped["agents"])} agents × {shipped["episodes"]} episodes on the target,
  each replayed in every candidate ({extra.get("n_boot")} bootstrap resamples, seed {extra.get("seed")}); PLV over
  {shipped["plv_seeds"]} seeds, {plv}.
- **Command**: {command}
- **Code**: {commit or "not recorded by the run"}.
- **Machine**: {machine or _machine_default()}.
- **Episodes**: {episodes:,} rows in `{EPISODES}` (domain: `target` or the candidate replayed, agent, episode, one
  column per task metric).
{extra_lines}
Recompute: `proxybench results rebuild --check` (every candidate's PRPV, order range, paired difference to the
lowest and both picks from `{EPISODES}` through plv-vs-prpv's own `recompute_choice`). Files:

{_files_table(dest)}
"""
    (dest / "README.md").write_text(text)
    return []


def _choice_numbers(name: str, folder: Path, rel: str) -> Rebuilt:
    from proxybench.experiments.plv_prpv.run import recompute_choice

    shipped = _json(folder / "choice.json")
    metrics = list((shipped.get("extra") or {}).get("metrics") or [])
    if not metrics:
        raise EvidenceError(f"{folder / 'choice.json'}: extra.metrics is missing")
    scores = _choice_scores_from_table(folder, metrics)
    order = list((shipped.get("extra") or {}).get("episode_agents") or scores.target)
    if sorted(order) != sorted(scores.target):
        raise EvidenceError(f"{folder / EPISODES}: its agents are not choice.json's extra.episode_agents")
    scores.target = {a: scores.target[a] for a in order}
    scores.candidates = {c: {a: by[a] for a in order if a in by} for c, by in scores.candidates.items()}
    res = recompute_choice(shipped, scores)
    problems = [f"{name}: {p}" for p in _choice_differences(shipped, res, f"{rel}/choice.json")]
    numbers = {}
    fresh = json.loads(json.dumps(res.to_dict(), default=str))
    tree = {"candidates": {_word(c["label"]): c for c in fresh["candidates"]}, "reference": fresh["reference"],
            "target_samples": fresh["target_samples"]}
    for path, v in _flatten(tree):
        if _is_number(v) and ".theta." not in f".{path}.":
            numbers[f"{name}.{path}"] = Number(v, f"{rel}/{EPISODES}" if ".prpv" in f".{path}" or ".delta." in
                                               f".{path}." else f"{rel}/choice.json")
    return Rebuilt(numbers, problems)


# -- export ---------------------------------------------------------------------------------------------------------

def _machine_default() -> str:
    import os

    return (f"not recorded by the study; exported on {platform.system()} {platform.machine()}, "
            f"{os.cpu_count()} CPUs, Python {platform.python_version()}")


def _elapsed(a: str, b: str) -> str:
    from datetime import datetime

    try:
        fmt = "%Y-%m-%d %H:%M:%S %z"
        s = (datetime.strptime(b, fmt) - datetime.strptime(a, fmt)).total_seconds()
    except (TypeError, ValueError):
        return "unknown"
    return f"{int(s // 3600)} h {int(s % 3600 // 60)} min" if s >= 3600 else f"{s / 60:.1f} min"


def _files_table(folder: Path) -> str:
    """A markdown table of the run's files (the target records on one line: looks.jsonl holds each one's sha256)."""
    import hashlib

    lines = ["| file | bytes | sha256 |", "| --- | ---: | --- |"]
    files = sorted(q for q in folder.rglob("*") if q.is_file() and q.name != "README.md")
    records = [p for p in files if p.parent.name == "targets"]
    for p in (p for p in files if p not in records):
        lines.append(f"| `{p.relative_to(folder).as_posix()}` | {p.stat().st_size:,} | "
                     f"`{hashlib.sha256(p.read_bytes()).hexdigest()[:16]}…` |")
    if records:
        lines.append(f"| `targets/{records[0].name}` … `{records[-1].name}` ({len(records)} records) | "
                     f"{sum(p.stat().st_size for p in records):,} | each in looks.jsonl |")
    return "\n".join(lines)


def _export_validate(study: Path, dest: Path, command: str | None, commit: str | None, machine: str | None,
                     notes: list[str]) -> list[str]:
    from proxybench.experiments.reporting import source_commit
    from proxybench.experiments.validate.report import answer

    st = _load_validate(study, finished=True)
    problems = st.shipped.get("criteria", {}).get("problems") or []
    if problems:
        raise EvidenceError(f"{study}: its final report failed the pre-registration check: {problems[0]}")
    problems = _registration_problems(study, st)
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise EvidenceError(f"{study}: pre-registration check failed: {problems[0]}{more}")
    summary = _validate_summary(study, st)
    differ = _differences(dict(_flatten(st.shipped)), dict(_flatten(summary.model_dump())), "summary.json")
    if differ:
        raise EvidenceError(f"{study}: {differ[0]}")
    for name in ("criteria.json", "looks.jsonl", "summary.json", "targets.csv"):
        shutil.copyfile(study / name, dest / name)
    (dest / "targets").mkdir()
    for k, data in st.record_bytes.items():
        (dest / "targets" / f"{k:03d}.json").write_bytes(data)
    episodes = _validate_episodes(study, st, dest / EPISODES)
    changed = _scoring_changes(st.criteria)
    said = []
    if changed:
        said.append(f"the scoring code at export differs from the code criteria.json hashed in {', '.join(changed)}; "
                    "`proxybench results rebuild` recomputes the summary with today's code and says where it "
                    "disagrees")
    if not episodes:
        said.append(f"no per-episode table: {study / 'runs'} held no cached episode")
    looks = [json.loads(line) for line in (study / "looks.jsonl").read_text().splitlines()]
    s = st.settings
    registered, final = st.criteria.get("written", "?"), looks[-1].get("time", "?")
    table = _files_table(dest)
    quick = " --quick" if s.quick else ""
    command = command or (f"`proxybench validate --family {s.family}{quick} ...` with the settings in criteria.json "
                          "(the study does not record its command line)")
    extra = "".join(f"- {n}\n" for n in [*said, *notes])
    grid = json.dumps({k: list(v) for k, v in s.grid.items()})
    text = f"""# {dest.name}: the validation study (`proxybench validate`), {s.family} family

{answer(summary)}

- **What**: {summary.targets} targets of the {s.family} family, pre-registered in `criteria.json`; per target
  {len(s.agents)} named agents (+ {s.bc_agents} behaviour-cloned) split into tuning and held-out halves,
  {s.episodes_tune} + {s.episodes_eval} target episodes of {s.seconds:g} s, candidates the grid
  {grid} and the nominal θ (docs/validate.md).
- **Command**: {command}
- **Code**: criteria.json's commit `{commit or st.criteria.get('commit', '?')}` (frozen for the study); exported at
  `{source_commit()}`.
- **Machine**: {machine or _machine_default()}.
- **Time**: registered {registered}, final look {final} ({_elapsed(registered, final)} from registration to the
  final look, pauses included); the last process ran {float(st.shipped.get('wall_s') or 0.0) / 60:.1f} min.
- **Episodes**: {episodes:,} cached episodes in `{EPISODES}` (target, role: target or candidate replay, candidate,
  split E1/E2, agent, episode, seed, termination, one column per task metric).
{extra}
Recompute: `proxybench results rebuild --check` (the summary from `targets/` and `criteria.json` through the
study's own `summarize`; the look log's chain and every record against it). Files:

{table}
"""
    (dest / "README.md").write_text(text)
    return said


def _export_rank_check(study: Path, dest: Path, command: str | None, commit: str | None, machine: str | None,
                       notes: list[str]) -> list[str]:
    from proxybench.experiments.rank_check.run import summary_lines

    shipped = _json(study / "summary.json")
    res = _rank_check_result(study)
    planned, n = res.config.targets, len(res.rows)
    if shipped.get("targets") != n:
        raise EvidenceError(f"{study}: summary.json covers {shipped.get('targets')} targets, targets.csv {n}")
    if planned is not None and n < planned:
        raise EvidenceError(f"{study}: {n} of the {planned} targets asked are in targets.csv: the study is "
                            "unfinished")
    folders = [d for d in (study / "targets").glob("*") if d.name.isdigit()] if (study / "targets").is_dir() else []
    if len(folders) > n:
        raise EvidenceError(f"{study}: holds {len(folders)} targets' episodes but its summary covers {n}: the study "
                            "is running or was extended; export it after it ends")
    differ = _differences(dict(_flatten(shipped)), dict(_flatten(_rank_check_summary(res))), "summary.json")
    if differ:
        raise EvidenceError(f"{study}: {differ[0]}")
    for name in ("summary.json", "targets.csv"):
        shutil.copyfile(study / name, dest / name)
    episodes = _rank_check_episodes(study, res, dest / EPISODES) if folders else 0
    said = [] if episodes else [f"no per-episode table: {study} held no cached episode"]
    c = res.config
    table = _files_table(dest)
    lines = "".join(f"- {line}\n" for line in summary_lines(res))
    command = command or (f"`proxybench rank-check --family {c.family} --targets {c.targets}` with the config in "
                          "summary.json (the study does not record its command line)")
    shipped_eps = (f"{episodes:,} cached episodes in `{EPISODES}` (target, role: target or proxy, agent, episode, "
                   "seed, termination, one column per task metric)" if episodes else "not shipped")
    extra = "".join(f"- {n}\n" for n in [*said, *notes])
    text = f"""# {dest.name}: rank-check (`proxybench rank-check`), {c.family} family

{lines}
- **Command**: {command}
- **Code**: {commit or "not recorded by the study"}.
- **Machine**: {machine or _machine_default()}.
- **Time**: {res.wall_s / 60:.1f} min of wall time in the run that wrote summary.json (summary.json's wall_s).
- **Episodes**: {shipped_eps}.
{extra}
Recompute: `proxybench results rebuild --check` (summary.json from targets.csv through rank-check's own summary
code). Files:

{table}
"""
    (dest / "README.md").write_text(text)
    return said


def export_study(study: Path, name: str, root: Path, *, replace: bool = False, command: str | None = None,
                 commit: str | None = None, machine: str | None = None, notes: tuple[str, ...] = ()) -> Exported:
    """Condense the finished study in ``study`` into ``root/results/NAME/``. Refuses (:class:`EvidenceError`) an
    unfinished study, a validation study whose pre-registration check fails or whose summary.json is not its
    final look, and an existing ``results/NAME`` unless ``replace``. ``command``, ``commit``, ``machine`` and
    ``notes`` go into the run's README.md (a study does not record all of them)."""
    study = Path(study)
    if not _NAME.fullmatch(name):
        raise EvidenceError(f"name {name!r}: use lower-case letters, digits, '_' and '-' (e.g. validate_gym)")
    if not study.is_dir():
        raise EvidenceError(f"{study}: no such study folder")
    results = Path(root) / RESULTS
    final = results / name
    if final.exists() and not replace:
        raise EvidenceError(f"{final} exists; give --replace to overwrite it")
    kind = study_kind(study)
    results.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=results))
    dest = tmp / name
    dest.mkdir()
    try:
        writer = {"validate": _export_validate, "plv": _export_plv, "plv-vs-prpv": _export_choice}.get(
            kind, _export_rank_check)
        said = writer(study, dest, command, commit, machine, list(notes))
        if final.exists():
            shutil.rmtree(final)
        dest.rename(final)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    sizes = {p.relative_to(final).as_posix(): p.stat().st_size for p in sorted(final.rglob("*")) if p.is_file()}
    return Exported(final, sizes, said)


# -- rebuild ----------------------------------------------------------------------------------------------------------

def _runs(root: Path) -> list[tuple[str, Path]]:
    """Every run folder in ``root/results/`` (a hidden one is an export in progress)."""
    results = root / RESULTS
    if not results.is_dir():
        raise EvidenceError(f"{results}: no such folder")
    return [(d.name, d) for d in sorted(results.iterdir()) if d.is_dir() and not d.name.startswith(".")]


def _validate_numbers(name: str, folder: Path, rel: str) -> Rebuilt:
    st = _load_validate(folder, finished=False)
    problems = [f"{name}: {p}" for p in _registration_problems(folder, st)]
    summary = _validate_summary(folder, st)
    dumped = summary.model_dump()
    problems += [f"{name}: {p}" for p in _differences(dict(_flatten(st.shipped)), dict(_flatten(dumped)),
                                                      f"{rel}/summary.json")]
    numbers = {}
    for path, v in _flatten(dumped):
        if not _is_number(v) or path.startswith(_NOT_COMPARED):
            continue
        source = ("criteria.json" if path.startswith(("settings.", "criteria.")) else
                  "summary.json" if path.startswith(("truths.", "wall_s")) else "targets/")
        numbers[f"{name}.{path}"] = Number(v, f"{rel}/{source}")
    return Rebuilt(numbers, problems)


def _rank_check_numbers(name: str, folder: Path, rel: str) -> Rebuilt:
    res = _rank_check_result(folder)
    recomputed = _rank_check_summary(res)
    problems = [f"{name}: {p}" for p in _differences(dict(_flatten(_json(folder / "summary.json"))),
                                                      dict(_flatten(recomputed)), f"{rel}/summary.json")]
    numbers = {}
    for path, v in _flatten(recomputed):
        if _is_number(v):
            source = "summary.json" if path.startswith(("config.", "wall_s", "alpha")) else "targets.csv"
            numbers[f"{name}.{path}"] = Number(v, f"{rel}/{source}")
    for path, v in _rank_check_extras(res).items():
        numbers[f"{name}.{path}"] = Number(v, f"{rel}/targets.csv")
    return Rebuilt(numbers, problems)


def rebuild(root: Path) -> Rebuilt:
    """Every number of every run in ``root/results/``, recomputed through its study's summary code, and what in
    the shipped files disagrees with its recomputation (a broken look log, an edited record or summary)."""
    out = Rebuilt({})
    for name, folder in _runs(Path(root)):
        rel = f"{RESULTS}/{name}"
        try:
            kind = study_kind(folder)
            numbers = {"validate": _validate_numbers, "plv": _plv_numbers, "plv-vs-prpv": _choice_numbers}.get(
                kind, _rank_check_numbers)
            got = numbers(name, folder, rel)
        except EvidenceError as exc:
            out.problems.append(f"{name}: {exc}")
            continue
        out.numbers.update(got.numbers)
        out.problems += got.problems
    return out


def write_numbers(root: Path, numbers: dict[str, Number]) -> Path:
    """``results/numbers.json``: name → value and source file, sorted by name."""
    path = Path(root) / RESULTS / NUMBERS
    doc = {"about": "every number recomputed from the shipped runs in results/ by `proxybench results rebuild`; "
                    "README.md tags a quoted figure with <!-- n:NAME --> (docs/results.md)",
           "numbers": {k: {"value": _as_json(n.value), "source": n.source} for k, n in sorted(numbers.items())}}
    path.write_text(json.dumps(doc, indent=1, ensure_ascii=False) + "\n")
    return path


# -- README's quotes ------------------------------------------------------------------------------------------------

def readme_quotes(text: str) -> tuple[list[Quote], list[str]]:
    """The figures README tags, each with its number's name; and markers that tag fewer figures than names."""
    quotes, problems, start, run = [], [], 0, ""
    for m in _MARKER.finditer(text):
        names = []
        for name in m.group(1).split():
            if not name.startswith("."):
                run = name.partition(".")[0]
            names.append(f"{run}{name}" if name.startswith(".") else name)
        line = text.count("\n", 0, m.start()) + 1
        figures = _FIGURE.findall(re.sub(r"[*_`]", " ", text[start:m.start()]))
        start = m.end()
        if len(figures) < len(names):
            problems.append(f"README.md line {line}: the marker names {len(names)} numbers but only {len(figures)} "
                            "figures precede it")
            continue
        for name, fig in zip(names, figures[len(figures) - len(names):], strict=True):
            base, op, scale = re.split(r"([*/])", name, maxsplit=1) if re.search(r"[*/]", name) else (name, "", "")
            try:
                factor = 1.0 if not op else float(scale) if op == "*" else 1.0 / float(scale)
            except (ValueError, ZeroDivisionError):
                problems.append(f"README.md line {line}: {name!r}: the scale after {op!r} is not a number")
                continue
            quotes.append(Quote(base, fig, line, factor))
    return quotes, problems


def _quote_holds(q: Quote, value: float) -> bool:
    shown = q.text.replace(",", "").replace("−", "-")
    decimals = len(shown.partition(".")[2])
    v = value * q.scale
    if not math.isfinite(v):
        return False
    return abs(v - float(shown)) <= 0.5 * 10.0 ** -decimals * (1 + 1e-9) + 1e-12


def check(root: Path, readme: Path | None = None) -> tuple[Rebuilt, list[str]]:
    """The recomputation, and every difference: a shipped file against its recomputation, a number against
    ``results/numbers.json`` (changed, added, gone), a README quote against the number it is tagged with."""
    root = Path(root)
    got = rebuild(root)
    problems = list(got.problems)
    path = root / RESULTS / NUMBERS
    if not path.is_file():
        problems.append(f"{RESULTS}/{NUMBERS} is missing: run `proxybench results rebuild`")
    else:
        stored = {k: _from_json(v.get("value")) for k, v in (_json(path).get("numbers") or {}).items()}
        for k in sorted({*stored, *got.numbers}):
            if k not in got.numbers:
                problems.append(f"{k}: in {RESULTS}/{NUMBERS} ({_show(stored[k])}) but no longer recomputed")
            elif k not in stored:
                problems.append(f"{k}: recomputed ({_show(got.numbers[k].value)}, from {got.numbers[k].source}) but "
                                f"not in {RESULTS}/{NUMBERS}")
            elif not _same(stored[k], got.numbers[k].value):
                problems.append(f"{k}: {RESULTS}/{NUMBERS} says {_show(stored[k])}, recomputed "
                                f"{_show(got.numbers[k].value)} (from {got.numbers[k].source})")
    readme = readme if readme is not None else root / "README.md"
    if readme.is_file():
        quotes, bad = readme_quotes(readme.read_text())
        problems += bad
        for q in quotes:
            n = got.numbers.get(q.name)
            if n is None:
                problems.append(f"README.md line {q.line}: {q.name} (quoted as {q.text}) is not a recomputed number")
            elif not _quote_holds(q, float(n.value)):
                problems.append(f"README.md line {q.line}: {q.name} is quoted as {q.text} but recomputes to "
                                f"{_show(n.value)}{f' × {q.scale:g}' if q.scale != 1 else ''} (from {n.source})")
    return got, problems

