"""`optimize` when trials tie: the tied set and its spread, never an average of whichever trials came first."""

from __future__ import annotations

import numpy as np

from proxybench.experiments.optimize.run import Trial, tied_set


def _target(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {f"a{i}": np.column_stack([rng.normal(i, 0.3, 6), rng.normal(10 - i, 0.3, 6)]) for i in range(6)}


def _case(order: list[int]):
    """Ten trials at PRPV 0 (proxies equal to the target) spread over trim 0.05 … 0.5, two clearly worse."""
    target = _target()
    good = {a: v.copy() for a, v in target.items()}
    bad = {a: v[:, ::-1] * [1, -1] for a, v in target.items()}  # the order of the agents reversed
    thetas = [0.05 * (i + 1) for i in range(10)] + [0.9, 1.0]
    trials, proxies = [], {}
    for number, j in enumerate(order):
        trials.append(Trial(number, 0.0 if j < 10 else 30.0, {"trim": thetas[j]}, prpv=0.0 if j < 10 else 30.0))
        proxies[number] = good if j < 10 else bad
    return trials, proxies, target


def test_tied_trials_form_a_set_with_its_spread_and_a_warning():
    trials, proxies, target = _case(list(range(12)))
    tied = tied_set(trials, proxies, target, (True, True), ["trim"], n_boot=100, seed=1)
    assert len(tied.trials) == 10 and not tied.separated
    median, lo, hi = tied.spread["trim"]
    assert (lo, hi) == (0.05, 0.5) and abs(median - 0.275) < 1e-9
    assert "not separated from 9 other" in tied.warning() and "trim 0.05 … 0.5" in tied.warning()


def test_the_summary_does_not_depend_on_the_order_trials_ran_in():
    a = tied_set(*_case(list(range(12))), (True, True), ["trim"], n_boot=100, seed=1)
    order = [11, 3, 9, 0, 10, 5, 1, 8, 2, 7, 4, 6]
    b = tied_set(*_case(order), (True, True), ["trim"], n_boot=100, seed=1)
    assert a.spread == b.spread


def test_a_best_trial_separated_from_the_rest_stands_alone():
    trials, proxies, target = _case([0, 10, 11])
    tied = tied_set(trials, proxies, target, (True, True), ["trim"], n_boot=100, seed=1)
    assert tied.separated and tied.trials == (0,) and tied.warning() is None
