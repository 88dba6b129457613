"""Usefulness metrics on hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from proxybench.usefulness import PairedResults, dominance, mmrv, ppv_value, prpv_value, usefulness


def res(**agents):
    return {a: np.atleast_2d(np.asarray(v, dtype=float)) for a, v in agents.items()}


def test_identical_orders_give_prpv_zero():
    a = dominance(res(x=[[3, 1]], y=[[2, 1]], z=[[1, 0]]), [True, True])
    assert prpv_value(a, a) == 0.0


def test_one_swapped_pair_gives_two():
    t = dominance(res(x=[[3]], y=[[2]], z=[[1]]), [True])
    p = dominance(res(x=[[2]], y=[[3]], z=[[1]]), [True])
    assert prpv_value(p, t) == 2.0  # α_xy and α_yx both flip


def test_incomparable_pairs_are_half():
    a = dominance(res(x=[[3, 1]], y=[[1, 3]]), [True, True])
    np.testing.assert_array_equal(a, [[0.5, 0.5], [0.5, 0.5]])
    b = dominance(res(x=[[3, 3]], y=[[1, 1]]), [True, True])
    assert prpv_value(a, b) == 1.0  # two entries differ by 0.5


def test_ties_and_direction():
    a = dominance(res(x=[[1.0]], y=[[1.0]]), [True])
    np.testing.assert_array_equal(a, [[0.5, 0.5], [0.5, 0.5]])
    lower = dominance(res(x=[[1.0]], y=[[2.0]]), [False])  # lower is better: x dominates
    assert lower[0, 1] == 1.0 and lower[1, 0] == 0.0


def test_single_agent():
    a = dominance(res(x=[[1.0]]), [True])
    assert a.shape == (1, 1) and prpv_value(a, a) == 0.0
    est = usefulness(PairedResults(res(x=[[1.0]]), res(x=[[2.0]]), (True,)), n_boot=5)
    assert est["prpv"].value == 0.0 and est["prpv_norm"].value == 0.0


def test_dominance_matrix_is_complementary():
    rng = np.random.default_rng(0)
    r = {f"a{i}": rng.normal(size=(4, 3)) for i in range(6)}
    a = dominance(r, [True, False, True])
    off = ~np.eye(6, dtype=bool)
    np.testing.assert_allclose((a + a.T)[off], 1.0)


def test_significance_turns_noisy_differences_into_ties():
    rng = np.random.default_rng(1)
    x, y = rng.normal(0.0, 1.0, (10, 1)), rng.normal(0.1, 1.0, (10, 1))
    assert dominance({"x": x, "y": y}, [True])[0, 1] in (0.0, 1.0)
    assert dominance({"x": x, "y": y}, [True], significance=0.05)[0, 1] == 0.5
    far = {"x": x + 10, "y": y}
    assert dominance(far, [True], significance=0.05)[0, 1] == 1.0


def test_ppv_is_per_agent_and_summarised_by_the_mean():
    t = res(x=[[2.0]], y=[[4.0]])  # target spread (std) = 1
    p = res(x=[[3.0]], y=[[4.5]])  # PPV(x) = 1, PPV(y) = 0.5 (thesis eq. 3.4.1, β = 1)
    assert ppv_value(p, t) == pytest.approx(0.75)


def test_mmrv_counts_the_worst_violation_per_agent():
    target = np.array([3.0, 2.0, 1.0])
    assert mmrv(target, target) == 0.0
    proxy = np.array([2.0, 3.0, 1.0])  # x and y swapped: each sees a violation of size 1
    assert mmrv(proxy, target) == pytest.approx(2 / 3)


def test_usefulness_reports_intervals_around_the_point():
    rng = np.random.default_rng(2)
    target = {f"a{i}": rng.normal(i, 0.3, (5, 2)) for i in range(5)}
    proxy = {a: v + rng.normal(0, 0.3, v.shape) for a, v in target.items()}
    est = usefulness(PairedResults(proxy, target, (True, True)), n_boot=50)
    for k in ("prpv", "ppv", "ppv_sum", "pearson", "spearman", "kendall", "mmrv_m0", "mmrv_m1", "mmrv_scaled"):
        assert est[k].low <= est[k].value <= est[k].high, (k, est[k])
    assert est["pearson"].value > 0.9 and est["prpv"].method == "order range"


def test_paired_results_must_match():
    with pytest.raises(ValueError, match="same agents"):
        PairedResults(res(x=[[1.0]]), res(y=[[1.0]]), (True,))
    with pytest.raises(ValueError, match=r"proxy\['x'\]: expected \(episodes, 2\)"):
        PairedResults(res(x=[[1.0]]), res(x=[[1.0, 2.0]]), (True, True))


def test_predictivity_experiment_end_to_end_on_a_tiny_config(tmp_path):
    from proxybench.experiments.config import ExperimentConfig
    from proxybench.experiments.predictivity.report import write_report
    from proxybench.experiments.predictivity.run import run_predictivity

    cfg = ExperimentConfig(agents=["straight", "pid", "vision"], episodes=2, seconds=3.0,
                           sweep={"trim": (-0.3, 0.0), "camera_pitch": (15.0, 19.15)}, n_boot=10, pod_seconds=1.0)
    res = run_predictivity(cfg, tmp_path / "runs")
    df = res.frame()
    assert list(df.parameter) == ["trim", "trim", "camera_pitch", "camera_pitch"]  # each parameter once
    assert set(res.target_scores) == {"straight", "pid", "vision"}
    assert (df.pod >= 0).all() and (df.prpv >= 0).all() and (df.prpv <= 6).all()
    assert res.target.info.simulated is True and res.target.info.kind == "reality-model"
    assert 0 <= res.noise.low <= res.noise.value <= res.noise.high <= 6
    assert set(res.claims) == {"trim", "camera_pitch"} and "delta_best" in df
    # proxies replay the target's episodes: same seeds and start poses
    poses = {(e.agent, e.episode): e.pose for e in res.target.episodes}
    assert len(poses) == 6 and all(p is not None for p in poses.values())
    files = write_report(res, tmp_path / "report")
    html = files["html"].read_text()
    assert "SIMULATED TARGET" in html and "data:image/png;base64" in html
    for key in ("fig3_3", "fig3_4"):
        assert files[key].exists() and files[key].with_suffix(".svg").exists()
    again = run_predictivity(cfg, tmp_path / "runs")  # resumes from the cache, same numbers
    assert again.frame().prpv.tolist() == df.prpv.tolist() and again.proxy_episodes == 0


def test_optimizer_runs_trials_into_a_sqlite_study_and_resumes(tmp_path):
    from proxybench.experiments.config import ExperimentConfig, SearchConfig
    from proxybench.experiments.optimize.run import optimize_proxy, plot_optimization

    cfg = ExperimentConfig(agents=["straight", "pid"], episodes=1, seconds=2.0, n_boot=10,
                           search=SearchConfig(space={"trim": (-0.3, 0.3)}, trials=3, sampler="random",
                                               storage=str(tmp_path / "study.db")))
    res = optimize_proxy(cfg, tmp_path / "runs")
    assert len(res.trials) == 3 and -0.3 <= res.best_params["trim"] <= 0.3
    assert res.truth == {"trim": 0.0} and res.best_value == min(t.value for t in res.trials)
    assert res.trials[0].prpv is not None and res.trials[0].ppv is not None
    assert set(res.recovered) == {"trim"} and set(res.errors()) == {"trim"}
    assert res.noise_floor is not None and res.target is not None and res.target.simulated is True
    again = optimize_proxy(cfg, tmp_path / "runs")  # the study is loaded, not repeated
    assert len(again.trials) == 3 and again.target_episodes_run == 0
    paths = plot_optimization(res, tmp_path / "plots")
    assert all(p.exists() for p in paths)


def test_experiment_config_names_bad_fields(tmp_path):
    from proxybench.experiments.config import ConfigError, load_config

    cases = [
        ({"search": {"space": {"trimm": [0.0, 1.0]}}}, "search.space: Value error, unknown domain parameter 'trimm'"),
        ({"search": {"space": {"trim": [1.0, 0.0]}}}, "trim needs low < high"),
        ({"search": {"objective": "best"}}, "search.objective"),
        ({"metrics": ["survival"]}, "metrics: Value error, unknown metric 'survival' (did you mean 'survival_time'?)"),
        ({"sweep": {"camera_pich": [1, 2]}}, "unknown domain parameter 'camera_pich' (did you mean 'camera_pitch'?)"),
        ({"episdoes": 3}, "episdoes: unknown key (did you mean 'episodes'?)"),
        ({"episodes": 0}, "episodes: a count within 1…10000, got 0"),
        ({"proxy": {"trim": 7}}, "proxy.trim"),
        ({"image_size": [4, 4]}, "image_size"),
    ]
    for data, message in cases:
        f = tmp_path / "exp.yaml"
        f.write_text(__import__("yaml").safe_dump(data))
        with pytest.raises(ConfigError) as err:
            load_config(f)
        assert str(f) in str(err.value) and message.replace("Value error, ", "") in str(err.value), str(err.value)
    assert load_config(None, {"episodes": 2}).episodes == 2  # the command line alone


def test_best_decile_is_the_mean_of_the_best_trials():
    from proxybench.experiments.optimize.run import Trial, best_decile

    trials = [Trial(v, float(v), {"x": float(v)}) for v in range(30)]  # value = x: best are x = 0, 1, 2
    assert best_decile(trials, ["x"]) == {"x": 1.0}
    trials = [Trial(v, float(v), {"x": float(v)}) for v in range(100)]
    assert best_decile(trials, ["x"]) == {"x": 4.5}  # the best 10


def test_the_best_prpv_names_every_proxy_that_reaches_it():
    """A best PRPV shared by two proxies is not claimed for one of them alone."""
    from types import SimpleNamespace

    import pandas as pd

    from proxybench.experiments.predictivity.report import noise_statement
    from proxybench.experiments.predictivity.run import BestProxy

    rows = [{"parameter": "command_delay", "value": 0.05, "prpv": 12.0, "prpv_low": 0.0, "prpv_high": 60.0},
            {"parameter": "blur_time", "value": 0.0, "prpv": 12.0, "prpv_low": 4.0, "prpv_high": 64.0},
            {"parameter": "trim", "value": 0.1, "prpv": 13.0, "prpv_low": 2.0, "prpv_high": 80.0}]
    res = SimpleNamespace(best_row=lambda: BestProxy.of({**rows[0], "ppv": 0.0}), frame=lambda: pd.DataFrame(rows),
                          noise=SimpleNamespace(value=18.0, low=4.0, high=32.0),
                          experiment=SimpleNamespace(episodes=3, episode_count=3))
    text = noise_statement(res)
    assert text.startswith("Best PRPV 12.0 [0.0, 60.0] at command_delay = 0.05 (equally at blur_time = 0);")
    assert "trim" not in text and "within the noise floor" in text
