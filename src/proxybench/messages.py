"""How values appear in messages to users: as they would type them, never as numpy's reprs.

numpy 2 writes a scalar's repr as ``np.float64(0.0)``, which is what an f-string's ``!r`` of a value taken
from an array prints (``time is not increasing (np.float64(0.0) → np.float64(0.0) s)``). Messages name
values through :func:`shown` instead.

>>> import numpy as np
>>> shown(np.float64(0.0)), shown(np.int64(3)), shown("a b"), shown(np.str_("x")), shown(np.bool_(True))
('0.0', '3', "'a b'", "'x'", 'True')
>>> f"{shown(np.float32(0.1))} s"
'0.1 s'
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["plain", "shown"]


def plain(value: Any) -> Any:
    """A numpy scalar as the Python value it holds (``np.int64(3)`` → ``3``); anything else unchanged."""
    return value.item() if isinstance(value, np.generic) else value


def shown(value: Any) -> str:
    """``repr`` of the plain value: what a user would write in a file (``0.0``, ``'text'``)."""
    if isinstance(value, np.floating):
        return str(value)  # numpy's shortest text that reads back as this value at its own precision
    return repr(plain(value))
