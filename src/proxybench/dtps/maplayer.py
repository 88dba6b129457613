"""A proxybench map as the Duckiematrix's map layer (``map/frames``, ``map/tiles``, ``map/tile_maps``).

The Duckiematrix describes a town as layers keyed by object (``map_0``, ``map_0/tile_2_0``, …): ``frames``
places each key (metres, radians, ``relative_to`` another key), ``tiles`` says what each tile is (``i`` east,
``j`` north from the bottom-left tile, ``type``, and ``orientation`` for road tiles), ``tile_maps`` gives
the tile size. Each layer travels as a duckietown-messages ``Dictionary`` (``{header, data: layer}``).
Tile types are the map file's kinds (``straight``, ``curve_left``, ``3way_right``, ``4way``, ``floor``, …),
as duckietown-world's layer loader reads them; the orientation is the map file's (the heading of a robot
entering the tile from its south edge in the right lane). Objects are placed as frames
``map_0/<kind>_<k>`` at their centre.

>>> from proxybench.domain.maps import load_map
>>> layers = map_layers(load_map("loop_3x3"))
>>> layers["tile_maps"]["map_0"]["tile_size"]["x"]
0.585
>>> layers["tiles"]["map_0/tile_0_0"]["type"], sorted(layers["frames"]["map_0/tile_0_0"]["pose"])[:3]
('curve_left', ['pitch', 'roll', 'x'])
"""

from __future__ import annotations

import math
from typing import Any

from proxybench.domain.maps import Map

__all__ = ["MAP_NAME", "map_layers"]

#: the map's key, as the Duckiematrix names its first map (an SDK agent's robot is ``map_0/vehicle_0``)
MAP_NAME = "map_0"


def _pose(x: float, y: float, yaw: float) -> dict[str, float]:
    return {"x": float(x), "y": float(y), "z": 0.0, "roll": 0.0, "pitch": 0.0, "yaw": float(yaw)}


def map_layers(m: Map, name: str = MAP_NAME) -> dict[str, dict[str, Any]]:
    """The three layers of ``m`` (``frames``, ``tiles``, ``tile_maps``), each a mapping of keys to entries."""
    ts = m.tile_size
    frames: dict[str, Any] = {name: {"relative_to": None, "pose": _pose(0, 0, 0)}}
    tiles: dict[str, Any] = {}
    for t in m.iter_tiles():
        key = f"{name}/tile_{t.i}_{t.j}"
        yaw = t.orientation * math.pi / 2 if t.drivable else 0.0
        frames[key] = {"relative_to": name, "pose": _pose((t.i + 0.5) * ts, (t.j + 0.5) * ts, yaw)}
        tiles[key] = {"i": t.i, "j": t.j, "type": t.kind} | ({"orientation": t.orientation.name} if t.drivable else {})
    for k, obj in enumerate(m.objects):
        frames[f"{name}/{obj.kind}_{k}"] = {"relative_to": name, "pose": _pose(obj.x, obj.y, obj.heading)}
    return {"frames": frames, "tiles": tiles, "tile_maps": {name: {"tile_size": {"x": ts, "y": ts}}}}
