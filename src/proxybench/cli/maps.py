"""`proxybench map ...`: check, draw and list Duckietown map files."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import typer
from rich.markup import escape

from proxybench.cli.app import console, err_console, fail, map_app

if TYPE_CHECKING:
    from proxybench.domain.maps import Map


def load_map_printing_warnings(name: str | Path, print_warnings: bool = True) -> Map:
    """``load_map`` for commands: what the map loaded with by a fallback as yellow lines on stderr (not as
    Python warnings). Raises ``MapError`` / ``OSError`` as ``load_map`` does."""
    from proxybench.domain.maps import MapWarning, load_map

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MapWarning)
        m = load_map(name)
    if print_warnings:
        for w in m.warnings:
            err_console.print(f"[yellow]warning:[/yellow] {escape(str(w))}", highlight=False)
    return m


@map_app.command("check")
def map_check(files: list[Path] = typer.Argument(..., help="map YAML files or built-in names")) -> None:
    """Validate map files; print a one-line summary each, and what was accepted with a fallback (warnings).

    Exit 1 if any map is invalid; warnings alone (an unknown object kind, a start tile off the road)
    do not fail the check, as gym-duckietown loads such maps too.
    """
    from proxybench.domain.maps import MapError

    bad = 0
    for f in files:
        name = escape(str(f))
        try:
            m = load_map_printing_warnings(f if f.exists() else str(f), print_warnings=False)
        except MapError as exc:
            bad += 1
            err_console.print(f"[red]✗[/red] {name}: {len(exc.issues)} problem(s)", highlight=False)
            for issue in exc.issues:
                err_console.print(f"    {issue}", markup=False, highlight=False)
            continue
        except (OSError, UnicodeDecodeError) as exc:
            bad += 1
            err_console.print(f"[red]✗[/red] {name}: {escape(str(exc))}", highlight=False)
            continue
        console.print(f"[green]✓[/green] {name}: {escape(m.summary())}", highlight=False)
        for warning in m.warnings:
            console.print(f"    [yellow]warning:[/yellow] {escape(str(warning))}", highlight=False)
    if bad:
        raise typer.Exit(1)


@map_app.command("show")
def map_show(
    file: str = typer.Argument(..., help="map YAML file or built-in name"),
    output: Path | None = typer.Option(None, "-o", "--output",
                                       help="image path, PNG (default: <map name>.png); missing folders are made"),
) -> None:
    """Draw a map top-down with its lane centre lines (arrows: driving direction) to a PNG."""
    from proxybench.domain.maps import MapError
    from proxybench.domain.topdown import save_map_plot

    try:
        m = load_map_printing_warnings(file)
    except (MapError, OSError) as exc:
        raise fail(exc) from exc
    path = output or Path(f"{m.name}.png")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path = save_map_plot(m, path)
    except (OSError, ValueError) as exc:  # a folder in the way, no permission, an image format matplotlib lacks
        raise fail(f"--output: cannot write {path}: {getattr(exc, 'strerror', None) or exc}") from exc
    console.print(f"wrote {escape(str(path))}", highlight=False)


@map_app.command("list")
def map_list() -> None:
    """List the built-in maps."""
    from proxybench.domain.maps import builtin_map_names

    for name in builtin_map_names():
        console.print(f"{name:16s} {load_map_printing_warnings(name).summary()}", highlight=False, markup=False)
