"""Map loading and validation: built-in maps, and every invalid map rejected with a precise location."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from proxybench.domain.maps import (
    DRIVABLE_KINDS,
    Direction,
    Map,
    MapError,
    MapWarning,
    builtin_map_names,
    load_map,
    parse_map,
)

BUILTIN = ["intersections", "loop_3x3", "small_loop", "small_loop_cw", "straight_road", "zigzag"]


def write_map(tmp_path: Path, text: str, name: str = "bad.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def load_error(path: Path) -> MapError:
    with pytest.raises(MapError) as exc_info:
        load_map(path)
    return exc_info.value


def assert_located(msg: str, path: Path, line: int, row: int | None = None, col: int | None = None) -> None:
    """The message names the file and YAML line, and (for tile problems) the tile's row and column."""
    assert str(path) in msg
    assert re.search(rf"{re.escape(str(path))}:{line}:\d+:", msg), msg
    if row is not None:
        assert f"row {row}" in msg, msg
    if col is not None:
        assert f"column {col}" in msg, msg


# ---------------------------------------------------------------------------------------------------
# Built-in maps


def test_builtin_map_names_lists_every_shipped_map():
    assert builtin_map_names() == BUILTIN


@pytest.mark.parametrize("name", BUILTIN)
def test_builtin_map_loads_and_every_road_connects(name):
    m = load_map(name)
    assert isinstance(m, Map)
    assert m.name == name
    assert m.tile_size == pytest.approx(0.585)
    assert Path(m.path).is_file()
    assert m.drivable_tiles()
    # every open edge faces a drivable tile that opens back, or the map's edge (a recorded road end)
    ends = set(m.road_ends)
    for t in m.drivable_tiles():
        for e in t.open_edges:
            dx, dy = e.unit
            other = m.tile(t.i + dx, t.j + dy)
            if other is None:
                assert (t.i, t.j, e) in ends
                assert not (0 <= t.i + dx < m.width and 0 <= t.j + dy < m.height)
            else:
                assert other.drivable
                assert e.opposite in other.open_edges


@pytest.mark.parametrize("name", BUILTIN)
def test_builtin_map_summary_counts(name):
    m = load_map(name)
    s = m.summary()
    assert s.startswith(f"{m.width}×{m.height} tiles of 0.585 m")
    assert f"{len(m.drivable_tiles())} drivable" in s
    assert f"{len(m.objects)} objects" in s


def test_summary_strings_exact():
    assert load_map("loop_3x3").summary() == (
        "3×3 tiles of 0.585 m (1.75 × 1.75 m); 8 drivable (4 curve_left, 4 straight); 0 objects"
    )
    assert load_map("straight_road").summary() == (
        "12×3 tiles of 0.585 m (7.02 × 1.75 m); 12 drivable (12 straight); 0 objects, 2 road ends at the map edge"
    )
    assert load_map("intersections").summary() == (
        "5×5 tiles of 0.585 m (2.92 × 2.92 m); 21 drivable (4 3way_left, 1 4way, 4 curve_left, 12 straight); "
        "1 objects"
    )


def test_loop_3x3_layout_and_frame():
    m = load_map("loop_3x3")
    assert (m.width, m.height) == (3, 3)
    # (i, j) = (column, row from the bottom): the file's last row is j = 0
    assert m.tile(0, 0).label == "curve_left/S"
    assert m.tile(2, 0).label == "curve_left/E"
    assert m.tile(0, 2).label == "curve_left/W"
    assert m.tile(2, 2).label == "curve_left/N"
    assert m.tile(1, 1).kind == "grass" and not m.tile(1, 1).drivable
    assert m.tile(1, 0).label == "straight/E"
    assert m.tile(3, 0) is None and m.tile(-1, 0) is None
    # curve_left/S (bottom-left) connects north and east; curve_left/W (top-left) east and south
    assert m.tile(0, 0).open_edges == (Direction.E, Direction.N)
    assert m.tile(0, 2).open_edges == (Direction.E, Direction.S)
    assert m.tile(1, 0).open_edges == (Direction.E, Direction.W)
    ts = m.tile_size
    assert m.tile_at(0.1, 0.1) is m.tile(0, 0)
    assert m.tile_at(2.5 * ts, 0.5 * ts) is m.tile(2, 0)
    assert m.tile_at(0.5 * ts, 2.5 * ts) is m.tile(0, 2)
    assert m.road_ends == ()


def test_straight_road_has_two_road_ends_at_the_map_edge():
    m = load_map("straight_road")
    assert sorted(m.road_ends) == [(0, 1, Direction.W), (11, 1, Direction.E)]
    assert m.start_tile == (0, 1)


def test_start_pose_converted_from_gym_duckietown_frame():
    m = load_map("small_loop")
    x, y, th = m.start_pose
    # [[0.585, 0, 1.0062], 0]: z counts down the listing of a 2-row map
    assert x == pytest.approx(0.585)
    assert y == pytest.approx(2 * 0.585 - 1.0062)
    assert th == 0.0


def test_objects_positions_in_map_frame():
    m = load_map("zigzag")
    (obj,) = m.objects
    assert obj.kind == "duckie"
    # pos [1.5, 3.5] in tiles east and down the listing of a 5-row map
    assert obj.x == pytest.approx(1.5 * 0.585)
    assert obj.y == pytest.approx((5 - 3.5) * 0.585)
    assert obj.heading == pytest.approx(0.7853981633974483)
    assert obj.height == pytest.approx(0.08)


def test_load_unknown_builtin_name_lists_builtins():
    with pytest.raises(MapError) as exc_info:
        load_map("no_such_map")
    assert "no_such_map" in str(exc_info.value)
    assert "loop_3x3" in str(exc_info.value)


def test_default_orientation_is_east_and_equals_explicit_east(tmp_path):
    a = load_map(write_map(tmp_path, "tiles:\n- [straight, straight]\ntile_size: 0.585\n", "a.yaml"))
    b = load_map(write_map(tmp_path, "tiles:\n- [straight/E, straight/E]\ntile_size: 0.585\n", "b.yaml"))
    assert a.tile(0, 0).orientation == Direction.E
    assert a.tiles == b.tiles
    assert a.road_ends == b.road_ends


def test_parse_map_from_string_accepts_every_drivable_kind():
    text = """
tiles:
- [curve_left/W, 3way_left/W, curve_left/N]
- [3way_right/N, 4way       , 3way_left/N]
- [curve_left/S, 3way_left/E, curve_left/E]
tile_size: 0.61
"""
    m = parse_map(text, path="inline.yaml", name="inline")
    assert m.tile_size == 0.61
    kinds = {t.kind for t in m.drivable_tiles()}
    assert kinds == {"curve_left", "3way_left", "3way_right", "4way"}
    assert set(DRIVABLE_KINDS) - kinds == {"straight", "curve_right"}


# ---------------------------------------------------------------------------------------------------
# Invalid maps: each problem located by file, line, and tile row / column


def test_unknown_tile_kind(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [straight/E, straight/E]\n- [grass, lava]\ntile_size: 0.585\n")
    msg = str(load_error(path))
    assert_located(msg, path, line=3, row=1, col=1)
    assert f"{path}:3:11:" in msg  # YAML line and column of the tile itself
    assert "unknown tile kind 'lava'" in msg


def test_ragged_rows(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [grass, grass, grass]\n- [grass, grass]\ntile_size: 0.585\n")
    err = load_error(path)
    msg = str(err)
    assert_located(msg, path, line=3, row=1)
    assert "ragged row" in msg and "2 tiles where row 0 has 3" in msg


def test_ragged_row_message_has_no_placeholder_column(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [grass, grass, grass]\n- [grass, grass]\ntile_size: 0.585\n")
    assert "column None" not in str(load_error(path))


@pytest.mark.parametrize("tile", ["straight/X", "straight/north", "curve_left/e"])
def test_bad_orientation(tmp_path, tile):
    path = write_map(tmp_path, f"tiles:\n- [grass, grass]\n- [grass, {tile}]\ntile_size: 0.585\n")
    msg = str(load_error(path))
    assert_located(msg, path, line=3, row=1, col=1)
    assert "bad orientation" in msg and tile in msg


def test_missing_tile_size(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [straight/E, straight/E]\n")
    msg = str(load_error(path))
    assert_located(msg, path, line=1)
    assert "missing 'tile_size'" in msg


@pytest.mark.parametrize("value", ["-1", "0", "abc", "true"])
def test_bad_tile_size(tmp_path, value):
    path = write_map(tmp_path, f"tiles:\n- [straight/E, straight/E]\ntile_size: {value}\n")
    msg = str(load_error(path))
    assert_located(msg, path, line=3)
    assert "'tile_size' must be a positive number" in msg


def test_missing_tiles(tmp_path):
    path = write_map(tmp_path, "tile_size: 0.585\n")
    msg = str(load_error(path))
    assert_located(msg, path, line=1)
    assert "missing 'tiles'" in msg


def test_invalid_yaml(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [straight/E, straight/E\ntile_size: 0.585\n")
    msg = str(load_error(path))
    assert str(path) in msg and "invalid YAML" in msg


def test_road_into_grass(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [grass     , grass]\n- [straight/N, grass]\ntile_size: 0.585\n")
    msg = str(load_error(path))
    assert_located(msg, path, line=3, row=1, col=0)
    assert "leaves through the N edge into 'grass' (row 0, column 0)" in msg


def test_road_into_empty_cell(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [grass, empty     ]\n- [grass, straight/N]\ntile_size: 0.585\n")
    msg = str(load_error(path))
    assert_located(msg, path, line=3, row=1, col=1)
    assert "leaves through the N edge into an empty cell" in msg


def test_road_into_tile_with_closed_edge(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [grass, grass     , grass]\n- [grass, straight/E, straight/N]\n"
                               "- [grass, grass     , grass]\ntile_size: 0.585\n")
    err = load_error(path)
    msg = str(err)
    assert_located(msg, path, line=3, row=1, col=1)
    assert "straight/E: the road leaves through the E edge but straight/N (row 1, column 2)" in msg
    assert "has no road on its W edge" in msg
    # every problem is reported, not just the first: the other tiles' open edges too
    assert len(err.issues) >= 2
    assert all(i.path == str(path) and i.line is not None for i in err.issues)


def test_curve_into_closed_edge(tmp_path):
    # curve_left/S opens north and east; its eastern neighbour must open west
    path = write_map(tmp_path, "tiles:\n- [straight/N  , grass]\n- [curve_left/S, straight/N]\ntile_size: 0.585\n")
    msg = str(load_error(path))
    assert_located(msg, path, line=3, row=1, col=0)
    assert "leaves through the E edge but straight/N (row 1, column 1) has no road on its W edge" in msg


def test_road_ending_at_map_edge_is_accepted(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [straight/N]\n- [straight/N]\ntile_size: 0.585\n")
    m = load_map(path)
    assert sorted(m.road_ends) == [(0, 0, Direction.S), (0, 1, Direction.N)]


def test_object_missing_kind_and_pos(tmp_path):
    text = (
        "tiles:\n- [straight/E, straight/E]\ntile_size: 0.585\nobjects:\n"
        "- kind: duckie\n  pos: [0.5, 0.5]\n"  # fine
        "- pos: [1, 0.5]\n"  # no kind, line 7
        "- kind: duckie\n"  # no pos, line 8
        "- kind: sign\n  pos: [1, 0.5]\n  rotate: north\n"  # bad rotate, line 9
    )
    path = write_map(tmp_path, text)
    err = load_error(path)
    msg = str(err)
    assert len(err.issues) == 3
    assert_located(msg, path, line=7)
    assert "objects[1]: missing or invalid 'kind'" in msg
    assert_located(msg, path, line=8)
    assert "objects[2]: no position: give 'pos: [x, y]' (tiles), 'pose: {~SE2Transform" in msg
    assert_located(msg, path, line=9)
    assert "objects[3]: 'rotate' must be a number" in msg


def test_named_object_with_bad_height(tmp_path):
    text = "tiles:\n- [straight/E]\ntile_size: 0.585\nobjects:\n  duck1:\n    kind: duckie\n    pos: [0.5, 0.5]\n" \
           "    height: -1\n"
    path = write_map(tmp_path, text)
    msg = str(load_error(path))
    assert_located(msg, path, line=6)
    assert "object 'duck1': 'height' must be a positive number" in msg


def test_start_tile_outside_map_falls_back_with_a_warning(tmp_path):
    """gym-duckietown accepts it and starts on a random drivable tile: a warning, not a refusal."""
    path = write_map(tmp_path, "tiles:\n- [straight/E, straight/E]\ntile_size: 0.585\nstart_tile: [5, 0]\n")
    with pytest.warns(MapWarning, match="is outside the map"):
        m = load_map(path)
    assert m.start_tile is None
    (w,) = m.warnings
    assert_located(str(w), path, line=4)
    assert "'start_tile' [5, 0] is outside the map (2×1 tiles): robots start on a random drivable tile" in str(w)


def test_start_tile_not_drivable_falls_back_with_a_warning(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [straight/N, grass]\n- [straight/N, grass]\ntile_size: 0.585\n"
                               "start_tile: [1, 0]\n")
    with pytest.warns(MapWarning, match="not a drivable tile"):
        m = load_map(path)
    assert m.start_tile is None
    (w,) = m.warnings
    assert_located(str(w), path, line=5, row=0, col=1)
    assert "'start_tile' [1, 0] is 'grass', not a drivable tile" in str(w)


def test_start_tile_is_column_then_file_row(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [straight/N, grass]\n- [straight/N, grass]\ntile_size: 0.585\n"
                               "start_tile: [0, 0]\n")
    # file row 0 is the northern row, j = 1
    assert load_map(path).start_tile == (0, 1)


def test_bad_start_pose(tmp_path):
    path = write_map(tmp_path, "tiles:\n- [straight/E]\ntile_size: 0.585\nstart_pose: [1, 2, 3]\n")
    msg = str(load_error(path))
    assert_located(msg, path, line=4)
    assert "'start_pose' must be [[x, y, z], angle]" in msg
