"""Duckietown maps in the gym-duckietown / duckietown-world YAML format, loaded unchanged.

The map frame is duckietown-world's: x points east (along a tile row), y points north (up the file
listing), headings are counter-clockwise from +x. Tile ``(i, j)`` covers
``[i*ts, (i+1)*ts] x [j*ts, (j+1)*ts]`` where ``i`` is the column and ``j`` counts rows from the
*bottom* of the ``tiles:`` listing, so the file reads like a map with north up.

Every problem is reported with the file, the YAML line and column, and the tile's row/column in the
listing, so a user can fix a hand-written map without guessing. What gym-duckietown accepts with a
fallback loads with a warning (``Map.warnings``): a start tile outside the map or off the road, an
unknown object kind. Objects in every placement are read by ``proxybench.domain.map_objects``.

>>> m = load_map("loop_3x3")
>>> (m.width, m.height, m.tile_size)
(3, 3, 0.585)
>>> m.tile(0, 0).kind, m.tile(0, 0).orientation_name
('curve_left', 'S')
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from enum import IntEnum
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from proxybench.domain.map_objects import AprilTag, parse_objects
from proxybench.untrusted import UntrustedInputError, compose_yaml, read_text_file

__all__ = [
    "DRIVABLE_KINDS", "GROUND_KINDS", "NON_DRIVABLE_KINDS", "ROAD_END_KINDS", "Direction", "Map", "MapError",
    "MapIssue", "MapObject", "MapWarning", "Tile", "builtin_map_names", "load_map", "parse_map",
]

#: a map file is read whole: at most this many bytes (a map may come from a recording of another lab)
MAP_MAX_BYTES = 4 << 20


class Direction(IntEnum):
    """Compass directions as quarter turns counter-clockwise from east (the heading's multiple of 90°)."""

    E = 0
    N = 1
    W = 2
    S = 3

    @property
    def opposite(self) -> Direction:
        return Direction((self + 2) % 4)

    @property
    def unit(self) -> tuple[int, int]:
        """Unit vector (dx, dy) in the map frame."""
        return _UNIT[self]

    def rotated(self, quarter_turns: int) -> Direction:
        """This direction turned counter-clockwise by ``quarter_turns`` × 90°."""
        return Direction((self + quarter_turns) % 4)


_UNIT = {Direction.E: (1, 0), Direction.N: (0, 1), Direction.W: (-1, 0), Direction.S: (0, -1)}

DRIVABLE_KINDS = ("straight", "curve_left", "curve_right", "3way_left", "3way_right", "4way")
NON_DRIVABLE_KINDS = ("asphalt", "grass", "floor", "calibration_tile")
#: the plain ground each non-drivable kind is drawn with (a calibration tile is a floor a road may end on)
GROUND_KINDS = {"asphalt": "asphalt", "grass": "grass", "floor": "floor", "calibration_tile": "floor"}
#: non-drivable kinds a road may lead onto, like the map's edge (duckietown-world's calibration maps)
ROAD_END_KINDS = ("calibration_tile",)
EMPTY_KIND = "empty"
DEFAULT_ORIENTATION = Direction.E

# Open edges of each drivable kind drawn heading north (orientation "N"): the orientation is the heading
# of a robot entering the tile from its south edge in the right lane (gym-duckietown's convention: a
# `curve_left/W` is entered heading west and turns left to head south).
_OPEN_EDGES_NORTH: dict[str, tuple[Direction, ...]] = {
    "straight": (Direction.S, Direction.N),
    "curve_left": (Direction.S, Direction.W),
    "curve_right": (Direction.S, Direction.E),
    "3way_left": (Direction.S, Direction.N, Direction.W),
    "3way_right": (Direction.S, Direction.N, Direction.E),
    "4way": (Direction.S, Direction.N, Direction.W, Direction.E),
}


@dataclass(frozen=True)
class Tile:
    """One cell of the map. ``orientation`` is meaningful for drivable kinds only."""

    kind: str
    orientation: Direction
    i: int
    j: int
    row: int
    col: int

    @property
    def drivable(self) -> bool:
        return self.kind in DRIVABLE_KINDS

    @property
    def orientation_name(self) -> str:
        return self.orientation.name

    @property
    def open_edges(self) -> tuple[Direction, ...]:
        """Edges through which the road leaves this tile (empty for non-drivable tiles)."""
        if not self.drivable:
            return ()
        turn = (self.orientation - Direction.N) % 4
        return tuple(sorted(e.rotated(turn) for e in _OPEN_EDGES_NORTH[self.kind]))

    @property
    def label(self) -> str:
        return f"{self.kind}/{self.orientation.name}" if self.drivable else self.kind


@dataclass(frozen=True)
class MapObject:
    """An object placed on the map. ``x``, ``y`` [m] in the map frame, ``heading`` [rad]."""

    kind: str
    x: float
    y: float
    heading: float = 0.0
    height: float | None = None
    scale: float | None = None
    optional: bool = False
    static: bool = True
    name: str | None = None
    tag: AprilTag | None = None


@dataclass(frozen=True)
class MapIssue:
    """One problem found in a map file, located as precisely as the file allows."""

    path: str
    message: str
    line: int | None = None
    column: int | None = None
    row: int | None = None
    col: int | None = None

    def __str__(self) -> str:
        where = self.path
        if self.line is not None:
            where += f":{self.line}"
            if self.column is not None:
                where += f":{self.column}"
        if self.row is None:
            cell = ""
        elif self.col is None:
            cell = f" row {self.row}:"
        else:
            cell = f" row {self.row}, column {self.col}:"
        return f"{where}:{cell} {self.message}"


class MapWarning(UserWarning):
    """A map loaded with a fallback (``Map.warnings``), warned when a file is loaded."""


class MapError(ValueError):
    """A map file could not be loaded; ``issues`` lists every problem found."""

    def __init__(self, issues: list[MapIssue]):
        self.issues = issues
        super().__init__("\n".join(str(i) for i in issues))


@dataclass(frozen=True)
class Map:
    """A validated Duckietown map. Grid access is by ``(i, j)`` = (column, row counted from the bottom)."""

    name: str
    path: str
    tile_size: float
    tiles: tuple[tuple[Tile | None, ...], ...]  # indexed [row][col] in file order (row 0 = north)
    objects: tuple[MapObject, ...] = ()
    start_pose: tuple[float, float, float] | None = None
    start_tile: tuple[int, int] | None = None
    #: (i, j, edge) where a road leaves the map, or runs onto a ``ROAD_END_KINDS`` tile
    road_ends: tuple[tuple[int, int, Direction], ...] = field(default=())
    #: what was accepted with a fallback (unknown object kinds, a start tile off the road), for ``map check``
    warnings: tuple[MapIssue, ...] = field(default=(), compare=False)

    @property
    def width(self) -> int:
        """Number of tile columns (east–west)."""
        return len(self.tiles[0]) if self.tiles else 0

    @property
    def height(self) -> int:
        """Number of tile rows (north–south)."""
        return len(self.tiles)

    @property
    def size_m(self) -> tuple[float, float]:
        return (self.width * self.tile_size, self.height * self.tile_size)

    def tile(self, i: int, j: int) -> Tile | None:
        """The tile at column ``i``, row ``j`` counted from the bottom; None if empty or outside."""
        if 0 <= i < self.width and 0 <= j < self.height:
            return self.tiles[self.height - 1 - j][i]
        return None

    def tile_at(self, x: float, y: float) -> Tile | None:
        """The tile under the map-frame point (x, y) [m]."""
        return self.tile(math.floor(x / self.tile_size), math.floor(y / self.tile_size))

    def iter_tiles(self) -> list[Tile]:
        return [t for row in self.tiles for t in row if t is not None]

    def drivable_tiles(self) -> list[Tile]:
        return [t for t in self.iter_tiles() if t.drivable]

    def summary(self) -> str:
        """One line for ``proxybench map check``."""
        kinds: dict[str, int] = {}
        for t in self.drivable_tiles():
            kinds[t.kind] = kinds.get(t.kind, 0) + 1
        kinds_s = ", ".join(f"{n} {k}" for k, n in sorted(kinds.items()))
        w, h = self.size_m
        n_edge = sum(self.tile(i + d.unit[0], j + d.unit[1]) is None for i, j, d in self.road_ends)
        ends = f", {n_edge} road ends at the map edge" if n_edge else ""
        if len(self.road_ends) > n_edge:
            ends += f", {len(self.road_ends) - n_edge} onto {'/'.join(ROAD_END_KINDS)}"
        return (
            f"{self.width}×{self.height} tiles of {self.tile_size:g} m ({w:.2f} × {h:.2f} m); "
            f"{len(self.drivable_tiles())} drivable ({kinds_s}); {len(self.objects)} objects{ends}"
        )


# ----------------------------------------------------------------------------------------------------
# Loading


def builtin_map_names() -> list[str]:
    """Names of the maps shipped with proxybench (``proxybench/maps/*.yaml``)."""
    root = resources.files("proxybench") / "maps"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".yaml"))


def _builtin_map_path(name: str) -> Path | None:
    root = resources.files("proxybench") / "maps"
    candidate = root / f"{name}.yaml"
    if candidate.is_file():
        return Path(str(candidate))
    return duckietown_world_map(name)


#: the package whose 44 maps (the Autolabs' among them) load by name when it is installed
DUCKIETOWN_WORLD = "duckietown-world-daffy"


def duckietown_world_map(name: str) -> Path | None:
    """The file of duckietown-world's map ``name`` (e.g. ``ETHZ_autolab_technical_track``) if that package is
    installed (``pip install 'proxybench[autolab]'``): found through its file list, never imported."""
    from importlib import metadata

    try:
        files = metadata.files(DUCKIETOWN_WORLD) or []
    except metadata.PackageNotFoundError:
        return None
    for f in files:
        if str(f).endswith(f"/gd1/maps/{name}.yaml"):
            path = Path(str(f.locate()))
            return path if path.is_file() else None
    return None


def load_map(name_or_path: str | Path) -> Map:
    """Load a map by built-in name (``loop_3x3``) or by path to a YAML file.

    Raises:
        MapError: with every problem found (file, line, row and column in each message).
    """
    path = Path(name_or_path)
    if not path.is_file():
        builtin = _builtin_map_path(str(name_or_path)) if "/" not in str(name_or_path) else None
        if builtin is None:
            names = ", ".join(builtin_map_names())
            raise MapError([MapIssue(str(name_or_path), f"no such map file or built-in map (built-in: {names}; "
                                     f"with {DUCKIETOWN_WORLD} installed, its maps too)")])
        path = builtin
    try:
        text = read_text_file(path, max_bytes=MAP_MAX_BYTES)
    except UntrustedInputError as exc:
        raise MapError([MapIssue(str(path), f"cannot read map file: {str(exc).removeprefix(f'{path}: ')}")]) from None
    m = parse_map(text, path=str(path), name=path.stem)
    for w in m.warnings:  # where nobody prints Map.warnings (an env, a runner): once per message and place
        warnings.warn(str(w), MapWarning, stacklevel=2)
    return m


def parse_map(text: str, path: str = "<string>", name: str = "map") -> Map:
    """Parse and validate map YAML text. See :func:`load_map`."""
    return _MapParser(text, path, name).parse()


_NUM = (int, float)


class _MapParser:
    """Walks the YAML node tree (not just the data) so every issue carries a line and column."""

    def __init__(self, text: str, path: str, name: str):
        self.text, self.path, self.name = text, path, name
        self.issues: list[MapIssue] = []
        self.warnings: list[MapIssue] = []

    def warn(self, message: str, node: yaml.Node | None = None, row: int | None = None, col: int | None = None):
        line = node.start_mark.line + 1 if node is not None else None
        column = node.start_mark.column + 1 if node is not None else None
        self.warnings.append(MapIssue(self.path, message, line, column, row, col))

    def issue(self, message: str, node: yaml.Node | None = None, row: int | None = None, col: int | None = None):
        line = node.start_mark.line + 1 if node is not None else None
        column = node.start_mark.column + 1 if node is not None else None
        self.issues.append(MapIssue(self.path, message, line, column, row, col))

    def fail(self) -> MapError:
        return MapError(self.issues)

    def parse(self) -> Map:
        try:  # bounded nesting: a map may come from a recording of another lab
            root = compose_yaml(self.text, max_depth=64)
        except UntrustedInputError as exc:
            self.issues.append(MapIssue(self.path, f"invalid YAML: {exc}"))
            raise self.fail() from None
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            line = mark.line + 1 if mark is not None else None
            self.issues.append(MapIssue(self.path, f"invalid YAML: {exc}", line))
            raise self.fail() from exc
        if not isinstance(root, yaml.MappingNode):
            self.issue("a map file must be a YAML mapping with 'tiles' and 'tile_size'", root)
            raise self.fail()
        keys = {k.value: (k, v) for k, v in root.value if isinstance(k, yaml.ScalarNode)}
        tile_size = self._tile_size(keys, root)
        tiles = self._tiles(keys, root)
        if self.issues:
            raise self.fail()
        assert tiles is not None and tile_size is not None
        grid_h, grid_w = len(tiles), len(tiles[0])
        objects = self._objects(keys.get("objects"), tile_size, grid_w, grid_h)
        origin, start_tile = self._start_tile(keys.get("start_tile"), tiles)
        start_pose = self._start_pose(keys.get("start_pose"), tile_size, grid_h, origin)
        m = Map(self.name, self.path, tile_size, tiles, tuple(objects), start_pose, start_tile)
        ends = self._check_connections(m, keys["tiles"][1])
        if self.issues:
            raise self.fail()
        if not m.drivable_tiles():
            self.warn("no drivable tile: the map loads and draws, but no robot can drive on it", root)
        return Map(self.name, self.path, tile_size, tiles, tuple(objects), start_pose, start_tile, tuple(ends),
                   tuple(self.warnings))

    # -- fields ------------------------------------------------------------------------------------

    def _data(self, node: yaml.Node) -> Any:
        loader = yaml.SafeLoader("")
        return loader.construct_object(node, deep=True)

    def _tile_size(self, keys: dict, root: yaml.Node) -> float | None:
        if "tile_size" not in keys:
            self.issue("missing 'tile_size' (metres per tile; most real maps use 0.585)", root)
            return None
        node = keys["tile_size"][1]
        value = self._data(node)
        if isinstance(value, bool) or not isinstance(value, _NUM) or not math.isfinite(value) or value <= 0:
            self.issue(f"'tile_size' must be a positive number of metres, got {value!r}", node)
            return None
        return float(value)

    def _tiles(self, keys: dict, root: yaml.Node) -> tuple[tuple[Tile | None, ...], ...] | None:
        if "tiles" not in keys:
            self.issue("missing 'tiles' (rows of 'kind/orientation')", root)
            return None
        node = keys["tiles"][1]
        if not isinstance(node, yaml.SequenceNode) or not node.value:
            self.issue("'tiles' must be a non-empty list of rows", node)
            return None
        rows = node.value
        widths = [len(r.value) if isinstance(r, yaml.SequenceNode) else -1 for r in rows]
        width = widths[0]
        grid: list[tuple[Tile | None, ...]] = []
        for r, row_node in enumerate(rows):
            if not isinstance(row_node, yaml.SequenceNode):
                self.issue("each row of 'tiles' must be a list of tiles", row_node, row=r)
                continue
            if len(row_node.value) != width:
                self.issue(f"ragged row: {len(row_node.value)} tiles where row 0 has {width}", row_node, row=r)
            cells: list[Tile | None] = []
            for c, cell in enumerate(row_node.value):
                cells.append(self._tile(cell, r, c, len(rows)))
            grid.append(tuple(cells))
        if width <= 0:
            self.issue("row 0 of 'tiles' is empty", rows[0], row=0)
        return tuple(grid)

    def _tile(self, node: yaml.Node, r: int, c: int, n_rows: int) -> Tile | None:
        if not isinstance(node, yaml.ScalarNode) or not isinstance(self._data(node), str):
            self.issue("a tile must be a string like 'straight/E'", node, r, c)
            return None
        text = node.value.strip()
        kind, _, orient = text.partition("/")
        kind = kind.strip()
        if kind == EMPTY_KIND:
            return None
        if kind not in DRIVABLE_KINDS and kind not in NON_DRIVABLE_KINDS:
            known = ", ".join(DRIVABLE_KINDS + NON_DRIVABLE_KINDS + (EMPTY_KIND,))
            self.issue(f"unknown tile kind {kind!r} in {text!r} (known: {known})", node, r, c)
            return None
        orientation = DEFAULT_ORIENTATION
        if orient:
            orient = orient.strip()
            if orient not in Direction.__members__:
                self.issue(f"bad orientation {orient!r} in {text!r} (one of N, E, S, W)", node, r, c)
                return None
            orientation = Direction[orient]
        return Tile(kind, orientation, i=c, j=n_rows - 1 - r, row=r, col=c)

    def _objects(self, entry: tuple | None, ts: float, grid_w: int, grid_h: int) -> list[MapObject]:
        node = entry[1] if entry is not None else None
        if node is None or (isinstance(node, yaml.ScalarNode) and self._data(node) is None):
            return []
        if isinstance(node, yaml.MappingNode):
            items = [(str(self._data(k)), v) for k, v in node.value]
        elif isinstance(node, yaml.SequenceNode):
            items = [(None, v) for v in node.value]
        else:
            self.issue("'objects' must be a list or a mapping of objects", node)
            return []
        objects, errors, warnings = parse_objects(items, self._data, ts, grid_w, grid_h, MapObject)
        for message, at in errors:
            self.issue(message, at)
        for message, at in warnings:
            self.warn(message, at)
        return objects

    def _start_tile(self, entry: tuple | None, tiles) -> tuple[tuple[int, int] | None, tuple[int, int] | None]:
        """(origin (i, j) of a relative start pose, start tile of the start distribution). As in gym-duckietown, one
        outside the map or off the road falls back to a random drivable tile (a warning); off-road, it anchors."""
        if entry is None:
            return None, None
        node = entry[1]
        value = self._data(node)
        if not (isinstance(value, list) and len(value) == 2
                and all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
            self.issue(f"'start_tile' must be [column, row], got {value!r}", node)
            return None, None
        c, r = value
        if not (0 <= r < len(tiles) and 0 <= c < len(tiles[r])):
            self.warn(f"'start_tile' {value} is outside the map ({len(tiles[0])}×{len(tiles)} tiles): "
                      "robots start on a random drivable tile instead (as gym-duckietown does)", node)
            return None, None
        tile = tiles[r][c]
        origin = (c, len(tiles) - 1 - r)
        if tile is None or not tile.drivable:
            what = "an empty cell" if tile is None else repr(tile.kind)
            self.warn(f"'start_tile' {value} is {what}, not a drivable tile: robots start on a random drivable "
                      "tile instead (as gym-duckietown does)", node, r, c)
            return origin, None
        return origin, (tile.i, tile.j)

    def _start_pose(self, entry: tuple | None, ts: float, grid_h: int,
                    origin: tuple[int, int] | None) -> tuple[float, float, float] | None:
        """The map-frame start pose. gym-duckietown writes ``[[x, y, z], angle]`` with z counting down the
        listing, absolute (its original maps), or from the north-west corner of ``start_tile`` when the
        map gives one (duckietown-world-daffy's maps, whose simulator reads it so)."""
        if entry is None:
            return None
        node = entry[1]
        value = self._data(node)
        ok = isinstance(value, list) and len(value) == 2 and isinstance(value[0], list)
        if ok:
            pos, angle = value
            ok = (len(pos) in (2, 3) and all(isinstance(p, _NUM) and not isinstance(p, bool) for p in pos)
                  and isinstance(angle, _NUM) and not isinstance(angle, bool))
        if not ok:
            self.issue(f"'start_pose' must be [[x, y, z], angle] (metres, radians), got {value!r}", node)
            return None
        x, z = float(pos[0]), float(pos[-1])
        if origin is not None:
            x, z = x + origin[0] * ts, z + (grid_h - 1 - origin[1]) * ts
        return (x, grid_h * ts - z, float(angle))

    # -- topology ----------------------------------------------------------------------------------

    def _check_connections(self, m: Map, tiles_node: yaml.SequenceNode) -> list[tuple[int, int, Direction]]:
        """Every open edge must face a drivable tile that opens back, or the map's edge (a road end)."""
        ends = []
        for tile in m.drivable_tiles():
            cell_node = tiles_node.value[tile.row].value[tile.col]
            for edge in tile.open_edges:
                dx, dy = edge.unit
                other = m.tile(tile.i + dx, tile.j + dy)
                inside = 0 <= tile.i + dx < m.width and 0 <= tile.j + dy < m.height
                if other is None:
                    if inside:
                        self.issue(
                            f"{tile.label}: the road leaves through the {edge.name} edge into an empty cell",
                            cell_node, tile.row, tile.col,
                        )
                    else:
                        ends.append((tile.i, tile.j, edge))
                elif other.kind in ROAD_END_KINDS:
                    ends.append((tile.i, tile.j, edge))
                elif not other.drivable:
                    self.issue(
                        f"{tile.label}: the road leaves through the {edge.name} edge into "
                        f"{other.kind!r} (row {other.row}, column {other.col})",
                        cell_node, tile.row, tile.col,
                    )
                elif edge.opposite not in other.open_edges:
                    self.issue(
                        f"{tile.label}: the road leaves through the {edge.name} edge but {other.label} "
                        f"(row {other.row}, column {other.col}) has no road on its {edge.opposite.name} edge",
                        cell_node, tile.row, tile.col,
                    )
        return ends
