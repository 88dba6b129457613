"""Checks for numeric command-line options, so bad input is a clear error naming the option.

Integers get Typer's own ``min=`` / ``max=``; floats get one of these callbacks, which also refuse
``nan`` and ``inf`` (a range check lets both through):

>>> import typer
>>> from typer.testing import CliRunner
>>> app = typer.Typer()
>>> @app.command()
... def cmd(seconds: float = typer.Option(1.0, callback=positive)):
...     pass
>>> result = CliRunner().invoke(app, ["--seconds", "-5"], env={"COLUMNS": "200"})
>>> result.exit_code, "Invalid value for '--seconds': must be a finite number > 0, got -5.0" in result.output
(2, True)
>>> "got nan" in CliRunner().invoke(app, ["--seconds", "nan"], env={"COLUMNS": "200"}).output
True
"""

from __future__ import annotations

import math

import typer

__all__ = ["non_negative", "positive", "probability"]


def positive(value: float | None) -> float | None:
    """Option callback: a finite number > 0 (a duration, a rate, a cost); None passes (an unset option)."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise typer.BadParameter(f"must be a finite number > 0, got {value}")
    return value


def non_negative(value: float | None) -> float | None:
    """Option callback: a finite number >= 0 (a noise level, a delay); None passes (an unset option)."""
    if value is not None and not (math.isfinite(value) and value >= 0):
        raise typer.BadParameter(f"must be a finite number >= 0, got {value}")
    return value


def probability(value: float | None) -> float | None:
    """Option callback: a probability strictly between 0 and 1 (a confidence, a power); None passes."""
    if value is not None and not (math.isfinite(value) and 0 < value < 1):
        raise typer.BadParameter(f"must be a number between 0 and 1 (exclusive), got {value}")
    return value
