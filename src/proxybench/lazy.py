"""Package exports loaded on first use (PEP 562), so that importing one light module of a package (a config,
an options model) does not load the whole package: the command line builds its options from configs at
start-up, and ``proxybench map check`` should not wait for the simulator's compiled kernels.

>>> getattr_ = lazy_exports("proxybench.targets", {"TargetError": "proxybench.targets.manifest"})
>>> getattr_("TargetError").__name__
'TargetError'
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(package: str, exports: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package``: ``exports`` maps a name to the module it comes from; other names
    are tried as submodules. Each value is kept in the package once loaded."""

    def __getattr__(name: str) -> Any:
        if name in exports:
            value = getattr(importlib.import_module(exports[name]), name)
        else:
            try:
                value = importlib.import_module(f"{package}.{name}")
            except ModuleNotFoundError:
                raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        setattr(sys.modules[package], name, value)
        return value

    return __getattr__
