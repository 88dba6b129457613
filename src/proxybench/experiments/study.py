"""A study, registered: :class:`Study` (name, config model, ``run`` → typed result, ``write_report``) and the one
base of every study's config, :class:`StudyConfig`: strict, frozen, documented field by field, loadable from YAML.

Every ``proxybench`` study command is generated from a registered :class:`Study` (:mod:`proxybench.cli.studies`):
its options from the config model, plus ``--quick``, ``--out``, ``--backend``, ``--workers`` and ``--config``
once for all. :func:`studies` lists the registered ones: the built-in families' (one folder each under
``experiments/``) and any a package declares in the ``proxybench.studies`` entry-point group (``name =
"module:StudyClass"``), as agent kinds are found.

A study's settings are a :class:`StudyConfig`: unknown keys and bad values are errors naming the field and
the file; each field's docstring (units, meaning) is its documentation *and* its ``--help`` text, since
the command-line options of a study are generated from its config (:mod:`proxybench.cli.config_options`).
:meth:`StudyConfig.load` reads ``--config FILE`` through the bounded YAML loader (:mod:`proxybench.untrusted`)
and lays the command line on top: a command-line option beats the file, the file beats the default.

How a field is spelt on a command line, where that is not ``--field-name``, is said once beside the field
with :class:`Cli` (``agents: Annotated[list[str], Cli("--agent")]``); it is data, no CLI code lives here.

>>> from pydantic import Field
>>> class Demo(StudyConfig):
...     seconds: float = Field(20.0, gt=0)
>>> Demo.load(None, {"seconds": 5}).seconds
5.0
>>> Demo.load(None, {"secconds": 5})
Traceback (most recent call last):
...
proxybench.experiments.study.ConfigError: command line: secconds: unknown key (did you mean 'seconds'?)
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import types
import typing
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Generic, Self, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from proxybench.targets.manifest import TargetError, format_errors

__all__ = [
    "Cli",
    "ConfigError",
    "Progress",
    "Study",
    "StudyConfig",
    "cli_hint",
    "fmt_default",
    "is_section",
    "mode_defaults",
    "register",
    "studies",
    "study",
    "unwrap_optional",
]

#: deepest nesting and largest size of a study file (a config is a handful of levels; this bounds hostile input)
MAX_DEPTH = 32
MAX_BYTES = 1 << 20


class ConfigError(TargetError):
    """A study that cannot run as given; the message names the field (and file) at fault."""


@dataclass(frozen=True)
class Cli:
    """How a config field is spelt on a command line, where not ``--field-name`` (read by the CLI's generator).

    ``option``: the long name (today's spelling, e.g. ``--agent`` for ``agents``); ``short``: e.g. ``-a``;
    ``metavar``: the shape of a value (``NAME=LOW:HIGH``); ``sep``: what separates the numbers of one value
    (``","`` by default, ``":"`` for a range, ``"x"`` for ``160x120``); ``prefix``: for a nested model, what
    its fields' options start with (``""``: their own names, as ``--trials`` for ``search.trials``);
    ``default``: the default as ``--help`` words it, where the field's own would mislead; ``count``: a
    sequence of integers given as a count N, standing for 0 … N−1 (``--seeds 15``).
    """

    option: str | None = None
    short: str | None = None
    metavar: str | None = None
    sep: str | None = None
    prefix: str | None = None
    default: str | None = None
    count: bool = False


def cli_hint(field: Any) -> Cli:
    """The :class:`Cli` hint of a pydantic ``FieldInfo`` (an empty one when the field has none)."""
    return next((m for m in getattr(field, "metadata", ()) if isinstance(m, Cli)), Cli())


def unwrap_optional(annotation: Any) -> tuple[Any, bool]:
    """``(X, True)`` for ``X | None``, else ``(annotation, False)``."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1 and len(typing.get_args(annotation)) == 2:
            return args[0], True
    return annotation, False


def is_section(annotation: Any) -> bool:
    """A nested group of settings (a model or a dataclass): the file's and the command line's keys merge."""
    inner, _ = unwrap_optional(annotation)
    return isinstance(inner, type) and (issubclass(inner, BaseModel) or dataclasses.is_dataclass(inner))


def _merge(base: dict[str, Any], top: dict[str, Any], sections: set[str]) -> dict[str, Any]:
    """``top`` over ``base``; a section given in both keeps ``base``'s keys that ``top`` does not set."""
    out = dict(base)
    for key, value in top.items():
        if key in sections and isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {**out[key], **value}
        else:
            out[key] = value
    return out


class StudyConfig(BaseModel):
    """A study's settings (subclass it): every field documented by its docstring, every problem named."""

    model_config = ConfigDict(extra="forbid", frozen=True, use_attribute_docstrings=True, defer_build=True)

    @classmethod
    def sections(cls) -> set[str]:
        """The fields that are nested groups: a file's and the command line's keys merge inside them."""
        return {name for name, f in cls.model_fields.items() if is_section(f.annotation)}

    @classmethod
    def prepare(cls, data: dict[str, Any], folder: Path | None) -> dict[str, Any]:
        """The data of a file (``folder``: the file's) or of the command line (``folder`` None) before validation:
        override to resolve paths (a file's stay inside its folder, :func:`proxybench.untrusted.inside`; the
        command line's are taken from where the command runs); raise ConfigError or UntrustedInputError naming
        the field."""
        return data

    @classmethod
    def read_file(cls, path: str | Path) -> dict[str, Any]:
        """The mapping of fields in ``path`` (YAML, or JSON, which is YAML), prepared; errors name the file."""
        from proxybench.untrusted import UntrustedInputError, load_yaml_file

        try:  # bounded: size, nesting, UTF-8 (a folder or a binary file is an error, not a traceback)
            loaded = load_yaml_file(path, max_bytes=MAX_BYTES, max_depth=MAX_DEPTH)
        except UntrustedInputError as exc:
            raise ConfigError(str(exc)) from None
        if loaded is not None and not isinstance(loaded, dict):
            raise ConfigError(f"{path}: expected a mapping of fields, got {type(loaded).__name__}")
        return cls._prepared(loaded or {}, Path(path).parent, str(path))

    @classmethod
    def _prepared(cls, data: dict[str, Any], folder: Path | None, origin: str) -> dict[str, Any]:
        from proxybench.untrusted import UntrustedInputError

        try:
            return cls.prepare(data, folder)
        except (ConfigError, UntrustedInputError) as exc:
            raise ConfigError(f"{origin}: {exc}") from None

    @classmethod
    def load(cls, path: str | Path | None, overrides: dict[str, Any] | None = None, *,
             base: dict[str, Any] | None = None, context: dict[str, Any] | None = None) -> Self:
        """The config of file ``path`` (or none) over ``base`` (e.g. a quick mode's values), with ``overrides``
        (the command line) on top; sections merge key by key. Problems: :class:`ConfigError` naming each."""
        sections = cls.sections()
        data = dict(base or {})
        if path is not None:
            data = _merge(data, cls.read_file(path), sections)
        data = _merge(data, cls._prepared(dict(overrides or {}), None, "command line"), sections)
        try:
            return cls.model_validate(data, context=context)
        except ValidationError as exc:
            raise ConfigError(format_errors(exc, "command line" if path is None else str(path), cls)) from None


def fmt_default(value: Any, sep: str = ",") -> str:
    """A default as ``--help`` words it: ``on``/``off``, ``1,2``, ``a=1; b=2``, ``none``."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        value = dataclasses.asdict(value)
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list | tuple):
        return sep.join(fmt_default(v) for v in value) if value else "none"
    if isinstance(value, Mapping):
        return "; ".join(f"{k}={fmt_default(v, sep)}" for k, v in value.items()) if value else "none"
    return str(value)


def mode_defaults(full: Mapping[str, Any], quick: Mapping[str, Any]) -> dict[str, str]:
    """How ``--help`` words the defaults of a study whose ``--quick`` mode has others (``full`` and ``quick``: the
    two configs' fields); of a section, only the keys that differ are said for ``--quick``."""
    out = {}
    for key, value in full.items():
        other = quick.get(key, value)
        if other == value:
            out[key] = fmt_default(value)
            continue
        if isinstance(value, Mapping) and isinstance(other, Mapping):
            other = {k: v for k, v in other.items() if value.get(k) != v}
        out[key] = f"{fmt_default(value)}; --quick {fmt_default(other)}"
    return out


# -- the registered study -----------------------------------------------------------------------------------------

C = TypeVar("C", bound=StudyConfig)
R = TypeVar("R")
#: a study's progress: ``progress(stage, done, total)``, a bar per stage on a terminal
Progress = Callable[[str, int, int], None]


class Study(ABC, Generic[C, R]):
    """One study: what its command is called, its settings, how it runs and how its result is reported.

    Subclass it in the study's folder, write its ``--help`` as the class's docstring, set the class attributes,
    implement :meth:`run` and :meth:`write_report`, and decorate the class with :func:`register`. The module
    holding the class must import nothing heavy at module level (the CLI builds every study's options at start):
    import the simulator, the runner and the report inside the methods. ``run`` returns a typed result (a
    dataclass or a model, never a dict read by key); ``write_report`` and ``show`` read that result only and run
    no episodes.
    """

    #: the command's name (``proxybench NAME``)
    name: ClassVar[str]
    #: the config model: every field a generated option
    config: ClassVar[type[StudyConfig]]
    #: what ``--quick`` does (its ``--help``)
    quick_help: ClassVar[str] = "a small, fast version of the study"
    #: what the ``--out`` folder holds
    out_help: ClassVar[str] = "report folder and episode cache (OUT/runs)"
    #: dotted config fields without an option
    exclude: ClassVar[tuple[str, ...]] = ()
    #: ``--config``'s help
    config_help: ClassVar[str] = "settings file (YAML or JSON) with any of the options below by their field names"

    @property
    def out(self) -> str:
        """The default ``--out`` folder: ``out/NAME`` (a class attribute ``out`` overrides it)."""
        return f"out/{self.name}"

    @property
    def help(self) -> str:
        """The command's ``--help``: the study class's own docstring (a first line, then a paragraph)."""
        return inspect.cleandoc(type(self).__doc__ or "")

    def help_defaults(self) -> dict[str, str]:
        """Dotted field → how ``--help`` words a default settled only when the study runs (by ``--quick``)."""
        return {}

    def load(self, path: Path | None, overrides: dict[str, Any], *, quick: bool = False) -> C:
        """The config of file ``path`` with the command line's ``overrides`` on top (``quick``: its quick mode's
        defaults below both, where the study has them); problems are :class:`ConfigError`."""
        return typing.cast(C, self.config.load(path, overrides))

    @abstractmethod
    def run(self, config: C, out: Path, backend: Any, progress: Progress, *, quick: bool = False) -> R:
        """Run (or resume) the study into ``out`` with the runner's ``backend``; its typed result."""

    @abstractmethod
    def write_report(self, result: R, out: Path, *, wall: float = 0.0) -> list[Path]:
        """The report's files in ``out`` (tables, figures, HTML), from ``result`` alone (``wall``: seconds run)."""

    def show(self, result: R, console: Any, *, wall: float = 0.0) -> None:
        """What the terminal shows once the study ran (a rich ``console``): by default nothing."""

    def example(self) -> R | None:
        """A small canned result, for the contract's check that the report is written from a result alone (None:
        the study has none)."""
        return None


_REGISTRY: dict[str, Study[Any, Any]] = {}
#: the built-in study families, one folder each (their ``study`` module registers them)
BUILTIN = ("predictivity", "score", "optimize", "plan", "heldout", "repeatability", "plv", "plv_prpv", "validate",
           "rank", "rank_check")
GROUP = "proxybench.studies"


def register(cls: type[Study[Any, Any]]) -> type[Study[Any, Any]]:
    """Class decorator: register a study under its ``name`` (a second study of that name is an error)."""
    old = _REGISTRY.get(cls.name)
    if old is not None and type(old).__qualname__ != cls.__qualname__:
        raise ValueError(f"study {cls.name!r} is registered twice ({type(old).__module__} and {cls.__module__})")
    _REGISTRY[cls.name] = cls()
    return cls


def studies() -> dict[str, Study[Any, Any]]:
    """Every registered study by name: the built-in families and the ``proxybench.studies`` entry points."""
    from importlib.metadata import entry_points

    for family in BUILTIN:
        importlib.import_module(f"proxybench.experiments.{family}.study")
    for ep in entry_points(group=GROUP):
        ep.load()
    return dict(_REGISTRY)


def study(name: str) -> Study[Any, Any]:
    """The registered study ``name``; an unknown name is a ConfigError listing the known ones."""
    found = studies()
    if name not in found:
        raise ConfigError(f"no study {name!r}; registered: {', '.join(sorted(found))}")
    return found[name]
