"""A DTPS robot as a target: where it is (``dtps:HOST[:PORT]/PATH``) and how proxybench drives it.

A real DB21 serves its topics at ``http://<name>.local:11911/<name>/…``; a Duckiematrix robot at
``http://127.0.0.1:7501/robot/map_0/vehicle_0/…``. The address names the server and the robot's path on
it, so both are written the same way::

    dtps:mybot.local/mybot                       # a real robot (port 11911 by default)
    dtps:127.0.0.1:7501/robot/map_0/vehicle_0    # a Duckiematrix robot

proxybench cannot tell a Duckiematrix robot from a real one over DTPS; ``kind`` is what the user says it is.

>>> parse_address("dtps:mybot.local/mybot")
DtpsAddress(host='mybot.local', port=11911, path='mybot')
>>> parse_address("127.0.0.1:7501/robot/map_0/vehicle_0").url
'http://127.0.0.1:7501/'
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["DEFAULT_ROBOT_PORT", "DTPS_PREFIX", "DtpsAddress", "DtpsRobotOptions", "load_start_poses",
           "parse_address"]

DTPS_PREFIX = "dtps:"
#: a real Duckiebot's DTPS switchboard port (duckietown-sdk's DEFAULT_ROBOT_SWITCHBOARD_PORT)
DEFAULT_ROBOT_PORT = 11911
_ADDRESS = re.compile(r"^(?P<host>[A-Za-z0-9._-]+|\[[0-9A-Fa-f:]+\])(?::(?P<port>\d{1,5}))?"
                      r"/(?P<path>[A-Za-z0-9._/-]+)$")


@dataclass(frozen=True)
class DtpsAddress:
    """A robot on a DTPS server: ``host``, ``port`` and the ``path`` its topics live under."""

    host: str
    port: int
    path: str

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/"

    def __str__(self) -> str:
        return f"{self.host}:{self.port}/{self.path}"


def parse_address(text: str) -> DtpsAddress:
    """``[dtps:]HOST[:PORT]/PATH`` → :class:`DtpsAddress`; a ``ValueError`` saying what is wrong otherwise."""
    body = text.strip().removeprefix(DTPS_PREFIX).strip()
    m = _ADDRESS.match(body)
    if m is None:
        raise ValueError(f"{text!r} is not a DTPS robot address: expected dtps:HOST[:PORT]/PATH, e.g. "
                         "dtps:mybot.local/mybot or dtps:127.0.0.1:7501/robot/map_0/vehicle_0")
    port = int(m.group("port") or DEFAULT_ROBOT_PORT)
    if not 1 <= port <= 65535:
        raise ValueError(f"{text!r}: port {port} is not within 1…65535")
    path = m.group("path").strip("/")
    if not path or any(part in ("", ".", "..") for part in path.split("/")):
        raise ValueError(f"{text!r}: the robot's path {m.group('path')!r} is not a plain path of names")
    return DtpsAddress(m.group("host"), port, path)


class DtpsRobotOptions(BaseModel):
    """How proxybench drives a DTPS robot (docs/dtps.md, "Connect a robot").

    ``pose``: the pose topic under the robot (``state/pose``), or ``/PATH`` from a server's root (a
    localisation system), on ``pose_url`` when it is another server; poses are in the map's frame (metres
    from its bottom-left corner, radians), as a Transformation or ``{x, y, theta}``. ``pwm``: the wheel
    topic (a real DB21's driver listens on ``actuator/wheels/base/pwm``; the Duckiematrix on
    ``…/pwm_filtered``). ``reset``: how each episode starts: ``prompt`` (an operator places the robot at the
    start pose proxybench prints and presses Enter; answers come from ``reset_input`` instead of the terminal
    when given), ``teleport`` (publish ``state/reset``: the Duckiematrix puts the robot back at its own
    start, which becomes the episode's), or ``pose-file`` (the starts were recorded beforehand in
    ``start_poses``; proxybench waits until the robot stands at the episode's). ``pose_tolerance``: how
    close [m, rad] the robot must stand to the start. ``kind``: what *you* say the robot is (proxybench
    cannot tell). Timeouts [s]: ``start_timeout`` (the bridge, the first pose), ``stale_timeout`` (the
    longest silence of camera or pose in an episode before the connection counts as lost),
    ``reset_timeout`` (an operator's answer, a robot reaching its start), ``watchdog`` (no command for this
    long: the bridge sends (0, 0)), ``stop_grace`` (how long the bridge tries to deliver its final (0, 0)).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    pose: str = Field("state/pose", min_length=1, description="pose topic (under the robot, or /PATH)")
    pose_url: str | None = Field(None, min_length=1, description="the localisation server's URL, if not the robot's")
    pwm: str = Field("actuator/wheels/base/pwm", min_length=1, description="wheel command topic")
    reset: Literal["prompt", "teleport", "pose-file"] = Field("prompt", description="prompt | teleport | pose-file")
    start_poses: str | None = Field(None, min_length=1, description="pose-file: the file of start poses")
    reset_input: str | None = Field(None, min_length=1, description="prompt: read answers from this file")
    pose_tolerance: tuple[float, float] = Field((0.05, 0.2), description="[m, rad] from the start pose")
    kind: Literal["real", "simulated"] | None = Field(None, description="what you say the robot is")
    wheel_distance: float = Field(0.102, gt=0.0, le=1.0, description="the robot's wheel distance [m]")
    start_timeout: float = Field(60.0, gt=0.0, allow_inf_nan=False, description="bridge start, first pose [s]")
    stale_timeout: float = Field(1.0, gt=0.0, allow_inf_nan=False, description="sensor silence = lost [s]")
    reset_timeout: float = Field(600.0, gt=0.0, allow_inf_nan=False, description="operator answer, reaching start")
    watchdog: float = Field(0.5, gt=0.0, allow_inf_nan=False, description="no command this long: (0, 0) [s]")
    stop_grace: float = Field(3.0, ge=0.0, allow_inf_nan=False, description="delivering the final (0, 0) [s]")

    @model_validator(mode="after")
    def _consistent(self) -> DtpsRobotOptions:
        if self.reset == "pose-file" and self.start_poses is None:
            raise ValueError("reset pose-file needs start_poses (the file of start poses)")
        if self.reset != "pose-file" and self.start_poses is not None:
            raise ValueError(f"start_poses is only read with reset pose-file (reset is {self.reset!r})")
        if not all(math.isfinite(v) and v > 0 for v in self.pose_tolerance):
            raise ValueError(f"pose_tolerance must be two positive numbers [m, rad], got {self.pose_tolerance}")
        return self

    def non_default(self) -> dict[str, Any]:
        return self.model_dump(exclude_defaults=True)

    def items(self) -> tuple[tuple[str, Any], ...]:
        """The non-default fields as sorted pairs (hashable, for ``DomainSpec``)."""
        return tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in self.non_default().items()))

    def key_data(self) -> dict[str, Any]:
        """What changes an episode on the robot (part of a job's key): where the pose comes from, which wheel
        topic, how episodes start. Timeouts, the prompt's input and the tolerance do not."""
        return {k: v for k, v in self.non_default().items() if k in ("pose", "pose_url", "pwm", "reset")}


def load_start_poses(path: str | Path, episodes: list[int]) -> dict[int, tuple[float, float, float]]:
    """The start pose of each of ``episodes`` from a YAML or JSON file: one ``[x, y, theta]`` for every episode,
    a list of them (index = episode id) or a mapping ``{episode: [x, y, theta]}`` (metres, radians, map frame).
    A ``ValueError`` names the file and the entry at fault."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the start poses ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not YAML or JSON ({exc})") from None

    def pose(value: Any, where: str) -> tuple[float, float, float]:
        ok = isinstance(value, list | tuple) and len(value) == 3 and all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value)
        if not ok:
            raise ValueError(f"{path}: {where}: expected [x, y, theta] (three finite numbers), got {value!r}")
        return (float(value[0]), float(value[1]), float(value[2]))

    if isinstance(data, list) and len(data) == 3 and all(isinstance(v, int | float) for v in data):
        one = pose(data, "the start pose")
        return dict.fromkeys(episodes, one)
    if isinstance(data, list):
        table = {i: v for i, v in enumerate(data)}
    elif isinstance(data, dict):
        table = {}
        for k, v in data.items():
            try:
                table[int(k)] = v
            except (TypeError, ValueError):
                raise ValueError(f"{path}: key {k!r} is not an episode id") from None
    else:
        raise ValueError(f"{path}: expected [x, y, theta], a list of them or a mapping episode → pose, got "
                         f"{type(data).__name__}")
    missing = [e for e in episodes if e not in table]
    if missing:
        raise ValueError(f"{path}: no start pose for episode(s) {', '.join(map(str, missing[:10]))}")
    return {e: pose(table[e], f"episode {e}") for e in episodes}
