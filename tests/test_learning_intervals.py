"""PLV you can trust: the "reach and stay above P" rule, the bootstrap over seeds, and the ladder's stopping rule.

Every expected number here is computed by hand in the comments.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from proxybench.usefulness.plv import settled_rung
from proxybench.usefulness.plv_intervals import Curve, Interval, curves_from_runs, mean_band, plv_bootstrap


def test_settled_rung_needs_the_score_to_stay_above():
    ns, thr = [0, 250, 500, 1000, 2000], 10.0
    assert settled_rung(ns, [11, 9, 11, 12, 13], thr, confirm=2) == 500  # 250 dips below: start after it
    assert settled_rung(ns, [11, 12, 13, 12, 11], thr, confirm=2) == 0  # never below: zero-shot is enough
    assert settled_rung(ns, [11, 12, 13, 12, 9], thr, confirm=0) is None  # falls below at the last rung tried
    assert settled_rung([0, 250, 500], [9, 11, 12], thr, confirm=2) is None  # 250 has only one rung after it
    assert settled_rung([0, 250, 500], [9, 11, 12], thr, confirm=2, through_end=True) == 250  # ladder ended
    assert settled_rung([500, 250, 0], [12, 11, 9], thr, confirm=1) == 250  # order of the lists does not matter
    assert settled_rung([0, 250, 500], [9, float("nan"), 12], thr, confirm=0) == 500  # NaN counts as below
    assert settled_rung([], [], thr) is None
    with pytest.raises(ValueError, match="confirm"):
        settled_rung([1], [1], 0.0, confirm=-1)


def _target() -> Curve:
    # two seeds, both 10 at 100 and 20 at 200: P = 0.95 · 20 = 19 in every replicate, |D_target| = 200
    return Curve(np.array([100.0, 200.0]), (0, 1), np.array([[10.0, 20.0], [10.0, 20.0]]), through_end=True)


def test_bootstrap_over_seeds_redoes_the_plv_in_each_replicate():
    # zero-shot 19.2 / 18.6 (mean 18.9 < 19): the point estimate settles at rung 100, PLV 200 − 100 = 100.
    # Replicates draw seeds (0,0) w.p. 1/4 → zero-shot 19.2 ≥ 19 → PLV 200; otherwise mean ≤ 18.9 → PLV 100.
    proxy = Curve(np.array([0.0, 100.0, 200.0]), (0, 1), np.array([[19.2, 19.5, 19.5], [18.6, 19.5, 19.5]]),
                  through_end=True)
    iv = plv_bootstrap(_target(), {"p": proxy}, tolerance=0.05, confirm=1, replicates=4000, seed=1)
    assert iv.reference == Interval(19.0, 19.0, 19.0) and iv.target_needed == Interval(200, 200.0, 200.0)
    assert iv.plv["p"] == Interval(100.0, 100.0, 200.0) and iv.needed["p"] == Interval(100, 0.0, 100.0)
    assert iv.reduction["p"].label("{:.0f} %", scale=100.0) == "50 % [50 %, 100 %]"
    assert iv.reached["p"] == 1.0 and iv.paired["p"]


def test_a_proxy_that_settles_for_one_seed_only_gets_not_reached_as_an_interval_end():
    # seed 0 stays at 19.5 ≥ 19, seed 1 at 15: only replicates (0,0) (1/4) settle, at rung 100 → PLV 100.
    proxy = Curve(np.array([0.0, 100.0, 200.0]), (0, 1), np.array([[5.0, 19.5, 19.5], [5.0, 15.0, 15.0]]),
                  through_end=True)
    iv = plv_bootstrap(_target(), {"p": proxy}, tolerance=0.05, confirm=1, replicates=4000, seed=2)
    assert iv.plv["p"] == Interval(None, None, 100.0)
    assert iv.plv["p"].label() == "not reached [not reached, 100]"
    assert iv.reached["p"] == pytest.approx(0.25, abs=0.03)


def test_unpaired_seeds_are_resampled_independently():
    proxy = Curve(np.array([0.0, 100.0]), (7, 8), np.array([[19.5, 19.5], [19.5, 19.5]]), through_end=True)
    iv = plv_bootstrap(_target(), {"p": proxy}, tolerance=0.05, confirm=1, replicates=500)
    assert not iv.paired["p"] and iv.plv["p"] == Interval(200.0, 200.0, 200.0)


def test_mean_band_is_the_seed_range_for_three_seeds_and_a_point_for_one():
    # all three draws equal the minimum with probability 1/27 ≈ 3.7 % > 2.5 %: the band's ends are min and max
    assert mean_band(np.array([-9.5, 9.9, 0.0])) == (pytest.approx(0.1333, abs=1e-4), -9.5, 9.9)
    assert mean_band(np.array([4.0])) == (4.0, 4.0, 4.0)


def test_curves_from_runs_keeps_seeds_present_on_every_rung_and_adds_the_zero_shot():
    runs = [{"arm": "p", "n": n, "seed": s, "cost": float(n), "score": n + s} for n in (10, 20) for s in (0, 1, 2)]
    runs = [r for r in runs if not (r["n"] == 20 and r["seed"] == 2)]  # seed 2 missing on rung 20
    c = curves_from_runs(runs, "p", ladder=(10, 20), zero_shot={"0": 1.0, "1": 2.0, "2": 3.0})
    assert c.seeds == (0, 1) and list(c.costs) == [0.0, 10.0, 20.0] and c.through_end
    np.testing.assert_array_equal(c.scores, [[1.0, 10.0, 20.0], [2.0, 11.0, 21.0]])
    assert not curves_from_runs(runs, "p", ladder=(10, 20, 40)).through_end
    with pytest.raises(ValueError, match="seeds × rungs"):
        Curve(np.array([1.0]), (0,), np.zeros((2, 1)), through_end=True)


class _ScriptedWork:
    """A stand-in for the experiment's workspace: each rung's score comes from a script, no training."""

    def __init__(self, ladder, confirm, scores, seeds=(0, 1)):
        self.cfg = SimpleNamespace(ladder=ladder, seeds=seeds, confirm=confirm, stop_when_reached=True)
        self.scores, self.trained = scores, []

    def run(self, arm, n, seed, make, tcfg):
        self.trained.append((n, seed))
        return {"arm": arm, "n": n, "seed": seed, "score": self.scores[n]}

    def tick(self, *_):
        pass


@pytest.mark.parametrize(("scores", "zero_shot", "confirm", "rungs"), [
    ({1: 5, 2: 11, 4: 12, 8: 13, 16: 14}, 0.0, 2, [1, 2, 4, 8]),   # 2 reaches, 4 and 8 confirm: stop
    ({1: 11, 2: 9, 4: 12, 8: 13, 16: 14}, 0.0, 1, [1, 2, 4, 8]),   # 1 reaches but 2 falls back: go on
    ({1: 11, 2: 12, 4: 2, 8: 2, 16: 2}, 12.0, 1, [1]),             # zero-shot + rung 1 above: stop at once
    ({1: 5, 2: 5, 4: 5, 8: 5, 16: 5}, 0.0, 2, [1, 2, 4, 8, 16]),    # never: the whole ladder
])
def test_a_proxy_ladder_stops_only_once_the_score_has_stayed_above(scores, zero_shot, confirm, rungs):
    from proxybench.experiments.plv.run import _ladder

    work = _ScriptedWork((1, 2, 4, 8, 16), confirm, scores)
    rows = _ladder(work, "p", make=None, tcfg=None, reference=10.0, zero_shot=zero_shot)
    assert sorted({r["n"] for r in rows}) == rungs and len(rows) == 2 * len(rungs)


def _tiny():
    from proxybench.experiments.plv.run import PLVConfig

    return PLVConfig.from_dict({"width": 32, "height": 24, "ladder": [40, 80], "seeds": [0, 1], "proxy_samples": 80,
                                "model": {"channels": [8, 8, 8, 8, 8], "hidden": [16]},
                                "train": {"min_steps": 2, "max_steps": 2}, "pretrain": {"min_steps": 2, "max_steps": 2},
                                "finetune": {"min_steps": 2, "max_steps": 2},
                                "collect": {"robots": 8, "episode_frames": 20}, "eval": {"episodes": 2, "seconds": 1.0},
                                "replicates": 200})


def test_plv_objective_scores_proxies_against_one_cached_target_curve(tmp_path):
    """argmax PLV (thesis eq. 3.6.2) needs PLV as a function of θ: a tiny run, θ given as values and as a family."""
    from proxybench.experiments.plv.objective import PLVObjective, objective_value

    objective = PLVObjective(_tiny(), tmp_path)
    trial = objective({"camera_pitch": 30.0})
    assert trial.proxy == "proxy:camera_pitch=30" and trial.domain["params"]["camera_pitch"] == 30.0
    assert trial.value == objective_value(trial.plv, 80.0) and 0.0 <= trial.reached_share <= 1.0
    assert {r["seed"] for r in trial.runs} <= {0, 1} and all(r["arm"] == trial.proxy for r in trial.runs)
    assert set(trial.attrs()) >= {"plv", "plv_ci", "reached_share", "zero_shot"}
    cached = objective.work.cached
    again = objective({"camera_pitch": 30.0})  # the same θ: every unit of work comes from the cache
    assert again.value == trial.value and objective.work.cached > cached
    fam = objective({"camera_pitch": {"uniform": [25.0, 35.0]}}, family=True)
    assert fam.proxy.startswith("family-") and fam.domain["kind"] == "family"
    with pytest.raises(ValueError, match="images are"):
        from proxybench.learning.domains import proxy_domain

        objective(proxy_domain(64, 48))


def test_optimize_plv_searches_instances_and_families_and_resumes(tmp_path):
    from proxybench.experiments.plv.objective import PLVSearch, optimize_plv

    with pytest.raises(ValueError, match="lo < hi"):
        PLVSearch({"camera_pitch": (30.0, 10.0)})
    search = PLVSearch({"camera_pitch": (10.0, 30.0)}, trials=2, sampler="random", storage=str(tmp_path / "s.db"))
    res = optimize_plv(search, _tiny(), tmp_path / "work")
    assert len(res.trials) == 2 and res.best.value == max(t.value for t in res.trials)
    assert all(t.proxy.startswith("proxy:camera_pitch=") and t.plv_ci for t in res.trials)
    again = optimize_plv(search, _tiny(), tmp_path / "work")  # the stored study has its trials: none added
    assert [t.number for t in again.trials] == [0, 1]
    fam = optimize_plv(PLVSearch({"camera_pitch": (10.0, 30.0)}, trials=1, family=True, sampler="random"),
                       _tiny(), tmp_path / "work")
    lo, hi = fam.best.proposal["camera_pitch"]["uniform"]
    assert 10.0 <= lo <= hi <= 30.0 and fam.best.proxy.startswith("family-") and not fam.separated
