"""The one base of every study's config: strict, frozen, documented field by field, loadable from YAML.

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
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

from pydantic import BaseModel, ConfigDict, ValidationError

from proxybench.targets.manifest import TargetError, format_errors

__all__ = ["Cli", "ConfigError", "StudyConfig", "cli_hint", "is_section", "unwrap_optional"]

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
