"""What the study commands share beyond their generated options: ``--backend`` / ``--workers``, and running a
study with a backend, a bar per stage and its problems as clean errors (never a traceback)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any, TypeVar

import typer

from proxybench.cli.config_options import fail
from proxybench.cli.progress import stage_bars, stage_progress

__all__ = ["BackendOption", "WorkersOption", "run_study"]

T = TypeVar("T")

BackendOption = Annotated[str, typer.Option(help="inline | local (process pool) | ray")]
WorkersOption = Annotated[int | None, typer.Option(min=1, help="parallel workers (default: one per core)")]


def run_study(backend: str, workers: int | None, run: Callable[[Any, Callable[[str, int, int], None]], T]) -> T:
    """``run(backend, progress)`` with the named backend (closed after) and a bar per stage; a target or a value
    the study cannot use ends the command with its message (exit 2)."""
    from proxybench.runner.backends import make_backend
    from proxybench.targets.manifest import TargetError

    be = make_backend(backend, workers)
    with stage_bars() as bar:
        try:
            return run(be, stage_progress(bar))
        except (TargetError, ValueError) as exc:
            fail(exc)
        finally:
            be.close()
