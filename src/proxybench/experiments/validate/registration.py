"""The validation study's pre-registration, tamper-evident (docs/validate.md, "What the pre-registration
guarantees").

- ``criteria.json`` is written once, before the first episode, and never rewritten: a run on a folder whose
  criteria hold other settings is refused (:func:`open_study`); ``--new-study`` moves the old study aside first.
- The targets' θ come from a seed kept in ``secret/``; a study whose secret is gone stops, it never draws anew.
- ``looks.jsonl`` is a hash chain: its first line (the registration) holds the sha256 of ``criteria.json``, each
  later line the sha256 of the line before it and its own sha256; a line is added for every finished target (the
  sha256 of its record) and for every look at the results (interim or final: the targets finished and the sha256
  of the summary).
- :func:`check_registration` is what every report runs: the chain, the records against the chain, the scoring
  code against the criteria's hash (:func:`scoring_hash`: every module scoring touches, from the files' bytes),
  the criteria's minimum detectable effect against their settings, and the criteria's time against the oldest
  cached episode. What it finds, the report says first, and the command exits non-zero.

Everything here lives in the study's folder: whoever can rewrite every file (and recompute every hash) can forge
a study. The chain makes an edit of one file visible; publishing the sha256 of ``criteria.json`` (printed when
the study is registered) or the log's last line anchors the study outside the folder.
"""

from __future__ import annotations

import ast
import hashlib
import json
import secrets
import time
from pathlib import Path
from typing import Any

from proxybench.experiments.config import ConfigError
from proxybench.experiments.validate.config import ValidateConfig, ValidateSettings

__all__ = ["CRITERIA", "LOOKS", "append_look", "check_registration", "draw_seed", "open_study", "read_looks",
           "record_target", "registered_rule", "scoring_files", "scoring_hash", "summary_sha256", "write_criteria"]

CRITERIA = "criteria.json"
LOOKS = "looks.jsonl"
SECRET = "secret"
#: what a study writes in its folder: ``--new-study`` moves these aside (the agents' checkpoints stay)
STUDY_FILES = (CRITERIA, LOOKS, SECRET, "targets", "runs", "summary.json", "targets.csv", "report.html",
               "vs_nominal.png", "vs_nominal.svg", "regrets.png", "regrets.svg")
#: the modules whose code scores the study; with every module of :data:`SCORING_PACKAGES` they import (at any
#: depth, imports inside functions too) they are what ``criteria.json`` hashes
SCORING_ROOTS = ("proxybench.experiments.validate.scoring", "proxybench.experiments.validate.measures")
#: the measures (usefulness metrics, intervals, the validation measures) and the task metrics
SCORING_PACKAGES = ("proxybench.usefulness.", "proxybench.tasks.")
#: file times are compared with a little slack (file systems store them coarsely)
_SLACK_S = 1.0


def _sha(data: bytes | str) -> str:
    return hashlib.sha256(data.encode() if isinstance(data, str) else data).hexdigest()


def _now() -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S %z")


# -- the code that scores ----------------------------------------------------------------------------------------

def _module_file(root: Path, name: str) -> Path | None:
    p = root.joinpath(*name.split(".")[1:])
    for f in (p.with_suffix(".py"), p / "__init__.py"):
        if f.is_file():
            return f
    return None


def _imports(path: Path) -> set[str]:
    """proxybench modules (and ``module.name`` guesses, which may be modules) that ``path`` imports anywhere."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_bytes())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("proxybench"):
            out |= {node.module, *(f"{node.module}.{a.name}" for a in node.names)}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("proxybench")}
    return out


def scoring_files() -> dict[str, Path]:
    """Every file of the code that scores the study, by its path in the package (``usefulness/validation.py``):
    :data:`SCORING_ROOTS` and the modules of :data:`SCORING_PACKAGES` they import, at any depth."""
    import proxybench

    root = Path(proxybench.__file__).parent
    found: dict[str, Path] = {}
    todo = list(SCORING_ROOTS)
    while todo:
        name = todo.pop()
        path = _module_file(root, name)
        if path is None or (name not in SCORING_ROOTS and not name.startswith(SCORING_PACKAGES)):
            continue
        rel = path.relative_to(root).as_posix()
        if rel not in found:
            found[rel] = path
            todo.extend(_imports(path))
    return dict(sorted(found.items()))


def scoring_hash() -> dict[str, str]:
    """sha256 of each file of the scoring code (:func:`scoring_files`), from its bytes."""
    return {rel: _sha(path.read_bytes()) for rel, path in scoring_files().items()}


# -- the criteria and the secret ---------------------------------------------------------------------------------

def draw_seed(cfg: ValidateConfig, out: Path, *, create: bool) -> int:
    """The seed of the targets' θ: the config's, else the one kept in ``out/secret/`` (mode 600); drawn and kept
    there only when ``create`` (a study being registered). A study whose secret is gone cannot go on."""
    if cfg.draw_seed is not None:
        return cfg.draw_seed
    path = out / SECRET / "draw_seed"
    if path.is_file():
        try:
            return int(path.read_text())
        except ValueError:
            raise ConfigError(f"{path}: not a seed (damaged or edited); the study cannot go on") from None
    if not create:
        raise ConfigError(f"{path} is missing: the study's hidden draw cannot be recovered and is never drawn anew; "
                          f"restore {out / SECRET} (or give --draw-seed), or start a new study (a new --out, or "
                          "--new-study)")
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    seed = secrets.randbits(48)
    path.write_text(str(seed))
    path.chmod(0o600)
    return seed


def _short(value: Any) -> str:
    text = json.dumps(value, ensure_ascii=False)
    return text if len(text) <= 60 else text[:57] + "…"


def settings_differ(written: dict[str, Any], now: dict[str, Any]) -> str | None:
    """The first setting in which ``now`` differs from the criteria's (``written``), in words; None if none."""
    keys = [k for k in (*now, *(k for k in written if k not in now)) if written.get(k) != now.get(k)]
    if not keys:
        return None
    k = keys[0]
    more = f" (and {', '.join(keys[1:])})" if keys[1:] else ""
    return f"{k}: the folder's criteria say {_short(written.get(k))}, this run asks {_short(now.get(k))}{more}"


def _read_criteria(out: Path) -> dict[str, Any] | None:
    path = out / CRITERIA
    if not path.exists():
        return None
    try:
        doc = json.loads(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: unreadable ({exc.__class__.__name__}): the study's criteria are damaged; "
                          "use a new --out") from None
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: not a criteria file; use a new --out")
    return doc


def _supersede(out: Path) -> Path | None:
    """``--new-study``: move the study in ``out`` (criteria, log, secret, targets, runs, report) into
    ``out/superseded-TIME/``; None when there was none."""
    names = [n for n in STUDY_FILES if (out / n).exists()]
    if not names:
        return None
    stamp = time.strftime("%Y%m%d-%H%M%S")
    dest, i = out / f"superseded-{stamp}", 1
    while dest.exists():
        dest, i = out / f"superseded-{stamp}-{i}", i + 1
    dest.mkdir()
    for n in names:
        (out / n).rename(dest / n)
    return dest


def registered_rule(cfg: ValidateConfig, s: ValidateSettings, out: Path) -> ValidateSettings:
    """``s`` with the multiplicity rule of the study already in ``out`` when ``--multiplicity`` is not given: a
    study registered before the rule existed (its criteria without ``multiplicity``) resumes, and is looked at,
    uncorrected as registered, instead of being refused for a setting its user never chose."""
    criteria = _read_criteria(out) if cfg.multiplicity is None else None
    primary = ((criteria or {}).get("settings") or {}).get("primary")
    if not isinstance(primary, dict) or "multiplicity" in primary or s.primary.multiplicity is None:
        return s
    return s.model_copy(update={"primary": s.primary.model_copy(update={"multiplicity": None})})


def open_study(cfg: ValidateConfig, s: ValidateSettings, out: Path, *, interim: bool = False
               ) -> tuple[dict[str, Any], int, list[str]]:
    """The study in ``out`` for settings ``s``: its criteria, its draw seed, and notes. Registers a new one (the
    secret, ``criteria.json`` and the log's first line) in a folder without one; resumes one with the same
    settings; refuses (:class:`ConfigError`, one line) other settings, a missing secret, or a look
    (``interim``) at a folder without a study. The criteria are never rewritten."""
    notes = []
    if cfg.new_study:
        if interim:
            raise ConfigError("--new-study starts a study and --interim looks at one: give one of them")
        moved = _supersede(out)
        if moved is not None:
            notes.append(f"the previous study in {out} was moved to {moved}")
    criteria = _read_criteria(out)
    if criteria is None:
        if interim:
            raise ConfigError(f"{out / CRITERIA}: no study to look at (no criteria); run it first")
        left = [n for n in (LOOKS, "targets") if (out / n).exists()]
        if left:
            raise ConfigError(f"{out}: holds a study's {' and '.join(left)} but no {CRITERIA} (its pre-registration "
                              "is gone); use a new --out (or --new-study to move what is there aside)")
        out.mkdir(parents=True, exist_ok=True)
        seed = draw_seed(cfg, out, create=True)
        criteria = write_criteria(s, seed, out)
        notes.append(f"registered: {out / CRITERIA} sha256 {_sha((out / CRITERIA).read_bytes())} (publish it to "
                     "anchor the study outside its folder)")
        return criteria, seed, notes
    diff = settings_differ(criteria.get("settings") or {}, s.model_dump(mode="json"))
    if diff:
        advice = ("an interim look takes the options the study was started with" if interim else
                  "use a new --out (or --new-study to start a new study in this folder, the old one kept in "
                  "superseded-TIME/)")
        raise ConfigError(f"{out / CRITERIA}: {diff}; {advice}")
    seed = draw_seed(cfg, out, create=False)
    if _sha(str(seed)) != criteria.get("draw_seed_sha256"):
        where = "--draw-seed" if cfg.draw_seed is not None else out / SECRET
        raise ConfigError(f"{out / CRITERIA}: the draw seed ({where}) is not the one the criteria registered; the "
                          "study cannot go on")
    return criteria, seed, notes


def write_criteria(s: ValidateSettings, seed: int, out: Path) -> dict[str, Any]:
    """``criteria.json`` (endpoints, test, minimum detectable effect, commit and scoring-code hash, the settings, and
    only a hash of the draw seed), and the log's first line; refuses to replace an existing file."""
    from proxybench.experiments.reporting import source_commit
    from proxybench.usefulness.validation import minimum_detectable_effect

    n = s.targets
    doc = {
        "written": _now(), "written_unix": round(time.time(), 3), "commit": source_commit(),
        "scoring_sha256": scoring_hash(), "draw_seed_sha256": _sha(str(seed)), "settings": s.model_dump(mode="json"),
        "unit": "the target (each with its own episode seeds and tuning/held-out split of the agents)",
        "primary_endpoint": "regret of the picked θ on the held-out agents B over fresh target episodes E2: "
                            "PRPV/K(K−1) of the pick minus that of the oracle θ (the candidate lowest on it in "
                            "hindsight)",
        "secondary_endpoints": ["regret in 1 − Kendall τ_b (first metric)", "regret of picking the top agent (first "
                                "metric, its unit)", f"regret of picking the top {s.top_k}", "hit rate: the pick "
                                "within one grid step of the oracle, beside the nominal pick's"],
        "primary_comparison": (f"PRPV's pick against {', '.join(s.primary.comparisons)} in the pick's quality on the "
                               "held-out agents, per pre-declared stratum (settings.primary: the strata, margin, "
                               "assumed SD and the targets each needs)"),
        "test": s.primary.test,
        "secondary_comparison": "PRPV's regret minus the nominal θ's, per target: a one-sided Wilcoxon signed-rank "
                                f"test (alpha {s.alpha}), a paired t-test and a percentile bootstrap interval beside "
                                "it; every other method against the nominal θ the same way (descriptive, no "
                                "multiplicity correction)",
        "minimum_detectable_effect": {"d_z": minimum_detectable_effect(n, s.alpha, s.power), "targets": n,
                                      "power": s.power, "meaning": "mean paired difference in standard deviations "
                                      "of the differences a one-sided paired t-test detects with that power"},
        "decision": s.primary.decision,
        "interim_looks": "logged in looks.jsonl; they show no target's θ and decide nothing",
    }
    with (out / CRITERIA).open("x") as f:  # never over an existing file
        f.write(json.dumps(doc, indent=1))
    (out / LOOKS).unlink(missing_ok=True)  # none can be there (open_study refuses it): the chain starts here
    _append(out, {"look": "registered", "targets": 0})
    return doc


# -- the log of looks ---------------------------------------------------------------------------------------------

def _seal(body: dict[str, Any]) -> str:
    """A log line: ``body`` (ending in prev_sha256) and the sha256 of that JSON text."""
    text = json.dumps(body)
    return json.dumps({**body, "sha256": _sha(text)})


def _append(out: Path, fields: dict[str, Any]) -> str:
    """Append one line to the log, chained to the last line (or to criteria.json's bytes); its sha256."""
    import fcntl

    with (out / LOOKS).open("a+") as f:
        fcntl.flock(f, fcntl.LOCK_EX)  # a look taken while the study runs appends beside it, never between
        f.seek(0)
        text = f.read()
        lines = text.splitlines()
        prev = _sha(lines[-1]) if lines else _sha((out / CRITERIA).read_bytes())
        line = _seal({"time": _now(), **fields, "prev_sha256": prev})
        f.write(("\n" if text and not text.endswith("\n") else "") + line + "\n")
        f.flush()
    return _sha(line)


def read_looks(out: Path) -> tuple[list[dict[str, Any]], list[str]]:
    """The log's lines up to the first that fails, and what failed (empty: the chain holds, from criteria.json's
    bytes to the last line)."""
    path = out / LOOKS
    if not path.exists():
        return [], [f"{LOOKS} is missing: the study's registration and looks cannot be checked"]
    prev = _sha((out / CRITERIA).read_bytes())
    entries: list[dict[str, Any]] = []
    for i, line in enumerate(path.read_text().splitlines(), 1):
        try:
            entry = json.loads(line)
            body = {k: v for k, v in entry.items() if k != "sha256"}
            sealed = entry["sha256"] == _sha(json.dumps(body))
        except (ValueError, TypeError, KeyError, AttributeError):
            return entries, [f"{LOOKS} line {i} is not a log record (edited or damaged): the chain is broken"]
        if entry.get("prev_sha256") != prev:
            what = (f"{CRITERIA} (the criteria were changed after they were registered)" if i == 1 else
                    f"line {i - 1} (a line was edited, removed or inserted)")
            return entries, [f"{LOOKS} line {i} does not chain to {what}: the chain is broken"]
        if not sealed:
            return entries, [f"{LOOKS} line {i} was edited (its sha256 does not match it): the chain is broken"]
        if i == 1 and entry.get("look") != "registered":
            return entries, [f"{LOOKS} line 1 is not the registration: the chain is broken"]
        entries.append(entry)
        prev = _sha(line)
    if not entries:
        return entries, [f"{LOOKS} is empty: the study's registration cannot be checked"]
    return entries, []


def record_target(out: Path, k: int, record_bytes: bytes, finished: int) -> None:
    """Log a finished target: its index and the sha256 of its record file."""
    _append(out, {"look": "target", "targets": finished, "target": k, "record_sha256": _sha(record_bytes)})


def logged_records(entries: list[dict[str, Any]]) -> dict[int, str]:
    """Per target index, the sha256 of the record the log holds last."""
    return {int(e["target"]): str(e["record_sha256"]) for e in entries if e.get("look") == "target"}


def summary_sha256(summary: Any) -> str:
    """sha256 of a summary's JSON (``summary.json`` without its wall time)."""
    return _sha(json.dumps(summary.model_dump(mode="json", exclude={"wall_s"}), sort_keys=True, default=float))


def append_look(out: Path, summary: Any) -> str:
    """Log a look at the results (``interim`` or ``final``); the sha256 of its line."""
    return _append(out, {"look": "interim" if summary.interim else "final", "targets": summary.targets,
                         "summary_sha256": summary_sha256(summary)})


# -- what every report checks --------------------------------------------------------------------------------------

def _criteria_time(criteria: dict[str, Any]) -> float | None:
    if isinstance(criteria.get("written_unix"), int | float):
        return float(criteria["written_unix"])
    from datetime import datetime

    try:
        return datetime.strptime(str(criteria.get("written")), "%Y-%m-%d %H:%M:%S %z").timestamp()
    except ValueError:
        return None


def _oldest_episode(out: Path) -> float | None:
    runs = out / "runs"
    times = [p.stat().st_mtime for p in runs.rglob("*.json") if p.parent.name == "episodes"] if runs.is_dir() else []
    return min(times) if times else None


def check_registration(out: Path, s: ValidateSettings, criteria: dict[str, Any],
                       records: dict[int, bytes]) -> tuple[list[str], bool]:
    """What a report must say before its numbers (empty: the pre-registration holds), and whether the scoring code
    is the one the criteria hashed. ``records``: the bytes of each target record the summary uses, by index."""
    from proxybench.usefulness.validation import minimum_detectable_effect

    problems = []
    written, now = criteria.get("scoring_sha256") or {}, scoring_hash()
    changed = sorted(f for f in {*written, *now} if written.get(f) != now.get(f))
    if changed:
        problems.append(f"the scoring code differs from the code {CRITERIA} hashed ({', '.join(changed)})")
    mde = criteria.get("minimum_detectable_effect") or {}
    expect = minimum_detectable_effect(s.targets, s.alpha, s.power)
    try:
        same = abs(float(mde.get("d_z")) - expect) < 1e-9 and mde.get("targets") == s.targets
    except (TypeError, ValueError):
        same = False
    if not same:
        problems.append(f"{CRITERIA}'s minimum detectable effect ({_short(mde.get('d_z'))}) is not the one its "
                        f"settings give ({expect:.4f}): the file was edited")
    entries, broken = read_looks(out)
    problems += broken
    logged = logged_records(entries)
    for k, data in sorted(records.items()) if not broken else ():  # a broken chain: no entry past it is trusted
        if logged.get(k) != _sha(data):
            problems.append(f"targets/{k:03d}.json is not the record {LOOKS} holds for target {k} (edited after it "
                            "was scored)" if k in logged else f"targets/{k:03d}.json was never logged in {LOOKS}")
    scored: dict[int, set[str]] = {}
    for e in entries:
        if e.get("look") == "target":
            scored.setdefault(int(e["target"]), set()).add(str(e["record_sha256"]))
    twice = sorted(k for k, shas in scored.items() if len(shas) > 1)
    if twice:
        problems.append(f"{LOOKS}: target(s) {', '.join(map(str, twice))} scored more than once with different "
                        "results (a record was edited, or the code or the data changed during the study)")
    t_criteria, oldest = _criteria_time(criteria), _oldest_episode(out)
    if t_criteria is None:
        problems.append(f"{CRITERIA}: its time is unreadable (edited)")
    elif oldest is not None and oldest < t_criteria - _SLACK_S:
        problems.append(f"{CRITERIA} (written {criteria.get('written')}) is newer than cached episodes in runs/ (the "
                        f"oldest from {time.strftime('%Y-%m-%d %H:%M:%S %z', time.localtime(oldest))}): the criteria "
                        "were written after data existed")
    return problems, not changed
