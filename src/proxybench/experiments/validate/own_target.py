"""``proxybench validate --target …``: the validation study's design on the user's own target (docs/validate.md, "On
your own target").

The family study draws many targets and splits the agents once per target. A user with one target — a recording,
a robot node, a DTPS robot, the reality model — asks "does tuning help on *my* target, and how sure can I be?".
Here the target is fixed and the splits are what varies:

1. every agent runs on the target for E = E1 + E2 episodes, once (through the runner and its cache; a recording
   is read), and every candidate θ (the study's grid and the nominal θ, :func:`run._candidates`) replays all of
   them, likewise;
2. then, with no further episode, S random splits (seeded): the agents into a tuning set A and a held-out set B
   (``tuning_share``), the episode ids into E1 and E2. Each method picks θ from A on E1
   (:func:`~proxybench.usefulness.validation.selection_scores`, :func:`~proxybench.usefulness.validation.pick`) and
   is judged on B on E2 (:func:`~proxybench.usefulness.validation.quality`): tuned − nominal in PRPV/K(K−1)
   (negative: tuning helped);
3. per method: the median over splits, the shares of splits where tuning helped / hurt / tied, a percentile range
   over splits, and an interval that also holds the target's own episode noise: a bootstrap in which each
   replicate draws fresh splits and resamples, with replacement, the episode ids inside each split's E1 and E2.

Splits of one target are not independent samples, so the range over splits is a description of this target and
this pool, not a confidence interval; the bootstrap's is the interval to read (conservative: it also holds the
Monte-Carlo spread of a median over :data:`BOOT_SPLITS` splits).

``settings.json`` is written before the first episode (every choice, the seed, a hash of the code that scores the
splits) and never rewritten: other settings on the folder are refused (``--new-study`` moves the old files aside).
Writes ``own_target.json`` (:class:`OwnTargetSummary`), ``splits.csv`` and ``report.html`` with a histogram of
tuned − nominal over splits.
"""

from __future__ import annotations

import hashlib
import html
import json
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict

from proxybench.experiments.config import ConfigError
from proxybench.experiments.validate.config import PYTHON, ValidateConfig, ValidateSettings, settings_for
from proxybench.experiments.validate.measures import ContinuousPick
from proxybench.targets.base import Target, TargetInfo, TargetRun

__all__ = ["BOOT", "BOOT_SPLITS", "DEFAULT_METHODS", "ONE_TARGET_CONTINUOUS", "PAIRS", "RANGE", "SPLITS",
           "MethodAnswer", "OwnTargetResult", "OwnTargetSettings", "OwnTargetSummary", "SplitRow", "Tables", "answer",
           "evaluate_splits", "kind_words", "pair_name", "run_own_target", "show_own_target", "summarize_pairs",
           "summarize_splits", "write_own_target_report"]

Progress = Callable[[str, int, int], None]

#: random A/B agent × E1/E2 episode splits of the answer
SPLITS = 200
#: bootstrap replicates of the episode-noise interval, and the fresh splits each replicate draws
BOOT = 100
BOOT_SPLITS = 20
#: the percentile range over splits that describes their spread [%]
RANGE = (5.0, 95.0)
#: the methods when ``--method`` is not given: the ones cheap enough for S + BOOT × BOOT_SPLITS picks (the
#: correlation methods recompute every usefulness measure with a bootstrap per candidate, ~0.1 s per pick each)
DEFAULT_METHODS = ("prpv", "eps_prpv", "prob_prpv", "trajectory", "calibration", "nominal")
#: the continuous methods a study on one target runs: ``calibration``'s θ does not depend on the split (two scripted
#: drives on the target, no simulator), so it is measured once and judged on every split's held-out half;
#: ``trajectory_fit`` refits per split (S × 40 replays of every tuning run) and is the family study's
ONE_TARGET_CONTINUOUS = ("calibration",)
#: the paired comparisons the answer reports: PRPV against the competitors that need no ranking (issue 35's primary
#: question, on one target)
PAIRS = (("prpv", "calibration"), ("prpv", "trajectory"))
#: the code that scores the splits, hashed into settings.json
_SCORING = ("experiments/validate/own_target.py", "usefulness/validation.py", "usefulness/calibration.py",
            "experiments/validate/scoring.py")


# -- typed results ------------------------------------------------------------------------------------------------

class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class OwnTargetSettings(_Model):
    """Every choice of a study on one target, written to settings.json before the first episode."""

    target: str
    target_kind: str
    agents: tuple[str, ...]
    tuning_agents: int
    episodes: tuple[int, ...]
    episodes_tune: int
    episodes_eval: int
    seconds: float
    map: str
    candidates: list[dict[str, float]]
    nominal_index: int
    metrics: tuple[str, ...]
    tolerances: dict[str, float]
    methods: tuple[str, ...]
    top_k: int
    n_boot: int
    image_size: tuple[int, int]
    seed: int
    splits: int
    boot: int
    boot_splits: int
    range_percent: tuple[float, float]
    scoring_sha256: str


class MethodAnswer(_Model):
    """One method over the splits: tuned − nominal in held-out PRPV/K(K−1) (negative: tuning helped)."""

    method: str
    splits: int
    median: float
    mean: float
    helped: float
    """share of splits where the method's pick ordered the held-out agents better than the nominal θ"""
    hurt: float
    tied: float
    range_low: float
    """the low end of the percentile range over splits (RANGE): how splits spread, not a confidence interval"""
    range_high: float
    median_low: float
    """95 % bootstrap interval of the median with the target's episodes resampled (and fresh splits)"""
    median_high: float
    mean_low: float
    mean_high: float
    mean_ties: float
    """candidates tied at the method's pick, on average (broken at random)"""


class OwnTargetSummary(_Model):
    """own_target.json: what the target was, every setting, and each method's answer."""

    settings: OwnTargetSettings
    target_kind: str
    """the target's kind once it ran (a robot node says what it is only then; settings.json has it as first seen)"""
    target_label: str
    target_statement: str
    simulated: bool | None
    methods: dict[str, MethodAnswer]
    answer: str
    notes: list[str]
    written: str
    commit: str
    scoring_unchanged: bool
    episodes_run: int
    wall_s: float = 0.0
    versus: dict[str, MethodAnswer] = {}
    """PRPV − each competitor (``prpv-calibration``, ``prpv-trajectory``), paired per split (negative: PRPV better)"""
    calibration: ContinuousPick | None = None
    """the calibration's θ (from its drives on the target: clipped to the grid's range) or why it has none; it is
    the candidate after the grid (``pick`` = len(candidates) in splits.csv)"""


class SplitRow(_Model):
    """One split × method (a row of splits.csv); ``rep`` −1 for the answer's splits, else a bootstrap replicate."""

    split: int
    method: str
    pick: int
    ties: int
    quality_pick: float
    quality_nominal: float
    quality_oracle: float
    tuning_agents: tuple[str, ...]
    e1: tuple[int, ...]
    e2: tuple[int, ...]

    @property
    def delta(self) -> float:
        return self.quality_pick - self.quality_nominal


@dataclass
class OwnTargetResult:
    """The summary and every split's row (the report and the terminal read these only)."""

    summary: OwnTargetSummary
    rows: list[SplitRow]
    settings_sha256: str = ""
    files: list[Path] = field(default_factory=list)


# -- the tables the splits are cut from -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Tables:
    """Every agent × episode on the target and under each candidate, indexed by position: the splits' raw data.

    ``target``: (K, E, M) scores; ``proxy``: (C, K, E, M) the candidates' replays of the same episodes, the grid's
    then (with ``calibrated``) the calibration's θ; ``trajectory``: (C, K, E) mean distance [m] between each recorded
    run and its open-loop replay under the candidate (NaN where the target left no trajectory)."""

    agents: tuple[str, ...]
    episodes: tuple[int, ...]
    target: np.ndarray
    proxy: np.ndarray
    trajectory: np.ndarray
    calibrated: bool = False
    """the last candidate of ``proxy`` is the calibration's θ (off the grid: only ``calibration`` picks it)"""


def _split(rng: np.random.Generator, k: int, e: int, n_a: int, n_e1: int) -> tuple[np.ndarray, ...]:
    agents, eps = rng.permutation(k), rng.permutation(e)
    return np.sort(agents[:n_a]), np.sort(agents[n_a:]), np.sort(eps[:n_e1]), np.sort(eps[n_e1:])


def _table(t: np.ndarray, who: np.ndarray, eps: np.ndarray, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    return {names[i]: t[i][eps] for i in who}


def _one(tab: Tables, s: OwnTargetSettings, higher: tuple[bool, ...], a: np.ndarray, b: np.ndarray, e1: np.ndarray,
         e2: np.ndarray, methods: tuple[str, ...], key: tuple[int, ...]) -> list[tuple[str, int, int, float, float,
                                                                                      float]]:
    """Each method's pick from A on E1 and its quality on B on E2: (method, pick, ties, q_pick, q_nominal, q_oracle)."""
    from proxybench.usefulness.validation import METHODS, pick, quality, selection_scores

    names, n_all = tab.agents, tab.proxy.shape[0]
    n_c = n_all - 1 if tab.calibrated else n_all  # the grid: every method but the calibration picks from it
    target_a, target_b = _table(tab.target, a, e1, names), _table(tab.target, b, e2, names)
    prox_a = [_table(tab.proxy[c], a, e1, names) for c in range(n_c)]
    prox_b = [_table(tab.proxy[c], b, e2, names) for c in range(n_all)]
    q = np.array([quality(p, target_b, higher, k=s.top_k).prpv_norm for p in prox_b])
    oracle = float(np.nanmin(q[:n_c]))
    tol = [s.tolerances[m] for m in s.metrics]
    out = []
    for method in methods:
        if method == "calibration":
            if tab.calibrated:
                out.append((method, n_c, 1, float(q[n_c]), float(q[s.nominal_index]), oracle))
            continue
        if method == "nominal":
            values = np.where(np.arange(n_c) == s.nominal_index, 0.0, 1.0)
        elif method == "trajectory":
            with np.errstate(invalid="ignore"):
                values = np.array([np.nanmean(tab.trajectory[c][np.ix_(a, e1)]) if np.isfinite(
                    tab.trajectory[c][np.ix_(a, e1)]).any() else np.nan for c in range(n_c)])
        else:
            values = selection_scores(method, prox_a, target_a, higher, tolerances=tol, n_boot=s.n_boot,
                                      seed=s.seed + key[-1])
        if not np.isfinite(values).any():
            continue
        index, ties = pick(np.where(np.isfinite(values), values, np.inf),
                           np.random.default_rng([s.seed, *key, METHODS.index(method)]))
        out.append((method, index, ties, float(q[index]), float(q[s.nominal_index]), oracle))
    return out


def _higher(metrics: tuple[str, ...]) -> tuple[bool, ...]:
    from proxybench.tasks.metrics import METRICS

    return tuple(METRICS[m].higher_is_better for m in metrics)


def evaluate_splits(tab: Tables, s: OwnTargetSettings, progress: Progress | None = None
                    ) -> tuple[list[SplitRow], dict[str, np.ndarray]]:
    """The answer's S splits (rows) and the bootstrap: per method, (BOOT, 2) the median and mean of tuned − nominal
    over each replicate's fresh splits, its episodes resampled inside E1 and E2. Runs no episode; the seed fixes
    everything."""
    higher = _higher(s.metrics)
    k, e = len(tab.agents), len(tab.episodes)
    rows: list[SplitRow] = []
    for i in range(s.splits):
        a, b, e1, e2 = _split(np.random.default_rng([s.seed, i, 0x5917]), k, e, s.tuning_agents, s.episodes_tune)
        for method, index, ties, qp, qn, qo in _one(tab, s, higher, a, b, e1, e2, s.methods, (i,)):
            rows.append(SplitRow(split=i, method=method, pick=index, ties=ties, quality_pick=qp, quality_nominal=qn,
                                 quality_oracle=qo, tuning_agents=tuple(tab.agents[j] for j in a),
                                 e1=tuple(tab.episodes[j] for j in e1), e2=tuple(tab.episodes[j] for j in e2)))
        if progress:
            progress("splits", i + 1, s.splits)
    boots: dict[str, list[tuple[float, float]]] = {m: [] for m in (*s.methods, *map(pair_name, PAIRS))}
    for r in range(s.boot):
        rng = np.random.default_rng([s.seed, r, 0xB007])
        deltas: dict[str, list[float]] = {}
        for j in range(s.boot_splits):
            a, b, e1, e2 = _split(rng, k, e, s.tuning_agents, s.episodes_tune)
            e1, e2 = rng.choice(e1, len(e1)), rng.choice(e2, len(e2))  # the target's episodes, resampled
            picked = {}
            for method, _, _, qp, qn, _ in _one(tab, s, higher, a, b, e1, e2, s.methods, (s.splits + r, j)):
                deltas.setdefault(method, []).append(qp - qn)
                picked[method] = qp
            for first, second in PAIRS:
                if first in picked and second in picked:
                    deltas.setdefault(pair_name((first, second)), []).append(picked[first] - picked[second])
        for method, d in deltas.items():
            boots[method].append((float(np.median(d)), float(np.mean(d))))
        if progress:
            progress("bootstrap over the target's episodes", r + 1, s.boot)
    return rows, {m: np.asarray(v, float).reshape(-1, 2) for m, v in boots.items() if v}


def _method_answer(name: str, d: np.ndarray, bt: np.ndarray, ties: float, s: OwnTargetSettings) -> MethodAnswer:
    """The answer over splits of one difference ``d`` (negative: the first did better), with its bootstrap."""
    close = np.isclose(d, 0.0, rtol=0.0, atol=1e-12)
    lo, hi = np.percentile(d, s.range_percent)
    mlo, mhi = np.percentile(bt[:, 0], [2.5, 97.5])
    alo, ahi = np.percentile(bt[:, 1], [2.5, 97.5])
    return MethodAnswer(
        method=name, splits=len(d), median=float(np.median(d)), mean=float(d.mean()),
        helped=float(np.mean((d < 0) & ~close)), hurt=float(np.mean((d > 0) & ~close)), tied=float(close.mean()),
        range_low=float(lo), range_high=float(hi), median_low=float(mlo), median_high=float(mhi),
        mean_low=float(alo), mean_high=float(ahi), mean_ties=ties)


def summarize_splits(rows: list[SplitRow], boots: dict[str, np.ndarray], s: OwnTargetSettings
                     ) -> dict[str, MethodAnswer]:
    """Per method: the median, mean and shares over the answer's splits, their percentile range, and the
    bootstrap's 95 % intervals of the median and the mean."""
    out = {}
    for method in s.methods:
        mine = [r for r in rows if r.method == method]
        if mine:
            out[method] = _method_answer(method, np.array([r.delta for r in mine]),
                                         boots.get(method, np.full((1, 2), np.nan)),
                                         float(np.mean([r.ties for r in mine])), s)
    return out


def pair_name(pair: tuple[str, str]) -> str:
    return f"{pair[0]}-{pair[1]}"


def summarize_pairs(rows: list[SplitRow], boots: dict[str, np.ndarray], s: OwnTargetSettings
                    ) -> dict[str, MethodAnswer]:
    """Per pair of :data:`PAIRS` that both picked: first − second in held-out PRPV/K(K−1) over the splits where both
    picked (negative: the first ordered the held-out agents better), with the same bootstrap (paired: the same
    replicate's splits)."""
    by = {(r.split, r.method): r.quality_pick for r in rows}
    out = {}
    for pair in PAIRS:
        d = np.array([by[(i, pair[0])] - by[(i, pair[1])] for i in range(s.splits)
                      if (i, pair[0]) in by and (i, pair[1]) in by])
        if d.size:
            out[pair_name(pair)] = _method_answer(pair_name(pair), d, boots.get(pair_name(pair),
                                                                               np.full((1, 2), np.nan)), 0.0, s)
    return out


# -- what the target is ---------------------------------------------------------------------------------------------

def kind_words(info: TargetInfo) -> str:
    """The target's kind as the answer names it: recorded (of what), robot node, DTPS robot, reality model; with
    "simulated by another simulator" where the target said so."""
    from proxybench.domain.kinds import DomainKind

    d = info.details
    if info.kind == DomainKind.RECORDED:
        of = {"real": "real robots, as its manifest declares", "reality-model": "proxybench's reality model",
              "simulation": "another simulator", "robot-node": "a robot node", "dtps-robot": "a DTPS robot"}
        return f"recorded ({of.get(d.get('source', ''), d.get('source', '?'))})"
    if info.kind == DomainKind.REALITY_MODEL:
        return "reality model (proxybench's simulated stand-in for a Duckiebot)"
    if d.get("link") == "dtps":
        return "DTPS robot"
    if d.get("simulator"):
        return "robot node, simulated by another simulator"
    return "robot node, a simulator by its own word" if d.get("kind") == "simulation" else "robot node"


def _tag(simulated: bool | None) -> str:
    return {True: "SIMULATED TARGET", False: "REAL ROBOTS (as the target declares)",
            None: "TARGET OF UNKNOWN NATURE"}[simulated]


def answer(summary: OwnTargetSummary) -> str:
    """The answer in a few sentences: the target's nature first, then PRPV's (or the first method's) verdict."""
    s = summary.settings
    head = f"{_tag(summary.simulated)} ({summary.target_kind}): {summary.target_label}."
    tuned = [m for m in s.methods if m != "nominal" and m in summary.methods]
    if not tuned:
        return head + " No method but the nominal θ picked: nothing to compare."
    m = summary.methods["prpv" if "prpv" in tuned else tuned[0]]
    if m.median_high < 0:
        verdict = "tuning helped on this target"
    elif m.median_low > 0:
        verdict = "tuning hurt on this target"
    elif abs(m.median_low) < 1e-12 and abs(m.median_high) < 1e-12:
        verdict = ("on a typical split tuning made no difference (the pick ordered the held-out agents as the "
                   "nominal θ did)")
    else:
        verdict = "this target's episodes do not settle whether tuning helps"
    def eps(n: int, other: str = "") -> str:
        return f"{n} {other}episode{'s' if n != 1 else ''}"

    return (f"{head} Tuning θ with {m.method} on {s.tuning_agents} of {len(s.agents)} agents ({eps(s.episodes_tune)} "
            f"each) and judging it on the other {len(s.agents) - s.tuning_agents} ({eps(s.episodes_eval, 'other ')}"
            f"): tuned − nominal PRPV/K(K−1) median {m.median:+.3f} over {m.splits} splits (helped in "
            f"{m.helped:.0%}, hurt in {m.hurt:.0%}, tied in {m.tied:.0%}; {s.range_percent[0]:g}–"
            f"{s.range_percent[1]:g} % of splits in [{m.range_low:+.3f}, {m.range_high:+.3f}]); with the target's "
            f"episode noise the median lies in [{m.median_low:+.3f}, {m.median_high:+.3f}] and the mean "
            f"{m.mean:+.3f} in [{m.mean_low:+.3f}, {m.mean_high:+.3f}] (95 % bootstrap over episodes): {verdict}. "
            f"{_versus_words(summary)}"
            "One target: this says nothing about other targets, nor about agents outside this pool.")


def _versus_words(summary: OwnTargetSummary) -> str:
    """One sentence per paired comparison: does ranking (PRPV) pick a better θ than the competitor?"""
    out = []
    for name, v in summary.versus.items():
        first, second = name.split("-", 1)
        if v.median_high < 0:
            said = f"{first} did better than {second}"
        elif v.median_low > 0:
            said = f"{second} did better than {first}"
        elif abs(v.median_low) < 1e-12 and abs(v.median_high) < 1e-12:
            said = "on a typical split both ordered the held-out agents alike"
        else:
            said = "not separated"
        out.append(f"{first} − {second}: median {v.median:+.3f} [{v.median_low:+.3f}, {v.median_high:+.3f}] over "
                   f"{v.splits} splits ({first} better in {v.helped:.0%}, worse in {v.hurt:.0%}): {said}. ")
    return "".join(out)


# -- running --------------------------------------------------------------------------------------------------------

def _scoring_hash() -> str:
    import proxybench

    root = Path(proxybench.__file__).parent
    h = hashlib.sha256()
    for rel in _SCORING:
        h.update(rel.encode() + b"\0" + (root / rel).read_bytes())
    return h.hexdigest()


def _refuse_family_fields(cfg: ValidateConfig) -> None:
    """Fields of the family study that mean nothing on one target: an error naming the first one given."""
    for name, why in (("targets", "the study on your own target has one target"),
                      ("draw", "your target's θ is its own; nothing is drawn"),
                      ("draw_seed", "your target's θ is its own; nothing is drawn"),
                      ("per_stratum", "your target's θ is its own; there are no strata to fill"),
                      ("bc_agents", "behaviour-cloned agents are not trained for your target; give them as --agent "
                                    "checkpoints"),
                      ("interim", "a study on one target has no interim look")):
        if name in cfg.model_fields_set and getattr(cfg, name) not in (None, False):
            raise ConfigError(f"{name}: {why}; leave it out with --target")


def _open(cfg: ValidateConfig, robot_nodes: int) -> Target:
    from proxybench.targets.spec import open_target

    return open_target(str(cfg.target), robot_nodes=robot_nodes)


def _agents(cfg: ValidateConfig, target: Target, pool: tuple[str, ...], out: Path) -> list[Any]:
    """The agents' specs: ``--agent``, else the recording's agents, else the family's pool; a recording must hold
    each, and at least 4 are needed (2 to tune, 2 to judge)."""
    from proxybench.experiments.agent_args import AgentArgError, parse_agents

    recorded = target.fixed_agents is not None
    texts = list(cfg.agents) if cfg.agents else (list(target.fixed_agents or []) if recorded else list(pool))
    texts = [t.replace(PYTHON, shlex.quote(sys.executable)) for t in texts]
    try:
        specs = parse_agents(texts, out / "agents")
    except AgentArgError as exc:
        raise ConfigError(f"agents: {exc}" + (" (the recording's agents replay in the proxies: give each as --agent "
                                              "NAME=COMMAND or a zoo name)" if recorded and not cfg.agents else "")
                          ) from None
    if recorded:
        missing = [a.label for a in specs if a.label not in (target.fixed_agents or [])]
        if missing:
            raise ConfigError(f"agents: {', '.join(map(repr, missing))} not in the recording at {cfg.target} (it "
                              f"has {', '.join(target.fixed_agents or [])})")
    if len(specs) < 4:
        raise ConfigError(f"agents: the study on one target needs at least 4 (2 to tune, 2 to judge), got "
                          f"{len(specs)} ({', '.join(a.label for a in specs)})")
    return specs


def _episode_ids(target: Target, n: int, cfg: ValidateConfig) -> list[int]:
    """The first n episode ids: 0 … n−1 on a live target, the recording's first n (it must have them)."""
    manifest = getattr(target, "manifest", None)
    if manifest is None:
        return list(range(n))
    ids = list(manifest.episodes)
    if len(ids) < n:
        raise ConfigError(f"episodes_tune + episodes_eval: {n} episodes per agent asked, the recording at "
                          f"{cfg.target} has {len(ids)} ({', '.join(map(str, ids))}); lower --episodes-tune / "
                          "--episodes-eval")
    return ids[:n]


def _settings(cfg: ValidateConfig, quick: bool, out: Path
              ) -> tuple[OwnTargetSettings, Target, list[Any], ValidateSettings]:
    """Every choice, checked before anything runs or is written (the target opened, its agents and episodes); and
    the family study's settings they came from (the calibration reads its grid)."""
    from proxybench.experiments.validate.run import _candidates

    _refuse_family_fields(cfg)
    base = settings_for(cfg, quick)
    target = _open(cfg, base.robot_nodes)
    seconds, map_name = base.seconds, base.maps[0]
    if target.fixed_seconds is not None:  # a recording fixes its map and length
        if cfg.seconds is not None and abs(cfg.seconds - target.fixed_seconds) > 1e-9:
            raise ConfigError(f"seconds: the recording's episodes last {target.fixed_seconds:g} s, not "
                              f"{cfg.seconds:g}; leave --seconds out")
        if cfg.maps and list(cfg.maps) != [target.fixed_map]:
            raise ConfigError(f"maps: the recording was made on {target.fixed_map}; leave --map out")
        seconds, map_name = float(target.fixed_seconds), str(target.fixed_map)
        base = settings_for(cfg.model_copy(update={"seconds": seconds}), quick)  # tolerances scaled to its length
    specs = _agents(cfg, target, base.agents, out)
    episodes = _episode_ids(target, base.episodes_tune + base.episodes_eval, cfg)
    cands = _candidates(base)
    from proxybench.experiments.proxies import proxy_params

    nominal = proxy_params(tuple(base.image_size))
    nominal_index = next((c for c, th in enumerate(cands)
                          if all(abs(v - float(getattr(nominal, n))) < 1e-9 for n, v in th.items())), None)
    if nominal_index is None:  # the candidates are the study's: it puts the nominal θ among them
        raise ConfigError(f"grid: the nominal θ ({', '.join(f'{n}={getattr(nominal, n)}' for n in base.grid)}) is "
                          "not among the candidates; every method is compared with it")
    methods = base.methods if "methods" in cfg.model_fields_set else DEFAULT_METHODS
    from proxybench.usefulness import validation

    # the grid methods only: a method whose pick is a continuous θ (fitted, or calibrated by scripted drives on a
    # live target) is the family study's to run
    off_grid = [m for m in methods if m in validation.CONTINUOUS and m not in ONE_TARGET_CONTINUOUS]
    if off_grid:
        raise ConfigError(f"methods: {', '.join(off_grid)} refits θ on every split and is not run on one target; "
                          f"give --method among {', '.join(m for m in validation.METHODS if m not in off_grid)}")
    k = len(specs)
    s = OwnTargetSettings(
        target=str(cfg.target), target_kind=kind_words(target.info()), agents=tuple(a.label for a in specs),
        tuning_agents=max(2, min(k - 2, round(k * base.tuning_share))), episodes=tuple(episodes),
        episodes_tune=base.episodes_tune, episodes_eval=base.episodes_eval, seconds=seconds, map=map_name,
        candidates=cands, nominal_index=nominal_index, metrics=base.metrics, tolerances=base.tolerances,
        methods=methods, top_k=base.top_k, n_boot=base.n_boot, image_size=base.image_size, seed=base.seed,
        splits=SPLITS, boot=BOOT, boot_splits=BOOT_SPLITS, range_percent=RANGE, scoring_sha256=_scoring_hash())
    return s, target, specs, base


def _register(out: Path, s: OwnTargetSettings, new_study: bool) -> str:
    """settings.json, written once before the first episode: the same settings resume, others are refused (the
    file stays byte-identical) unless ``new_study`` moves the old files to ``superseded-TIME/``. Its sha256."""
    from proxybench.experiments.reporting import source_commit

    path = out / "settings.json"
    if path.exists():
        try:
            old = json.loads(path.read_text())["settings"]
        except (OSError, ValueError, KeyError, TypeError):
            old = None
        now = s.model_dump(mode="json")
        # the scoring code's hash is compared by the report (it says so), not refused: the episodes stay valid
        differs = next((k for k in now if k != "scoring_sha256" and (old is None or old.get(k) != now[k])), None)
        if differs is None:
            return hashlib.sha256(path.read_bytes()).hexdigest()
        if not new_study:
            said = "unreadable" if old is None else f"{old.get(differs)!r}, this run asks {now[differs]!r}"
            raise ConfigError(f"{differs}: the folder's settings.json says {said}; use a new --out (or --new-study to "
                              f"move the old study to {out}/superseded-TIME/)")
        aside = out / f"superseded-{datetime.now(UTC).strftime('%Y%m%dT%H%M%SZ')}"
        aside.mkdir()
        for name in ("settings.json", "own_target.json", "splits.csv", "report.html", "own_target_splits.png",
                     "own_target_splits.svg"):
            if (out / name).exists():
                (out / name).rename(aside / name)
    out.mkdir(parents=True, exist_ok=True)
    data = json.dumps({"written": datetime.now(UTC).strftime("%Y-%m-%d %H:%M:%S +0000"), "commit": source_commit(),
                       "settings": s.model_dump(mode="json")}, indent=1).encode()
    path.write_bytes(data)
    return hashlib.sha256(data).hexdigest()


def _calibrate(s: OwnTargetSettings, base: ValidateSettings, target: Target, run_dir: Path, backend: Any,
               progress: Progress | None) -> tuple[ContinuousPick | None, int]:
    """The calibration's θ from its scripted drives on the target (None when the study does not run it) and the
    target episodes they took. Clipped to the grid's range: the user's target has no drawn range, and we never
    centre anything on a truth we know."""
    if "calibration" not in s.methods:
        return None, 0
    from proxybench.experiments.validate.run import _calibration

    kw = {"map_name": s.map, "seconds": s.seconds, "seed": s.seed, "metrics": s.metrics,
          "image_size": tuple(s.image_size), "run_dir": run_dir, "backend": backend}
    stage = (lambda name: (lambda _st, d, t: progress(name, d, t))) if progress else (lambda _n: None)
    return _calibration(target, base.model_copy(update={"draw": {}}), kw, stage)


def _replays(s: OwnTargetSettings, specs: list[Any], tgt: TargetRun, run_dir: Path, backend: Any,
             progress: Progress | None, extra: list[dict[str, float]] = ()) -> tuple[np.ndarray, int]:
    """(C, K, E, M) every candidate's replay of every target episode (the grid's, then ``extra`` θ), through the
    runner; and how many ran now."""
    from proxybench.experiments.proxies import proxy_params
    from proxybench.runner.jobs import DomainSpec, Job
    from proxybench.runner.sweep import run_jobs

    by_label = {a.label: a for a in specs}
    pos = {(a, e): (i, j) for i, a in enumerate(s.agents) for j, e in enumerate(s.episodes)}
    jobs = [Job(by_label[e.agent], DomainSpec(f"candidate {c}", proxy_params(tuple(s.image_size), **theta)),
                tgt.map, e.episode, e.seed, tgt.seconds, pose=e.pose, metrics=s.metrics)
            for c, theta in enumerate([*s.candidates, *extra]) for e in tgt.episodes]
    sweep = run_jobs(jobs, run_dir, backend,
                     progress=(lambda d, t, _r: progress("candidates replay the target's episodes", d, t))
                     if progress else None)
    out = np.full((len(s.candidates) + len(extra), len(s.agents), len(s.episodes), len(s.metrics)), np.nan)
    per = len(tgt.episodes)
    for n, (job, res) in enumerate(zip(jobs, sweep.results, strict=True)):
        i, j = pos[(job.agent.label, job.episode)]
        out[n // per, i, j] = [res.scores[m] for m in s.metrics]
    return out, sweep.ran


def _trajectories(s: OwnTargetSettings, tgt: TargetRun, progress: Progress | None) -> np.ndarray:
    """(C, K, E) trajectory matching's distances: each target run replayed open loop under each candidate."""
    from proxybench.experiments.proxies import proxy_params
    from proxybench.runner.replay import replay_runs
    from proxybench.tasks.trajectory import Trajectory
    from proxybench.usefulness.validation import trajectory_error

    out = np.full((len(s.candidates), len(s.agents), len(s.episodes)), np.nan)
    if "trajectory" not in s.methods:
        return out
    runs, where = [], []
    for e in tgt.episodes:
        path = tgt.files.get((e.agent, e.episode))
        if not path:
            continue
        tr = Trajectory.load(path)
        runs.append((tr["t"], np.column_stack([tr["pwm_left"], tr["pwm_right"]]), e.pose, e.seed,
                     np.column_stack([tr["t"], tr["x"], tr["y"]])))
        where.append((s.agents.index(e.agent), s.episodes.index(e.episode)))
    for c, theta in enumerate(s.candidates):
        if runs:
            replays = replay_runs(tgt.map, proxy_params(tuple(s.image_size), **theta),
                                  [r[:4] for r in runs], tgt.seconds)
            for (i, j), rep, r in zip(where, replays, runs, strict=True):
                out[c, i, j] = trajectory_error(rep, r[4])
        if progress:
            progress("trajectory matching: open-loop replays", c + 1, len(s.candidates))
    return out


def run_own_target(cfg: ValidateConfig, out: str | Path, backend: Any = None, progress: Progress | None = None, *,
                   quick: bool = False, splits: int | None = None, boot: int | None = None,
                   boot_splits: int | None = None) -> OwnTargetResult:
    """Run the study on ``cfg.target`` into ``out``: check every choice, write settings.json, run the target's
    episodes and the candidates' replays (cached in ``out/runs``), then the splits. ``splits``, ``boot``,
    ``boot_splits``: other than :data:`SPLITS`, :data:`BOOT`, :data:`BOOT_SPLITS` (from Python only)."""
    from proxybench.experiments.reporting import source_commit
    from proxybench.runner.backends import InlineBackend

    t0 = time.perf_counter()
    out = Path(out)
    if not cfg.target:
        raise ConfigError("target: give the target (DIR, robot:CMD or dtps:HOST[:PORT]/PATH)")
    s, target, specs, base = _settings(cfg, quick, out)
    s = s.model_copy(update={k: v for k, v in (("splits", splits), ("boot", boot), ("boot_splits", boot_splits))
                             if v is not None})
    if min(s.splits, s.boot, s.boot_splits) < 1:
        raise ConfigError("splits, boot, boot_splits: each at least 1")
    settings_sha = _register(out, s, cfg.new_study)
    written = json.loads((out / "settings.json").read_text())
    backend = backend or InlineBackend()
    run_dir = out / "runs"
    tgt = target.run(specs, map_name=s.map, seconds=s.seconds, episodes=list(s.episodes), seed=s.seed,
                     metrics=s.metrics, image_size=tuple(s.image_size), run_dir=run_dir, backend=backend,
                     progress=(lambda _st, d, t: progress("the target's episodes", d, t)) if progress else None)
    missing = [(a, e) for a in s.agents for e in s.episodes
               if not any(x.agent == a and x.episode == e for x in tgt.episodes)]
    if missing:
        raise ConfigError(f"target: no episode {missing[0][1]} of {missing[0][0]} came back ({len(missing)} missing)")
    target_t = np.full((len(s.agents), len(s.episodes), len(s.metrics)), np.nan)
    for a, rows in tgt.results.items():
        for ep, row in zip(tgt.episodes_of(a), rows, strict=True):
            target_t[s.agents.index(a), s.episodes.index(ep.episode)] = row
    calib, drives_ran = _calibrate(s, base, target, run_dir, backend, progress)
    extra = [calib.theta] if calib is not None and calib.theta is not None else []
    proxy, ran = _replays(s, specs, tgt, run_dir, backend, progress, extra=extra)
    trajectory = _trajectories(s, tgt, progress)
    if extra:
        trajectory = np.concatenate([trajectory, np.full((1, *trajectory.shape[1:]), np.nan)])
    tab = Tables(s.agents, s.episodes, target_t, proxy, trajectory, calibrated=bool(extra))
    notes = []
    if calib is not None and calib.theta is None:
        notes.append(f"calibration: {calib.reason}, so it did not pick")
    if "trajectory" in s.methods and not np.isfinite(tab.trajectory).any():
        notes.append("trajectory: the target left no trajectories (wheel commands and poses), so trajectory matching "
                     "did not pick")
    rows, boots = evaluate_splits(tab, s, progress)
    if written["commit"] != source_commit():
        notes.append(f"settings.json was written at commit {written['commit']}; this run is {source_commit()}")
    info = target.info()
    summary = OwnTargetSummary(settings=s, target_kind=kind_words(info), target_label=info.label,
                               target_statement=info.statement, simulated=info.simulated,
                               methods=summarize_splits(rows, boots, s), versus=summarize_pairs(rows, boots, s),
                               answer="",
                               notes=notes, written=written["written"], commit=written["commit"],
                               scoring_unchanged=written["settings"]["scoring_sha256"] == _scoring_hash(),
                               episodes_run=tgt.ran + ran + drives_ran, wall_s=round(time.perf_counter() - t0, 1),
                               calibration=calib)
    summary = summary.model_copy(update={"answer": answer(summary)})
    return OwnTargetResult(summary, rows, settings_sha)


# -- report ---------------------------------------------------------------------------------------------------------

def _csv(result: OwnTargetResult, path: Path) -> Path:
    import csv

    calib = result.summary.calibration
    cands = [*result.summary.settings.candidates, *([calib.theta] if calib is not None and calib.theta else [])]
    names = list(cands[0]) if cands else []
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["split", "method", "pick", *(f"pick_{n}" for n in names), "ties", "prpv_norm_pick",
                    "prpv_norm_nominal", "prpv_norm_oracle", "tuned_minus_nominal", "tuning_agents", "e1", "e2"])
        for r in result.rows:
            w.writerow([r.split, r.method, r.pick, *(cands[r.pick][n] for n in names), r.ties, f"{r.quality_pick:.6g}",
                        f"{r.quality_nominal:.6g}", f"{r.quality_oracle:.6g}", f"{r.delta:.6g}",
                        ";".join(r.tuning_agents), ";".join(map(str, r.e1)), ";".join(map(str, r.e2))])
    return path


def _histogram(result: OwnTargetResult, out: Path) -> Path:
    from proxybench.experiments.reporting import pyplot, save_figure

    plt = pyplot()
    methods = [m for m in result.summary.methods if m != "nominal"] or list(result.summary.methods)
    fig, axes = plt.subplots(len(methods), 1, figsize=(7, 1.9 * len(methods) + 0.6), sharex=True, squeeze=False)
    deltas = {m: np.array([r.delta for r in result.rows if r.method == m]) for m in methods}
    allv = np.concatenate([d for d in deltas.values() if d.size]) if deltas else np.zeros(1)
    lo, hi = float(min(allv.min(), -0.01)), float(max(allv.max(), 0.01))
    bins = np.linspace(lo, hi, 31)
    for ax, m in zip(axes[:, 0], methods, strict=True):
        a = result.summary.methods[m]
        ax.hist(deltas[m], bins=bins, color="#4c72b0" if m == "prpv" else "#8c8c8c")
        ax.axvline(0.0, color="k", lw=0.8)
        ax.axvline(a.median, color="#c44e52", lw=1.5)
        ax.axvspan(a.median_low, a.median_high, color="#c44e52", alpha=0.15)
        ax.axvline(a.mean, color="#c44e52", lw=1.0, ls="--")
        ax.set_ylabel(f"{m}\nsplits")
    axes[-1, 0].set_xlabel("tuned − nominal, held-out PRPV/K(K−1) (left of 0: tuning helped)")
    fig.suptitle("Over splits; red: the median (solid, its 95 % episode bootstrap shaded) and the mean (dashed)",
                 fontsize=9)
    fig.tight_layout()
    return save_figure(fig, out / "own_target_splits.png")


def write_own_target_report(result: OwnTargetResult, out: str | Path, *, wall: float = 0.0) -> list[Path]:
    """own_target.json, splits.csv, the histogram and a self-contained report.html (from the result alone)."""
    from proxybench.experiments.reporting import html_img, html_table

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summary = result.summary.model_copy(update={"wall_s": round(wall, 1)}) if wall else result.summary
    js = out / "own_target.json"
    js.write_text(summary.model_dump_json(indent=1))
    csv_path = _csv(result, out / "splits.csv")
    fig = _histogram(result, out)
    s = summary.settings
    colour = {True: "#fff4e5", False: "#e8f5e9", None: "#fffde7"}[summary.simulated]
    rows = [(m, a.splits, f"{a.median:+.4f}", f"[{a.median_low:+.4f}, {a.median_high:+.4f}]", f"{a.mean:+.4f}",
             f"[{a.mean_low:+.4f}, {a.mean_high:+.4f}]", f"{a.helped:.0%} / {a.hurt:.0%} / {a.tied:.0%}",
             f"[{a.range_low:+.4f}, {a.range_high:+.4f}]", f"{a.mean_ties:.1f}") for m, a in summary.methods.items()]
    rows += [(f"{m.replace('-', ' − ')} (paired)", a.splits, f"{a.median:+.4f}", f"[{a.median_low:+.4f}, "
              f"{a.median_high:+.4f}]", f"{a.mean:+.4f}", f"[{a.mean_low:+.4f}, {a.mean_high:+.4f}]",
              f"{a.helped:.0%} / {a.hurt:.0%} / {a.tied:.0%}", f"[{a.range_low:+.4f}, {a.range_high:+.4f}]", "")
             for m, a in summary.versus.items()]
    calib = summary.calibration
    calib_words = ("" if calib is None else "Calibration (two scripted drives on the target, no simulator): " + (
        "θ {" + ", ".join(f"{k}={v:g}" for k, v in calib.theta.items()) + "} from the measured {" +
        ", ".join(f"{k}={v:.4g}" for k, v in calib.estimate.items()) + "} (clipped to the grid's range)."
        if calib.theta else f"not applicable: {calib.reason}."))
    cands = ", ".join(("nominal " if c == s.nominal_index else "") + "{" + ", ".join(
        f"{k}={v:g}" for k, v in th.items()) + "}" for c, th in enumerate(s.candidates))
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>validate on one target</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:2em auto}}td,th{{padding:.2em .6em;border-bottom:1px solid
#ddd;text-align:right}}</style></head><body>
<h1>Does tuning help on this target?</h1>
<div style="background:{colour};border:1px solid #ccc;padding:.6em 1em"><b>{_tag(summary.simulated)}</b>
({html.escape(summary.target_kind)}). {html.escape(summary.target_statement)}</div>
<p><b>{html.escape(summary.answer)}</b></p>
{"".join(f"<p><i>{html.escape(n)}</i></p>" for n in summary.notes)}
<h2>Every method against the nominal θ</h2>
<p>Tuned − nominal in PRPV/K(K−1) of the held-out agents on the held-out episodes (negative: tuning helped); the
rows marked "paired" are PRPV's pick against a competitor's on the same splits (negative: PRPV better). Over
{s.splits} random splits of the agents ({s.tuning_agents} tune, {len(s.agents) - s.tuning_agents} judge) and of the
episodes ({s.episodes_tune} tune, {s.episodes_eval} judge). The range over splits describes how the answer moves
with the split; it is not a confidence interval (splits share the same episodes). The 95 % intervals come from
{s.boot} bootstrap replicates, each of {s.boot_splits} fresh splits with the episode ids resampled inside E1 and
E2: they hold the target's episode noise.</p>
{html_table(("method", "splits", "median", "median 95 % (episodes)", "mean", "mean 95 % (episodes)",
             "helped / hurt / tied", f"{s.range_percent[0]:g}–{s.range_percent[1]:g} % of splits", "ties at pick"),
            rows)}
{html_img(fig, "tuned minus nominal over splits")}
<h2>Settings (settings.json, written {html.escape(summary.written)} at commit {html.escape(summary.commit)})</h2>
<p>Agents: {html.escape(", ".join(s.agents))}. Episodes: {html.escape(", ".join(map(str, s.episodes)))} of
{s.seconds:g} s on {html.escape(s.map)}. Candidates: {html.escape(cands)}. Metrics: {html.escape(", ".join(s.metrics))}.
{html.escape(calib_words)}
Seed {s.seed}. Scoring code {"unchanged since settings.json" if summary.scoring_unchanged else
"<b>CHANGED since settings.json was written</b>"}. {summary.episodes_run} episodes ran for this report.</p>
</body></html>"""
    page_path = out / "report.html"
    page_path.write_text(page)
    return [js, csv_path, fig, page_path]


def show_own_target(result: OwnTargetResult, console: Any, *, wall: float = 0.0) -> None:
    """The terminal: the answer, one line per method, what ran."""
    summary = result.summary
    for note in summary.notes:
        console.print(note, highlight=False, markup=False)
    console.print(summary.answer, highlight=False, markup=False)
    for m, a in [*summary.methods.items(), *summary.versus.items()]:
        console.print(f"  {m:>16}: median {a.median:+.4f} [{a.median_low:+.4f}, {a.median_high:+.4f}]  helped "
                      f"{a.helped:4.0%}  hurt {a.hurt:4.0%}  tied {a.tied:4.0%}  splits in [{a.range_low:+.4f}, "
                      f"{a.range_high:+.4f}]", highlight=False, markup=False)
    if not summary.scoring_unchanged:
        console.print("the scoring code changed since settings.json was written", style="bold red", highlight=False,
                      markup=False)
    console.print(f"{summary.episodes_run} episodes run now; wall {wall:.0f} s; settings.json sha256 "
                  f"{result.settings_sha256}", highlight=False, markup=False)
