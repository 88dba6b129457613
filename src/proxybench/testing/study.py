"""The contract every registered study passes (``proxybench.experiments.study.Study``): a config that loads and
refuses what it does not know, a generated command whose ``--help`` offers its options, and a report written
from a canned result alone.

The study is taken as it is (duck-typed: this layer sits below the studies), and its command, where given, is
the one the command line generates (``proxybench.cli.studies.study_command``)::

    from proxybench.cli.studies import study_command
    from proxybench.experiments.study import studies
    from proxybench.testing import StudyContract

    for st in studies().values():
        StudyContract(st, study_command(st)).check_all()
"""

from __future__ import annotations

import io
import re
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from proxybench.testing.results import CheckFailed, Contract

__all__ = ["StudyContract"]

#: a command's name: lower case words joined by dashes
NAME = re.compile(r"^[a-z][a-z0-9]*(-[a-z0-9]+)*$")


class StudyContract(Contract):
    """Checks of one registered study; ``command``: its generated command (the ``command`` check needs it)."""

    CHECKS = ("identity", "config", "command", "report")
    title = "study contract"

    def __init__(self, study: Any, command: Callable[..., Any] | None = None):
        super().__init__()
        self.study = study
        self.command = command
        self.subject = f"study {getattr(study, 'name', type(study).__name__)!r}"

    def check_identity(self) -> tuple[bool, str]:
        st = self.study
        name = getattr(st, "name", None)
        if not isinstance(name, str) or not NAME.match(name):
            raise CheckFailed(f"name {name!r}: a command name (lower case words joined by dashes)")
        for attr in ("help", "out", "quick_help", "out_help"):
            if not str(getattr(st, attr, "") or "").strip():
                raise CheckFailed(f"{attr}: empty (the command's --help shows it)")
        if not hasattr(getattr(st, "config", None), "model_fields"):
            raise CheckFailed("config: not a config model (a StudyConfig)")
        return True, f"{name}: help, default --out {st.out!r}, config {st.config.__name__}"

    def check_config(self) -> tuple[bool, str]:
        st = self.study
        full, quick = st.load(None, {}, quick=False), st.load(None, {}, quick=True)
        for cfg in (full, quick):
            if not isinstance(cfg, st.config):
                raise CheckFailed(f"load: gave a {type(cfg).__name__}, not its config {st.config.__name__}")
        try:
            st.load(None, {"no_such_field": 1})
        except Exception as exc:  # any refusal will do, if it names the key
            if "no_such_field" not in str(exc):
                raise CheckFailed(f"an unknown key is refused without naming it: {exc}") from None
        else:
            raise CheckFailed("an unknown key (no_such_field) was accepted")
        try:
            setattr(full, next(iter(st.config.model_fields)), None)
        except Exception:  # frozen: any refusal
            pass
        else:
            raise CheckFailed("the config can be changed after it is loaded (it must be frozen)")
        return True, f"defaults load (full and --quick); unknown keys refused; frozen ({len(st.config.model_fields)} " \
                     "fields)"

    def check_command(self) -> tuple[bool, str]:
        if self.command is None:
            raise CheckFailed("no command given: StudyContract(study, study_command(study))")
        import typer
        from typer.testing import CliRunner

        app = typer.Typer()
        app.command(self.study.name)(self.command)
        app.command("_other")(lambda: None)  # two commands: the study's is called by name, as in proxybench
        res = CliRunner().invoke(app, [self.study.name, "--help"], env={"COLUMNS": "400", "NO_COLOR": "1"})
        if res.exit_code != 0:
            raise CheckFailed(f"--help exited {res.exit_code}: {res.output[-300:]}")
        options = [o.option for o in getattr(self.command, "study_options", [])]
        missing = [o for o in ("--config", "--quick", "--out", "--backend", "--workers", *options)
                   if o not in res.output]
        if missing:
            raise CheckFailed(f"--help does not offer {', '.join(missing)}")
        return True, f"--help offers the shared options and {len(options)} of the config's"

    def check_report(self) -> tuple[bool, str]:
        from rich.console import Console

        result = self.study.example()
        if result is None:
            raise CheckFailed("no canned result (Study.example): the report cannot be checked without a run")
        with tempfile.TemporaryDirectory() as tmp:
            files = self.study.write_report(result, Path(tmp), wall=1.0)
            absent = [str(p) for p in files if not Path(p).is_file()]
            if not files or absent:
                raise CheckFailed(f"write_report named files it did not write: {', '.join(absent) or 'none named'}")
            shown = io.StringIO()
            self.study.show(result, Console(file=shown, width=160), wall=1.0)
            return True, f"{len(files)} files from a canned result; {len(shown.getvalue().splitlines())} lines shown"
