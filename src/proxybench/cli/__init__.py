"""The ``proxybench`` command line: thin Typer commands over the library, one module per topic."""

from proxybench.cli import (  # noqa: F401 - importing registers the commands
    agents,
    drive,
    dtps,
    evaluate,
    evaluator,
    heldout,
    learning,
    maps,
    params,
    plan,
    robot,
    sandbox,
    server,
    targets,
    usefulness,
)
from proxybench.cli.app import app

__all__ = ["app", "main"]


def main() -> None:
    app()
