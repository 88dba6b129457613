"""How a DTPS robot target is driven, on the command line (``--target dtps:…`` of the studies and ``target record``).

The options users reach for are flags (``--dtps-reset``, ``--dtps-kind``); every field of
:class:`~proxybench.dtps.robot_options.DtpsRobotOptions` is settable with ``--dtps-option KEY=VALUE``
(repeat), or in an experiment file's ``dtps_options:`` section. A bad value is a usage error naming it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

__all__ = ["DtpsKind", "DtpsOption", "DtpsReset", "dtps_option_values"]

DtpsReset = Annotated[str | None, typer.Option(
    "--dtps-reset", help="a DTPS robot's episode starts: prompt (an operator places it; default), teleport "
                         "(state/reset: the Duckiematrix) or pose-file (starts recorded beforehand: "
                         "--dtps-option start_poses=FILE)")]
DtpsKind = Annotated[str | None, typer.Option(
    "--dtps-kind", help="what the DTPS robot is, as you know it: real | simulated (proxybench cannot tell; the "
                        "report says what you said)")]
DtpsOption = Annotated[list[str], typer.Option(
    "--dtps-option", help="a DTPS robot option KEY=VALUE (repeat): pose, pose_url, pwm, start_poses, reset_input, "
                          "pose_tolerance, wheel_distance, start_timeout, stale_timeout, reset_timeout, watchdog, "
                          "stop_grace (docs/dtps.md)")]

_PATHS = ("start_poses", "reset_input")  # relative to where the command runs: made absolute


def dtps_option_values(reset: str | None, kind: str | None, items: list[str]) -> dict[str, Any]:
    """The DTPS robot options given (unset ones left out, so an experiment file's stay), checked by
    ``DtpsRobotOptions``; file paths made absolute."""
    import yaml
    from pydantic import ValidationError

    from proxybench.dtps.robot_options import DtpsRobotOptions

    given: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise typer.BadParameter(f"{item!r} is not KEY=VALUE", param_hint="--dtps-option")
        key = key.strip()
        if key not in DtpsRobotOptions.model_fields:
            raise typer.BadParameter(f"unknown option {key!r} (known: {', '.join(DtpsRobotOptions.model_fields)})",
                                     param_hint="--dtps-option")
        given[key] = raw if key in _PATHS or key in ("pose", "pose_url", "pwm") else yaml.safe_load(raw)
    for key, value in (("reset", reset), ("kind", kind)):
        if value is not None:
            given[key] = value
    for key in _PATHS:
        if key in given:
            given[key] = str(Path(given[key]).expanduser().resolve())
    probe = dict(given)  # the file may hold the other half of a pair (reset pose-file + start_poses)
    if probe.get("reset") == "pose-file":
        probe.setdefault("start_poses", "-")
    elif "start_poses" in probe and "reset" not in probe:
        probe["reset"] = "pose-file"
    if given:
        try:
            DtpsRobotOptions(**probe)
        except ValidationError as exc:
            err = exc.errors()[0]
            where = {"reset": "--dtps-reset", "kind": "--dtps-kind"}.get(str(err["loc"][0]) if err["loc"] else "",
                                                                       "--dtps-option")
            raise typer.BadParameter(err["msg"].removeprefix("Value error, "), param_hint=where) from None
    return given
