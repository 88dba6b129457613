"""Reports carry baselines (the nominal θ, an agent-class rule, the target's own first half) beside every proxy,
and say which agent pairs each predictor orders differently from the target, and on which starts."""

from __future__ import annotations

import numpy as np
import pandas as pd
import yaml

from proxybench.experiments.baselines import CLASS_RULE, agent_class_ranks, start_direction
from proxybench.usefulness.baselines import class_predictor, half_split
from proxybench.usefulness.diagnosis import pair_disagreements
from proxybench.usefulness.intervals import usefulness
from proxybench.usefulness.metrics import PairedResults


def test_the_class_rule_ties_within_a_class_and_orders_the_classes():
    ranks = agent_class_ranks(["pid", "vision", "my-node", "random", "straight", "bang-bang"])
    assert ranks == {"pid": 2, "vision": 1, "my-node": 1, "random": 0, "straight": 0, "bang-bang": 2}
    assert "ahead of" in CLASS_RULE
    target = {a: np.array([[float(i)], [float(i) + 0.5]]) for i, a in enumerate(ranks)}
    pred = class_predictor(target, ranks, (True,))
    u = usefulness(PairedResults(pred, target, (True,), ("m",)), n_boot=30)
    assert pred["pid"][0, 0] == pred["bang-bang"][0, 0] > pred["vision"][0, 0] > pred["random"][0, 0]
    assert u["prpv"].low <= u["prpv"].value <= u["prpv"].high
    first, second = half_split(target)
    assert first["pid"].shape == second["pid"].shape == (1, 1)


def test_a_pair_ordered_differently_only_on_clockwise_starts_says_so():
    # on the target a camera agent survives counter-clockwise starts but leaves the road on clockwise ones; the
    # proxy lets it survive both: overall the target puts it behind "straight", the proxy ahead
    target = {"cam": np.array([[30.0], [1.0], [30.0], [1.0]]), "straight": np.array([[20.0]] * 4)}
    proxy = {"cam": np.array([[30.0], [29.0], [30.0], [30.0]]), "straight": np.array([[20.0]] * 4)}
    groups = {a: ["counter-clockwise start", "clockwise start"] * 2 for a in target}
    (d,) = pair_disagreements(proxy, target, (True,), ("survival_time",), groups=groups)
    assert (d.a, d.b, d.alpha_target, d.alpha_proxy, d.cost) == ("cam", "straight", 0.0, 1.0, 2.0)
    assert d.where() == ["clockwise start"] and d.groups["clockwise start"] == (1.0, 0.0, 2)
    assert d.target_delta["survival_time"] == -4.5 and d.proxy_delta["survival_time"] == 9.75
    assert pair_disagreements(target, target, (True,), ("m",)) == []  # a perfect predictor: nothing to list


def test_start_direction_around_the_map_centre():
    assert start_direction((1.0, 0.0, np.pi / 2), (0.0, 0.0)) == "counter-clockwise start"
    assert start_direction((1.0, 0.0, -np.pi / 2), (0.0, 0.0)) == "clockwise start"
    assert start_direction(None, (0.0, 0.0)) == "unknown start"


def test_the_report_of_a_recorded_target_shows_baselines_and_the_per_pair_table(tmp_path):
    from proxybench.experiments.config import ExperimentConfig
    from proxybench.experiments.predictivity.report import findings, write_report
    from proxybench.experiments.predictivity.run import run_predictivity

    root = tmp_path / "lab"
    y = 0.585 * 0.5 - 0.22 * 0.585
    man = {"source": "simulation", "map": "loop_3x3", "seconds": 2.0, "agents": ["pid", "straight", "vision"],
           "episodes": [0, 1], "trajectories": "{agent}_{episode}.csv", "who": "another simulator"}
    root.mkdir()
    (root / "target.yaml").write_text(yaml.safe_dump(man))
    for agent, v in (("pid", 0.3), ("straight", 0.1), ("vision", 0.2)):
        for ep in (0, 1):
            t = np.linspace(0, 2.0, 41)
            pd.DataFrame({"t": t, "x": 0.5 + 0.1 * ep + v * t, "y": np.full(41, y), "theta": 0 * t}).to_csv(
                root / f"{agent}_{ep}.csv", index=False)
    cfg = ExperimentConfig(target=str(root), sweep={"trim": (-0.2, 0.0)}, n_boot=20, pod_seconds=0.0)
    res = run_predictivity(cfg, tmp_path / "runs")
    assert set(res.baselines) == {"nominal θ", "no simulator: agent classes", "no simulator: the target's first half"}
    assert any(name.startswith("best proxy") for name in res.diagnosis) and "nominal θ" in res.diagnosis
    lines = findings(res)
    assert any(line.startswith("baseline no simulator: agent classes: PRPV") for line in lines)
    files = write_report(res, tmp_path / "report")
    page = files["html"].read_text()
    assert "Baselines: no tuning, no simulator" in page and "Which pairs of agents each predictor orders" in page
    assert files["diagnosis"].exists() and files["pairs"].exists()
