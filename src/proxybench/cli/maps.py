"""`proxybench map ...`: check, draw and list Duckietown map files."""

from __future__ import annotations

from pathlib import Path

import typer

from proxybench.cli.app import console, err_console, map_app


@map_app.command("check")
def map_check(files: list[Path] = typer.Argument(..., help="map YAML files or built-in names")) -> None:
    """Validate map files; print a one-line summary each. Exit 1 if any is invalid."""
    from proxybench.domain.maps import MapError, load_map

    bad = 0
    for f in files:
        try:
            m = load_map(f if f.exists() else str(f))
        except MapError as exc:
            bad += 1
            err_console.print(f"[red]✗[/red] {f}: {len(exc.issues)} problem(s)")
            for issue in exc.issues:
                err_console.print(f"    {issue}", markup=False, highlight=False)
            continue
        except (FileNotFoundError, IsADirectoryError, UnicodeDecodeError) as exc:
            bad += 1
            err_console.print(f"[red]✗[/red] {f}: {exc}", highlight=False)
            continue
        console.print(f"[green]✓[/green] {f}: {m.summary()}", highlight=False)
    if bad:
        raise typer.Exit(1)


@map_app.command("show")
def map_show(
    file: str = typer.Argument(..., help="map YAML file or built-in name"),
    output: Path | None = typer.Option(None, "-o", "--output", help="PNG path (default: <map name>.png)"),
) -> None:
    """Draw a map top-down with its lane centre lines (arrows: driving direction) to a PNG."""
    from proxybench.domain.maps import MapError, load_map
    from proxybench.domain.topdown import save_map_plot

    try:
        m = load_map(file)
    except (MapError, FileNotFoundError) as exc:
        err_console.print(f"[red]error:[/red] {exc}", highlight=False)
        raise typer.Exit(1) from exc
    path = save_map_plot(m, output or Path(f"{m.name}.png"))
    console.print(f"wrote {path}")


@map_app.command("list")
def map_list() -> None:
    """List the built-in maps."""
    from proxybench.domain.maps import builtin_map_names, load_map

    for name in builtin_map_names():
        console.print(f"{name:16s} {load_map(name).summary()}", highlight=False)
