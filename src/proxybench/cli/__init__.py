"""The ``proxybench`` command line: thin Typer commands over the library, one module per topic."""

from proxybench.cli import (  # noqa: F401 - importing registers the commands
    agents,
    autolab,
    drive,
    dtps,
    evaluate,
    evaluator,
    gym,
    learning,
    maps,
    params,
    results,
    robot,
    sandbox,
    server,
    targets,
)
from proxybench.cli.app import app
from proxybench.cli.studies import add_study_commands

add_study_commands(app)  # one command per registered study

__all__ = ["app", "main"]


def main() -> None:
    app()
