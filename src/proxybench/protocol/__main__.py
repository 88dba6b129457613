"""``python -m proxybench.protocol AGENT``: serve an agent as an AIDO node on stdin/stdout (or the
``AIDONODE_DATA_IN`` / ``AIDONODE_DATA_OUT`` streams).

AGENT is a zoo name (``proxybench agent list``) or ``package.module:Class`` (built with no arguments).
"""

from __future__ import annotations

import argparse
import importlib

from proxybench.agents.base import Agent
from proxybench.protocol.node import serve


def load_agent(spec: str) -> Agent:
    """A zoo agent by name, or an instance of ``module:Class``."""
    if ":" in spec:
        module, _, attr = spec.partition(":")
        return getattr(importlib.import_module(module), attr)()
    from proxybench.agents.zoo import make_agent

    return make_agent(spec)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m proxybench.protocol", description=__doc__)
    parser.add_argument("agent", help="zoo name or module:Class")
    parser.add_argument("--name", default="agent", help="node name used in timing info (default: agent)")
    args = parser.parse_args(argv)
    return serve(load_agent(args.agent), node_name=args.name)


if __name__ == "__main__":
    raise SystemExit(main())
