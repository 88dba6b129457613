"""The ``proxybench`` command line: thin Typer commands over the library, one module per topic."""

from proxybench.cli import (  # noqa: F401 - importing registers the commands
    agents,
    autolab,
    drive,
    dtps,
    evaluate,
    evaluator,
    gym,
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
    validate,
)
from proxybench.cli.app import app

__all__ = ["app", "main"]


def main() -> None:
    app()
