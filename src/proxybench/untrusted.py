"""Helpers for input from strangers: YAML with bounded depth, text that any database can store, finite numbers.

Used by the agent-package checks (:mod:`proxybench.protocol.package`), the server and the evaluator's upload
contract (:mod:`proxybench.contract`), so both sides refuse and clean the same things.

>>> clean_text("stderr\\x00tail\\ud800")
'stderr\\ufffdtail\\ufffd'
>>> load_yaml("a: [1, [2, [3]]]", max_depth=3)
Traceback (most recent call last):
...
proxybench.untrusted.UntrustedInputError: line 1, column 9: nested deeper than 3 levels
>>> find_non_finite({"a": [1.0, {"b": float("inf")}]})
'a.1.b'
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

import yaml

__all__ = ["UntrustedInputError", "clean_text", "clean_tree", "find_non_finite", "load_yaml", "problems"]

# NUL (PostgreSQL text cannot hold it) and lone surrogates (not encodable as UTF-8)
_UNSTORABLE = re.compile("[\x00\ud800-\udfff]")


class UntrustedInputError(ValueError):
    """Input refused; the message says where (line and column, or the field path) and why."""


def clean_text(text: str) -> str:
    """``text`` with NUL bytes and lone surrogates replaced by U+FFFD: storable in SQLite and PostgreSQL alike,
    and still showing where something was."""
    return _UNSTORABLE.sub("\ufffd", text) if _UNSTORABLE.search(text) else text


def clean_tree(value: Any) -> Any:
    """:func:`clean_text` on every string (keys included) of a JSON-like tree; other values unchanged."""
    if isinstance(value, str):
        return clean_text(value)
    if isinstance(value, Mapping):
        return {clean_tree(k) if isinstance(k, str) else k: clean_tree(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [clean_tree(v) for v in value]
    return value


def find_non_finite(value: Any, path: str = "") -> str | None:
    """The dotted path of the first NaN or ±inf in a JSON-like tree, or None (JSON cannot carry them)."""
    if isinstance(value, float):
        return None if math.isfinite(value) else (path or "(root)")
    if isinstance(value, Mapping):
        items = value.items()
    elif isinstance(value, list | tuple):
        items = enumerate(value)
    else:
        return None
    for k, v in items:
        found = find_non_finite(v, f"{path}.{k}" if path else str(k))
        if found is not None:
            return found
    return None


class _BoundedLoader(yaml.SafeLoader):
    """PyYAML's safe loader with a nesting limit (deep nesting otherwise ends in a RecursionError) and,
    optionally, no aliases (an alias bomb expands to billions of nodes in whoever walks the result)."""

    max_depth = 64
    allow_aliases = True

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):  # type: ignore[no-untyped-def]
        if not self.allow_aliases and self.check_event(yaml.AliasEvent):
            mark = self.peek_event().start_mark
            raise UntrustedInputError(f"line {mark.line + 1}, column {mark.column + 1}: aliases (*name) are not "
                                      "allowed here")
        self._depth += 1
        if self._depth > self.max_depth:
            mark = self.peek_event().start_mark
            raise UntrustedInputError(f"line {mark.line + 1}, column {mark.column + 1}: nested deeper than "
                                      f"{self.max_depth} levels")
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def load_yaml(text: str, *, max_depth: int = 64, allow_aliases: bool = True) -> Any:
    """``yaml.safe_load`` that cannot recurse without bound. Raises :class:`UntrustedInputError` for too deep
    or (``allow_aliases=False``) aliased documents and ``yaml.YAMLError`` for invalid YAML."""
    loader_cls = type("Loader", (_BoundedLoader,), {"max_depth": max_depth, "allow_aliases": allow_aliases})
    loader = loader_cls(text)
    try:
        return loader.get_single_data()
    except RecursionError:  # a construction path we did not bound: still a refusal, never a crash
        raise UntrustedInputError(f"nested too deeply (more than {max_depth} levels)") from None
    finally:
        loader.dispose()


def problems(exc: Any, prefix: str = "") -> str:
    """A pydantic ``ValidationError`` as ``prefix.field: message`` parts joined by "; " (``prefix: message``
    for a check of the whole model, whose message names its fields itself), without pydantic's
    "Value error, " prefix: one way of naming the field at fault wherever input is validated."""
    parts = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in (prefix, *err["loc"]) if p != "")
        msg = err["msg"].removeprefix("Value error, ")
        parts.append(f"{loc}: {msg}" if loc else msg)
    return "; ".join(parts)
