"""Task metrics against hand-computed trajectories, and the trajectory file formats."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from proxybench.domain.maps import load_map
from proxybench.tasks.metrics import LANE_HALF_WIDTH, METRICS, repeatability
from proxybench.tasks.trajectory import Trajectory, TrajectoryError

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
    traj.events.append({"t": 1.0, "kind": "note", "message": "hello"})
    path = traj.save(tmp_path / "a.parquet")
    back = Trajectory.load(path)
    assert back.meta == traj.meta and back.events == traj.events and back.termination == traj.termination
    for name in traj.columns:
        np.testing.assert_array_equal(back[name], traj[name])
    assert not list(tmp_path.glob(".*tmp"))  # atomic write leaves no temporary file


def test_repeatability_of_identical_runs_is_zero_and_grows_with_spread(road):
    a = _drive(road, 0.3, 0.2, 10.0, EAST_LANE_Y, 0.0)
    assert repeatability([a, a])["MPD_cm"] == pytest.approx(0.0, abs=1e-9)
    b = _drive(road, 0.3, 0.2, 10.0, EAST_LANE_Y + 0.02, 0.0)
    r = repeatability([a, b])
    assert r["MPD_cm"] == pytest.approx(1.0)  # each run is 1 cm from the mean
    assert r["MOD_deg"] == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(ValueError, match="at least 2 runs"):
        repeatability([a])
