"""Task metrics against hand-computed trajectories, and the trajectory file formats."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from proxybench.domain.maps import load_map
from proxybench.tasks.metrics import LANE_HALF_WIDTH, METRICS, UNIT_DECIMALS, deviation_curves, repeatability
from proxybench.tasks.trajectory import Event, Trajectory, TrajectoryError

TS = 0.585
EAST_LANE_Y = 1.5 * TS - 0.22 * TS  # centre of the eastbound right lane on straight_road
WEST_LANE_Y = 1.5 * TS + 0.22 * TS
DT = 0.05


@pytest.fixture(scope="module")
def road():
    return load_map("straight_road")


def _drive(road, x0, speed, seconds, y, heading):
    t = np.arange(0.0, seconds + 1e-9, DT)
    x = x0 + speed * t * np.cos(heading)
    pose = np.stack([x, np.full_like(t, y), np.full_like(t, heading)], axis=1)
    return Trajectory.from_poses(road, t, pose, meta={"episode_seconds": seconds})


def m(name, traj):
    return METRICS[name](traj)


def test_straight_drive_in_lane(road):
    traj = _drive(road, 0.3, 0.2, 10.0, EAST_LANE_Y, 0.0)
    assert m("survival_time", traj) == pytest.approx(10.0)
    assert m("driven_lanedir_consec", traj) == pytest.approx(2.0)
    assert m("driven_any", traj) == pytest.approx(2.0)
    assert m("deviation_center_line", traj) == pytest.approx(0.0, abs=1e-12)
    assert m("deviation_heading", traj) == pytest.approx(0.0, abs=1e-12)
    assert m("in_drivable_lane", traj) == pytest.approx(0.0)
    assert m("lane_score", traj) == pytest.approx(10.0)


def test_offset_and_heading_integrate_over_time(road):
    traj = _drive(road, 0.3, 0.2, 4.0, EAST_LANE_Y + 0.05, 0.0)
    assert m("deviation_center_line", traj) == pytest.approx(0.05 * 4.0)


def test_wrong_way_scores_nothing(road):
    # in the eastbound lane, driving west: the robot is in the wrong lane for its heading
    traj = _drive(road, 5.0, 0.2, 5.0, EAST_LANE_Y, np.pi)
    assert m("driven_any", traj) == pytest.approx(1.0)
    assert m("driven_lanedir_consec", traj) == 0.0
    assert m("in_drivable_lane", traj) == pytest.approx(5.0)


def test_backwards_in_own_lane_is_negative_progress(road):
    # facing east in the eastbound lane but reversing: progress is negative
    t = np.arange(0.0, 2.0 + 1e-9, DT)
    pose = np.stack([3.0 - 0.1 * t, np.full_like(t, EAST_LANE_Y), np.zeros_like(t)], axis=1)
    traj = Trajectory.from_poses(road, t, pose)
    assert m("driven_lanedir_consec", traj) == pytest.approx(-0.2)


def test_one_wheel_out_for_two_seconds(road):
    # wheel track 0.102 m: one wheel out when the centre is more than half-width − 0.051 m off the lane centre
    off = LANE_HALF_WIDTH - 0.051 + 0.02
    t = np.arange(0.0, 6.0 + 1e-9, DT)
    y = np.where((t > 2.0) & (t <= 4.0 + 1e-9), EAST_LANE_Y + off, EAST_LANE_Y)
    pose = np.stack([0.5 + 0.2 * t, y, np.zeros_like(t)], axis=1)
    traj = Trajectory.from_poses(road, t, pose)
    assert m("lane_score", traj) == pytest.approx(6.0 - 2.0)
    assert m("in_drivable_lane", traj) == pytest.approx(0.0)  # the centre stayed in the lane


def test_both_wheels_out_costs_two_per_second(road):
    t = np.arange(0.0, 3.0 + 1e-9, DT)
    y = np.where(t > 1.0 + 1e-9, WEST_LANE_Y, EAST_LANE_Y)  # swerve fully into the other lane after 1 s
    pose = np.stack([0.5 + 0.2 * t, y, np.zeros_like(t)], axis=1)
    traj = Trajectory.from_poses(road, t, pose)
    assert m("lane_score", traj) == pytest.approx(3.0 - 2 * 2.0)  # episode time − 2 × time with both out
    assert m("in_drivable_lane", traj) == pytest.approx(2.0)


def test_recorded_run_leaving_the_map_ends_there(road, tmp_path):
    t = np.arange(0.0, 3.0 + 1e-9, DT)
    x = 6.6 + 0.2 * t  # the map is 7.02 m long: leaves after ~2.1 s
    csv = tmp_path / "run.csv"
    pd.DataFrame({"timestamp": t + 100.0, "x": x, "y": EAST_LANE_Y, "heading": 0.0}).to_csv(csv, index=False)
    traj = Trajectory.from_file(csv, "straight_road")
    assert traj.termination == "left_map" and traj.meta["source"] == "recorded"
    assert traj["t"][0] == 0.0 and traj.duration == pytest.approx(2.1 - DT, abs=DT)
    assert m("driven_lanedir_consec", traj) == pytest.approx(traj.duration * 0.2, rel=1e-6)


@pytest.mark.parametrize(
    ("frame", "message"),
    [
        (pd.DataFrame({"t": [0.0, 1.0], "x": [1.0, 1.1]}), "missing column(s) y, theta"),
        (pd.DataFrame({"t": [0.0, 1.0, 0.5], "x": [1.0] * 3, "y": [0.7] * 3, "theta": [0.0] * 3}),
         "time is not increasing at sample 2"),
        (pd.DataFrame({"t": [0.0, 1.0], "x": [50.0, 50.1], "y": [0.7] * 2, "theta": [0.0] * 2}),
         "off the map"),
        (pd.DataFrame({"t": [0.0, 1.0], "x": [1.0, np.nan], "y": [0.7] * 2, "theta": [0.0] * 2}),
         "sample 1 is not a finite number"),
    ],
)
def test_bad_recorded_files_are_rejected_with_the_reason(tmp_path, frame, message):
    path = tmp_path / "bad.csv"
    frame.to_csv(path, index=False)
    with pytest.raises(TrajectoryError, match=str(path).replace(".", r"\.")) as exc:
        Trajectory.from_file(path, "straight_road")
    assert message in str(exc.value)


def test_unknown_format_and_missing_file(tmp_path):
    with pytest.raises(TrajectoryError, match="no such file"):
        Trajectory.from_file(tmp_path / "nope.csv", "straight_road")
    (tmp_path / "x.json").write_text("{}")
    with pytest.raises(TrajectoryError, match="unknown trajectory format"):
        Trajectory.from_file(tmp_path / "x.json", "straight_road")


def test_parquet_round_trip_keeps_columns_meta_and_events(road, tmp_path):
    traj = _drive(road, 0.3, 0.2, 2.0, EAST_LANE_Y, 0.0)
    traj.events.append(Event(1.0, "note", "hello", extra={"by": "a lab's importer"}))
    path = traj.save(tmp_path / "a.parquet")
    back = Trajectory.load(path)
    assert back.meta == traj.meta and back.events == traj.events and back.termination == traj.termination
    for name in traj.columns:
        np.testing.assert_array_equal(back[name], traj[name])
    assert not list(tmp_path.glob(".*tmp"))  # atomic write leaves no temporary file


def _runs_at(road, offsets_m, headings=None, seconds=10.0):
    headings = headings or [0.0] * len(offsets_m)
    return [_drive(road, 0.3, 0.2, seconds, EAST_LANE_Y + d, h) for d, h in zip(offsets_m, headings, strict=True)]


def test_mpd_is_the_signed_mean_offset_from_the_lane_centre_as_the_thesis_defines_it(road):
    """Thesis §5.4: MPD at a point = mean lateral displacement from the lane centre (not spread around the mean)."""
    same = repeatability(_runs_at(road, [0.02, 0.02]))
    assert same["MPD_cm"] == pytest.approx(2.0) and same["MPD_std_cm"] == pytest.approx(0.0, abs=1e-9)
    r = repeatability(_runs_at(road, [0.01, 0.03]))  # 1 and 3 cm left: mean 2, std (ddof 1) √2
    assert r["MPD_cm"] == pytest.approx(2.0) and r["MPD_std_cm"] == pytest.approx(np.sqrt(2.0))
    assert r["MOD_deg"] == pytest.approx(0.0, abs=1e-9) and r["MPD_std_route_cm"] == pytest.approx(0.0, abs=1e-9)
    right = repeatability(_runs_at(road, [-0.05, -0.07]))  # both right of the centre: negative, like the thesis' −6.2
    assert right["MPD_cm"] == pytest.approx(-6.0)
    sym = repeatability(_runs_at(road, [-0.01, 0.01]))  # the old spread-around-the-mean measure said 1 cm
    assert sym["MPD_cm"] == pytest.approx(0.0, abs=1e-9) and sym["MPD_std_cm"] == pytest.approx(np.sqrt(2.0))
    assert r["runs"] == 2 and r["route_m"] == pytest.approx(2.0, abs=0.03)


def test_mod_is_the_signed_mean_heading_error(road):
    r = repeatability(_runs_at(road, [0.0, 0.0], headings=[np.radians(2.0), np.radians(4.0)]))
    assert r["MOD_deg"] == pytest.approx(3.0) and r["MOD_std_deg"] == pytest.approx(np.sqrt(2.0))


def test_repeatability_splits_variability_within_and_between_robots(road):
    # robot A: 0 and 2 cm; robot B: 4 and 6 cm. Within: each pair has variance 2 → √2; between: means 1 and 5
    # → variance 8 → 2√2; all four: variance (9 + 1 + 1 + 9) / 3 → √(20/3).
    r = repeatability(_runs_at(road, [0.0, 0.02, 0.04, 0.06]), groups=["A", "A", "B", "B"])
    assert r["MPD_cm"] == pytest.approx(3.0) and r["MPD_std_cm"] == pytest.approx(np.sqrt(20 / 3))
    assert r["MPD_within_std_cm"] == pytest.approx(np.sqrt(2.0))
    assert r["MPD_between_std_cm"] == pytest.approx(2 * np.sqrt(2.0))
    assert r["MOD_within_std_deg"] == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(ValueError, match="one label per run"):
        repeatability(_runs_at(road, [0.0, 0.02]), groups=["A"])


def test_runs_of_different_length_are_compared_where_two_reached(road):
    # a 4 cm run that stops after 0.4 m: the first 0.4 m average three runs (2 cm), the rest two (1 cm)
    runs = [*_runs_at(road, [0.0, 0.02], seconds=5.0), _drive(road, 0.3, 0.2, 2.0, EAST_LANE_Y + 0.04, 0.0)]
    c = deviation_curves(runs, grid_step=0.05)
    assert list(c.runs_at[:8]) == [3] * 8 and set(c.runs_at[10:]) == {2}
    r = repeatability(runs, grid_step=0.05)
    assert 1.0 < r["MPD_cm"] < 2.0
    with pytest.raises(ValueError, match="at least 2 runs"):
        repeatability(runs[:1])
    with pytest.raises(ValueError, match="share no driven distance"):
        repeatability([runs[0], _drive(road, 0.3, 0.0, 2.0, EAST_LANE_Y, 0.0)])  # the second never moves


def test_every_metric_says_how_people_read_it():
    """Tables and the web console show each metric by its label, unit and direction, with its unit's precision."""
    labels = [m.display_name for m in METRICS.values()]
    for m in METRICS.values():
        assert m.label and m.label[0].isupper() and "_" not in m.label, m.name
        assert m.unit in UNIT_DECIMALS, (m.name, m.unit)
        assert m.title == f"{m.label} [{m.unit}]" and m.direction in "↑↓"
    assert len(set(labels)) == len(labels)  # no two read alike
    assert METRICS["survival_time"].decimals == 1 and METRICS["deviation_center_line"].decimals == 3
    assert METRICS["stopped_at_line"].missing  # its NaN means something: said where it is shown
