"""One command per registered study (:func:`proxybench.experiments.study.studies`), generated: the study's config
fields as options (:mod:`proxybench.cli.config_options`), and once for all of them ``--quick``, ``--out``,
``--backend``, ``--workers`` and ``--config``; a bar per stage while it runs, its problems as clean errors (never a
traceback), then its report and what the terminal shows.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer

from proxybench.cli.app import app, console, fail
from proxybench.cli.config_options import study_options
from proxybench.cli.progress import stage_bars, stage_progress
from proxybench.experiments.study import Study, studies

__all__ = ["BackendOption", "WorkersOption", "add_study_commands", "run_study", "study_command"]

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
            raise fail(exc, 2, mark="✗") from None
        finally:
            be.close()


def study_command(st: Study[Any, Any]) -> Callable[..., None]:
    """The command of study ``st``: its generated options and the shared ones; runs it, writes and shows its report."""

    def command(cfg: Any, quick: bool = False, out: Path = Path(st.out), backend: BackendOption = "local",
                workers: WorkersOption = None) -> None:
        t0 = time.perf_counter()
        result = run_study(backend, workers, lambda be, progress: st.run(cfg, out, be, progress, quick=quick))
        wall = time.perf_counter() - t0
        files = st.write_report(result, out, wall=wall)
        st.show(result, console, wall=wall)
        if files:
            console.print(f"wrote {', '.join(str(p) for p in files)}", highlight=False, markup=False)

    defaults = command.__defaults__
    assert defaults is not None
    command.__annotations__ = dict(command.__annotations__)
    command.__defaults__ = (typer.Option(False, "--quick", help=st.quick_help),
                            typer.Option(Path(st.out), help=st.out_help), *defaults[2:])
    command.__name__ = command.__qualname__ = st.name.replace("-", "_")
    command.__doc__ = st.help
    return study_options(st.config, load=lambda path, over, own: st.load(path, over, quick=own["quick"]),
                         exclude=st.exclude, defaults=st.help_defaults(), config_help=st.config_help)(command)


def add_study_commands(target: typer.Typer = app) -> list[str]:
    """A command on ``target`` for every registered study; their names."""
    names = []
    for name, st in studies().items():
        target.command(name)(study_command(st))
        names.append(name)
    return names
