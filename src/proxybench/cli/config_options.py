"""A study's command-line options, generated from its config model: a field is declared once.

:func:`study_options` decorates a command whose function takes ``cfg`` (the study's config) and its own
options (``--quick``, ``--out``, ``--backend``, ``--workers``: what only the command line has). It adds
``--config FILE`` and one option per field of the model, and hands the function the config of the file
with the given options on top (an option beats the file, the file beats the default). Per field:

- the name is ``--field-name``, or the field's :class:`~proxybench.experiments.study.Cli` spelling
  (``agents`` → ``--agent``); a nested model's fields are flattened (``search.trials`` → ``--trials``,
  ``robot_options.cwd`` → ``--robot-cwd``), another nested group takes ``--group KEY=VALUE``;
- the help is the field's docstring, the shown default the field's, or the command's wording where the
  default is settled only when it runs (by ``--quick``, by the target);
- numbers keep their bounds (an integer's ``ge`` / ``le`` as a range, a float's checked, ``nan`` and ``inf``
  refused) and a bad value is a usage error naming the option, before anything runs;
- lists are repeated options (``--agent a --agent b``; numbers and metric names also ``--ladder 50,100``,
  ``--metric a,b``); mappings are
  repeated ``NAME=VALUE`` (``--sweep trim=-0.1,0,0.1``, ``--param trim=-0.3:0.3``; values of ``Any`` read as
  YAML); booleans are ``--flag/--no-flag``; a fixed-size tuple is one value (``--image-size 160x120``).

>>> import typer
>>> from typer.testing import CliRunner
>>> from pydantic import Field
>>> from proxybench.experiments.study import StudyConfig
>>> class Demo(StudyConfig):
...     seconds: float = Field(20.0, gt=0)
...     agents: tuple[str, ...] = ("pid",)
>>> app = typer.Typer()
>>> @app.command()
... @study_options(Demo)
... def demo(cfg: Demo) -> None:
...     print(cfg.seconds, cfg.agents)
>>> CliRunner().invoke(app, ["--seconds", "5", "--agents", "a", "--agents", "b"]).output
"5.0 ('a', 'b')\\n"
>>> "must be a finite number > 0, got -1.0" in CliRunner().invoke(app, ["--seconds", "-1"]).output
True
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import annotated_types as at
import typer
from pydantic import BaseModel
from rich.markup import escape

from proxybench.cli.app import fail
from proxybench.experiments.study import ConfigError, cli_hint, mode_defaults, unwrap_optional
from proxybench.experiments.study import fmt_default as _fmt
from proxybench.untrusted import repeated

__all__ = ["StudyOption", "image_size", "key_values", "mode_defaults", "option_table", "overrides_of",
           "study_option_list", "study_options"]

Loader = Callable[[Path | None, dict[str, Any], dict[str, Any]], Any]

CONFIG_HELP = "settings file (YAML or JSON) with any of the options below by their field names"


@dataclass(frozen=True)
class StudyOption:
    """One generated option: the field it sets (``path``), its name and how a raw value becomes the field's."""

    path: tuple[str, ...]
    option: str
    param: str
    parameter: inspect.Parameter
    convert: Callable[[Any], Any]

    @property
    def dotted(self) -> str:
        return ".".join(self.path)

    @property
    def names(self) -> list[str]:
        """Every name the option answers to (a flag's ``--no-…`` too, and a short form)."""
        info = typing.get_args(self.parameter.annotation)[1]
        decls = (info.default, *info.param_decls) if isinstance(info.default, str) else info.param_decls  # Annotated
        return [n for decl in decls for n in decl.split("/")]


def _text(doc: str | None) -> str:
    return " ".join((doc or "").split())


def _default_text(field: Any, sep: str, command_default: str | None) -> str:
    hint = cli_hint(field)
    if command_default is not None or hint.default is not None:
        return command_default if command_default is not None else hint.default  # type: ignore[return-value]
    value = field.get_default(call_default_factory=True)
    return "none" if value is None else _fmt(value, sep)


# ------------------------------------------------------------------------------------------ value parsers


def _bounds(field: Any) -> dict[str, float]:
    out: dict[str, float] = {}
    for m in getattr(field, "metadata", ()):
        for key in ("gt", "ge", "lt", "le"):
            if isinstance(m, getattr(at, key.capitalize())):
                out[key] = getattr(m, key)
    return out


def _range_words(b: dict[str, float]) -> str:
    if "gt" in b and "lt" in b:
        return f"a number between {b['gt']:g} and {b['lt']:g} (exclusive)"
    parts = [f"{sym} {b[k]:g}" for k, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")) if k in b]
    return "a finite number" + (" " + " and ".join(parts) if parts else "")


def _float_check(b: dict[str, float]) -> Callable[[float | None], float | None]:
    def check(value: float | None) -> float | None:
        if value is None:
            return None
        ok = math.isfinite(value) and all(
            {"gt": value > lim, "ge": value >= lim, "lt": value < lim, "le": value <= lim}[k] for k, lim in b.items())
        if not ok:
            raise typer.BadParameter(f"must be {_range_words(b)}, got {value}")
        return value

    return check


def _choice_check(choices: tuple[Any, ...]) -> Callable[[str | None], str | None]:
    def check(value: str | None) -> str | None:
        if value is not None and value not in choices:
            raise typer.BadParameter(f"must be one of {', '.join(map(str, choices))}, got {value!r}")
        return value

    return check


def _scalar(tp: Any) -> Callable[[str], Any]:
    """str → the scalar type ``tp`` (int, float, a path, text; anything else read as YAML)."""
    if tp in (int, float):
        return tp
    if tp in (str, Path) or typing.get_origin(tp) is Literal:
        return str
    if any(a in (str, Path) for a in typing.get_args(tp)):  # str | AgentEntry: the text form
        return str
    return _yaml


def _yaml(text: str) -> Any:
    """A value written on the command line, read as YAML (bounded); a ValueError when it is not YAML."""
    import yaml

    from proxybench.untrusted import load_yaml

    try:
        return load_yaml(text, max_depth=8, allow_aliases=False)
    except yaml.YAMLError as exc:
        raise ValueError(f"not YAML ({exc})") from None


def _elements(tp: Any) -> tuple[Any, bool] | None:
    """(element type, fixed size) of a sequence type, else None."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is list or (origin is tuple and len(args) == 2 and args[1] is Ellipsis):
        return args[0], False
    if origin is tuple and args:
        return args[0], True
    return None


def _split(text: str, elem: Any, sep: str) -> list[Any]:
    parse = _scalar(elem)
    return [parse(v.strip()) for v in text.split(sep) if v.strip()]


def key_values(items: list[str], option: str) -> dict[str, Any]:
    """``NAME=VALUE`` items, values read as YAML (numbers, booleans, lists); a usage error names ``option``."""
    out: dict[str, Any] = {}
    for item in items:
        key, eq, raw = item.partition("=")
        try:
            if not eq or not key.strip():
                raise ValueError("expected NAME=VALUE")
            out[key.strip()] = _yaml(raw.strip())
        except ValueError as exc:
            raise typer.BadParameter(f"{item!r}: {exc}", param_hint=option) from None
    return out


def image_size(text: str, option: str = "--image-size") -> list[int]:
    """``WIDTHxHEIGHT`` → [width, height]; a usage error names ``option``."""
    try:
        w, h = _split(text.lower(), int, "x")
    except ValueError:
        raise typer.BadParameter(f"{text!r}: expected WIDTHxHEIGHT, e.g. 160x120", param_hint=option) from None
    return [w, h]


# ------------------------------------------------------------------------------------------ one field


def _param_name(path: tuple[str, ...]) -> str:
    return "cfg__" + "__".join(path)


@dataclass
class _Kind:
    """How one kind of field is spelt: the type typer parses, extra ``typer.Option`` settings, the conversion."""

    parsed: Any
    convert: Callable[[Any], Any]
    settings: dict[str, Any]


def _same(value: Any) -> Any:
    return value


def _bad(item: str, shape: str, name: str) -> typer.BadParameter:
    return typer.BadParameter(f"{item!r}: expected {shape}", param_hint=name)


def _scalar_kind(tp: Any, field: Any, hint: Any) -> _Kind:
    """A number (its bounds kept: an integer's as a range, a float's checked), a choice, a path or text."""
    if tp is int:
        b = _bounds(field)
        return _Kind(int, _same, {"min": b.get("ge", b["gt"] + 1 if "gt" in b else None),
                                  "max": b.get("le", b["lt"] - 1 if "lt" in b else None)})
    if tp is float:
        return _Kind(float, _same, {"callback": _float_check(_bounds(field))})
    if typing.get_origin(tp) is Literal:
        choices = typing.get_args(tp)
        return _Kind(str, _same, {"callback": _choice_check(choices), "metavar": "|".join(map(str, choices))})
    return _Kind(Path if tp is Path else str, str, {"metavar": hint.metavar})


def _tuple_kind(tp: Any, elem: Any, sep: str, name: str, hint: Any) -> _Kind:
    """A fixed-size tuple: one value, e.g. 160x120."""
    metavar = hint.metavar or sep.join(["V"] * len(typing.get_args(tp)))

    def convert(v: str) -> Any:
        try:
            return _split(v, elem, sep)
        except ValueError:
            raise _bad(v, metavar, name) from None

    return _Kind(str, convert, {"metavar": metavar})


#: list fields whose values are names that never hold a comma: ``--metric a,b`` is ``--metric a --metric b``
#: (other text lists, such as commands and paths, may hold commas: those are repeated)
NAME_LISTS = ("metrics",)


def _list_kind(elem: Any, sep: str, name: str, hint: Any, names: bool = False) -> _Kind:
    """A repeated option; numbers (and ``names``) may also come separated (``--ladder 50,100``)."""
    numeric = elem in (int, float)

    def convert(items: list[str]) -> list[Any]:
        out: list[Any] = []
        for item in items:
            try:
                out += _split(item, elem, sep) if numeric or names else [_scalar(elem)(item)]
            except ValueError:
                raise _bad(item, f"{elem.__name__} values", name) from None
        return out

    return _Kind(list[str], convert, {"metavar": hint.metavar or (f"V[{sep}V…]" if numeric else
                                                                  f"NAME[{sep}NAME…]" if names else None)})


def _mapping_kind(tp: Any, sep: str, name: str, hint: Any) -> _Kind:
    """Repeated ``NAME=VALUE``: a mapping's items, or a nested group's keys (values of ``Any``: YAML)."""
    value_tp = typing.get_args(tp)[1] if typing.get_origin(tp) else Any
    inner = _elements(value_tp)
    if inner is not None:
        size = len(typing.get_args(value_tp)) if inner[1] else 0
        metavar = hint.metavar or ("NAME=" + sep.join(f"V{i + 1}" for i in range(size)) if size
                                   else f"NAME=V1{sep}V2{sep}…")
    else:
        metavar = hint.metavar or ("KEY=VALUE" if dataclasses.is_dataclass(tp) else "NAME=VALUE")

    def convert(items: list[str]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for item in items:
            key, eq, raw = item.partition("=")
            try:
                if not eq or not key.strip():
                    raise ValueError
                out[key.strip()] = _split(raw, inner[0], sep) if inner else _scalar(value_tp)(raw.strip())
            except ValueError:
                raise _bad(item, metavar, name) from None
        return out

    return _Kind(list[str], convert, {"metavar": metavar})


def _option(path: tuple[str, ...], field: Any, name: str, command_default: str | None,
            panel: str) -> StudyOption | None:
    """The option of one (non-section) field, or None for a type the command line cannot spell."""
    hint = cli_hint(field)
    tp, _ = unwrap_optional(field.annotation)
    sep = hint.sep or ","
    help_text = f"{_text(field.description)} (default: {_default_text(field, sep, command_default)})".lstrip()
    common: dict[str, Any] = {"help": escape(help_text), "show_default": False, "rich_help_panel": panel}
    decls = [name] + ([hint.short] if hint.short else [])
    seq = _elements(tp)
    if tp is bool:
        kind, decls = _Kind(bool, _same, {}), [f"{name}/{_negative(name, path[-1])}"]
    elif tp in (int, float, str, Path) or typing.get_origin(tp) is Literal:
        kind = _scalar_kind(tp, field, hint)
    elif seq is not None and hint.count:  # a count N: 0 … N−1
        kind = _Kind(int, lambda n: list(range(n)), {"min": 1, "max": 100_000, "metavar": "N"})
    elif seq is not None:
        kind = _tuple_kind(tp, seq[0], sep, name, hint) if seq[1] else \
            _list_kind(seq[0], sep, name, hint, names=path[-1] in NAME_LISTS)
    elif typing.get_origin(tp) in (typing.Union, types.UnionType):  # e.g. a count or ids: the model reads the text
        kind = _Kind(str, _yaml, {"metavar": hint.metavar})
    elif typing.get_origin(tp) in (dict, Mapping) or dataclasses.is_dataclass(tp) or \
            (isinstance(tp, type) and issubclass(tp, BaseModel)):
        kind = _mapping_kind(tp, sep, name, hint)
    else:
        return None
    annotation = Annotated[kind.parsed | None, typer.Option(*decls, **common, **kind.settings)]
    param = _param_name(path)
    return StudyOption(path, name, param, inspect.Parameter(param, inspect.Parameter.KEYWORD_ONLY, default=None,
                                                            annotation=annotation), kind.convert)


def _panel_title(name: str, description: str) -> str:
    """A section's box title: ``name: description``, the name once where the description starts with it."""
    if not description:
        return name
    return description if description.startswith(f"{name}:") else f"{name}: {description}"


def _negative(name: str, field_name: str) -> str:
    """``--no-…`` of a flag: ``--robot-reflection`` → ``--robot-no-reflection``, ``--family`` → ``--no-family``."""
    stem = field_name.replace("_", "-")
    if name.endswith("-" + stem) and name != "--" + stem:
        return name[: -len(stem)] + "no-" + stem
    return "--no-" + name[2:]


def study_option_list(model: type[BaseModel], *, exclude: tuple[str, ...] = (),
                      defaults: Mapping[str, str] | None = None, panel: str = "Settings (or in --config FILE)",
                      _path: tuple[str, ...] = (), _prefix: str = "") -> list[StudyOption]:
    """Every option of ``model`` (fields named in ``exclude`` by dotted path left out)."""
    out: list[StudyOption] = []
    for name, field in model.model_fields.items():
        path = (*_path, name)
        if ".".join(path) in exclude:
            continue
        hint = cli_hint(field)
        tp, _ = unwrap_optional(field.annotation)
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            if hint.option:  # the section also takes KEY=VALUE (``--dtps-option pose=/watchtower/pose``)
                made = _option(path, field, hint.option, (defaults or {}).get(".".join(path)), panel)
                out += [made] if made is not None else []
            prefix = _prefix + (hint.prefix if hint.prefix is not None else name.replace("_", "-") + "-")
            out += study_option_list(tp, exclude=exclude, defaults=defaults, _path=path, _prefix=prefix,
                                     panel=_panel_title(name, _text(field.description)))
            continue
        option = hint.option or f"--{_prefix}{name.replace('_', '-')}"
        made = _option(path, field, option, (defaults or {}).get(".".join(path)), panel)
        if made is not None:
            out.append(made)
    return out


def overrides_of(options: list[StudyOption], values: Mapping[str, Any]) -> dict[str, Any]:
    """The nested overrides of the options given (``values``: parameter name → raw value; None, [] unset)."""
    out: dict[str, Any] = {}
    for o in options:
        raw = values.get(o.param)
        if raw is None or (isinstance(raw, list | tuple) and not raw):
            continue
        node = out
        for key in o.path[:-1]:
            node = node.setdefault(key, {})
        value = o.convert(list(raw) if isinstance(raw, tuple) else raw)
        if isinstance(value, dict) and isinstance(node.get(o.path[-1]), dict):  # a section's KEY=VALUE and flags
            value = {**value, **node[o.path[-1]]}
        node[o.path[-1]] = value
    return out


def _name_options(message: str, options: list[StudyOption]) -> str:
    """``command line: search.trials: …`` → ``command line: search.trials (--trials): …``."""
    by_path = sorted(((o.dotted, o.option) for o in options), key=lambda x: -len(x[0]))
    lines = []
    for line in message.splitlines():
        head, sep, rest = line.partition("command line: ")
        if sep and not head:
            match = next(((p, opt) for p, opt in by_path if rest.startswith(p + ":") or rest.startswith(p + ".")),
                         None)
            if match:
                line = f"command line: {match[0]} ({match[1]}){rest[len(match[0]):]}"
        lines.append(line)
    return "\n".join(lines)


def study_options(model: type[BaseModel], *, load: Loader | None = None, exclude: tuple[str, ...] = (),
                  defaults: Mapping[str, str] | None = None, config_help: str = CONFIG_HELP):
    """Decorate a command taking ``cfg: model`` (and its own options) with ``--config`` and the model's options.

    ``load(path, overrides, own)`` makes the config (default ``model.load(path, overrides)``; ``own``: the
    command's own option values, e.g. ``quick`` for a quick mode's base); ``exclude``: dotted field paths
    without an option; ``defaults``: dotted path → how ``--help`` words a default settled later.
    """
    options = study_option_list(model, exclude=exclude, defaults=defaults)
    names = [n for o in options for n in o.names]
    clash = repeated(names)
    if clash:  # two fields spelt alike: a programming error, caught when the command is defined
        raise ValueError(f"{model.__name__}: options {', '.join(clash)} stand for more than one field")

    def decorate(fn: Callable[..., Any]) -> Callable[..., Any]:
        own = [p.replace(annotation=eval(p.annotation, fn.__globals__)) if isinstance(p.annotation, str) else p
               for p in inspect.signature(fn).parameters.values() if p.name != "cfg"]  # cfg: the model, any spelling
        config = inspect.Parameter("config", inspect.Parameter.KEYWORD_ONLY, default=None, annotation=Annotated[
            Path | None, typer.Option("--config", help=config_help, show_default=False)])
        params = [*own, config, *(o.parameter for o in options)]

        @functools.wraps(fn)
        def command(**kwargs: Any) -> Any:
            path = kwargs.pop("config")
            given = {o.param: kwargs.pop(o.param) for o in options}
            try:
                cfg = (load or (lambda p, over, _own: model.load(p, over)))(path, overrides_of(options, given), kwargs)
            except ConfigError as exc:  # one ✗ line a problem, naming options where the command line is at fault
                raise fail(_name_options(str(exc), options), 2, mark="✗") from None
            return fn(cfg=cfg, **kwargs)

        del command.__wrapped__  # typer reads the signature below, not the function's
        command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
        command.__annotations__ = {p.name: p.annotation for p in params}
        command.study_options = options  # type: ignore[attr-defined]
        return command

    return decorate


def option_table(command: Callable[..., Any]) -> dict[str, str]:
    """Dotted field path → option name of a decorated command (for docs and tests)."""
    return {o.dotted: o.option for o in command.study_options}  # type: ignore[attr-defined]
