"""Every map that ships with duckietown-world loads unchanged, passes `map check`, and drives.

The maps are read from the installed ``duckietown-world-daffy`` package (a test dependency, located
through its file list, never imported): 44 gym-duckietown ("gd1") maps in both object placements.
"""

from __future__ import annotations

import math
from collections import Counter
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from proxybench.agents import make_agent
from proxybench.cli import app
from proxybench.domain.maps import Direction, load_map
from proxybench.domain.objects import pack_objects
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.runner.episode import run_episode

# three of the maps load with a fallback (a start tile off the map or off the road, no road at all): checked below
pytestmark = pytest.mark.filterwarnings("ignore::proxybench.domain.maps.MapWarning")

PACKAGE = "duckietown-world-daffy"
TS = 0.585


def _maps() -> list[Path]:
    try:
        files = metadata.files(PACKAGE) or []
    except metadata.PackageNotFoundError:
        return []
    return sorted(Path(str(f.locate())) for f in files if "/gd1/maps/" in str(f) and str(f).endswith(".yaml"))


MAPS = _maps()
BY_NAME = {p.stem: p for p in MAPS}
#: maps without a single drivable tile (an asphalt field; the intrinsic-calibration room)
NOT_DRIVABLE = {"field1", "calibration_map_int"}


def test_all_44_maps_of_the_package_are_there():
    assert len(MAPS) == 44, f"{PACKAGE}==6.4.3 is a test dependency: pip install -e '.[test]' (found {len(MAPS)} maps)"


@pytest.mark.parametrize("path", MAPS, ids=[p.stem for p in MAPS])
def test_map_loads_with_every_object(path):
    m = load_map(path)
    data = yaml.safe_load(path.read_text())
    objects = data.get("objects") or {}
    assert len(m.objects) == len(objects), "no object may be dropped"
    assert bool(m.drivable_tiles()) == (path.stem not in NOT_DRIVABLE)
    w, h = m.size_m
    for obj in m.objects:  # on the map or just beside it (TTIC_ripltown has a tag 0.45 m past its edge)
        assert -TS <= obj.x <= w + TS and -TS <= obj.y <= h + TS, obj
    assert not [w for w in m.warnings if "unknown object kind" in w.message], "every kind they use has a shape"


def test_map_check_passes_on_all_of_them():
    res = CliRunner().invoke(app, ["map", "check", *map(str, MAPS)])
    assert res.exit_code == 0, res.output
    assert res.output.count("✓") == len(MAPS) == 44
    assert "💯" not in res.output and "straight_road_down.yaml:12:13: 'start_tile' [1, 0] is outside" in res.output


@pytest.mark.parametrize("name", sorted(set(BY_NAME) - NOT_DRIVABLE))
def test_map_drives(name):
    """A short episode of the privileged PID agent (small camera frames): it moves, and does not start on an
    object."""
    sim = Simulator(load_map(BY_NAME[name]), DomainParams(image_width=32, image_height=24))
    traj = run_episode(sim, make_agent("pid"), seed=0, seconds=2.0)
    assert traj.termination in ("timeout", "off_road"), traj.events
    x, y = traj["x"], traj["y"]
    moved = math.hypot(x[-1] - x[0], y[-1] - y[0])
    assert moved > 0.1, f"{name}: the robot moved {moved:.3f} m"


# ---------------------------------------------------------------------------------------------------
# What the placements mean, checked on the real files


def test_place_is_metres_from_the_tile_centre():
    (light,) = load_map(BY_NAME["4way"]).objects
    assert light.kind == "trafficlight" and light.height == 0.4
    assert (light.x, light.y) == pytest.approx((2.5 * TS - 0.18, 2.5 * TS - 0.18))
    assert light.heading == pytest.approx(math.radians(135))
    assert pack_objects([light]).colliders.shape[0] == 0  # hangs over the crossing: nothing hits it


def test_pose_is_metres_in_the_map_frame_and_tags_are_kept():
    m = load_map(BY_NAME["robotarium1"])
    o7 = next(o for o in m.objects if o.name == "O7")
    assert o7.kind == "floor_tag" and (o7.x, o7.y) == pytest.approx((3.021, 7.659)) and o7.heading == 0.0
    assert (o7.tag.family, o7.tag.tag_id, o7.tag.size) == ("36h11", 366, 0.08)
    g6 = next(o for o in m.objects if o.name == "G6")
    assert g6.heading == pytest.approx(math.pi / 4)
    kinds = Counter(o.kind for o in m.objects)
    assert kinds["floor_tag"] > 50 and sum(k.startswith("sign") for k in kinds.elements()) == 34


def test_attach_is_a_sign_slot_around_the_tile_corner_with_the_pose_heading():
    m = load_map(BY_NAME["robotarium2"])
    tag31 = next(o for o in m.objects if o.name == "tag31")  # tile [3, 15], slot 0, theta_deg 270
    assert tag31.kind == "sign_right_T_intersect"
    assert (tag31.x, tag31.y) == pytest.approx(((3 + 0.09) * TS, (15 + 0.035) * TS))
    assert tag31.heading == pytest.approx(math.radians(270))


def test_start_tile_outside_the_map_starts_on_a_random_drivable_tile():
    m = load_map(BY_NAME["straight_road_down"])
    assert m.start_tile is None and len(m.warnings) == 1
    sim = Simulator(m, render=False)
    starts = {sim.map.tile_at(*sim.sample_start(np.random.default_rng(s))[:2]).j for s in range(20)}
    assert len(starts) > 3


def test_calibration_maps_start_on_their_start_tile_and_end_on_the_calibration_tile():
    ext = load_map(BY_NAME["calibration_map_ext"])
    # start_pose [[0.480, 0, 0.2925], 0] counts from the north-west corner of start_tile [0, 3] (file row 3 of 7)
    assert ext.start_pose == pytest.approx((0.48, 3.5 * TS, 0.0))
    assert ext.tile(1, 3).kind == "calibration_tile" and not ext.tile(1, 3).drivable
    assert (0, 3, Direction.E) in ext.road_ends
    assert "1 onto calibration_tile" in ext.summary()
    intr = load_map(BY_NAME["calibration_map_int"])
    assert intr.start_tile is None and intr.start_pose == pytest.approx((0.48, 3.5 * TS, 0.0))
    assert {o.kind for o in intr.objects} == {"checkerboard"}
    assert any("no drivable tile" in w.message for w in intr.warnings)
