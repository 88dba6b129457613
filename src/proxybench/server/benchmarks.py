"""Benchmarks on the server: YAML texts validated by :class:`proxybench.tasks.benchmark.Benchmark`, versioned.

Uploading a changed text under a known name makes a new version; an unchanged text is a no-op, so the
built-in benchmarks can be registered at every start. Results stay attached to the version they ran.
"""

from __future__ import annotations

import hashlib
import secrets
import time
from functools import lru_cache
from importlib import resources
from typing import Any

import yaml
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from proxybench.server.errors import ServiceError
from proxybench.server.models import BenchmarkVersion
from proxybench.tasks.benchmark import Benchmark, BenchmarkError, builtin_benchmark_names
from proxybench.untrusted import UntrustedInputError, load_yaml

__all__ = ["benchmark_of", "latest", "parse_benchmark", "public_view", "register_builtins", "store_benchmark"]


def parse_benchmark(text: str, origin: str = "<upload>") -> Benchmark:
    """Validate a benchmark text; maps must be built-in (the server holds no user map files)."""
    try:
        data = load_yaml(text, max_depth=32)
    except UntrustedInputError as exc:
        raise ServiceError(422, f"{origin}: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f":{mark.line + 1}:{mark.column + 1}" if mark is not None else ""
        raise ServiceError(422, f"{origin}{at}: not valid YAML ({getattr(exc, 'problem', exc)})") from None
    if isinstance(data, dict) and isinstance(data.get("map"), str) and ("/" in data["map"] or "\\" in data["map"]):
        raise ServiceError(422, f"{origin}: field 'map': the server accepts built-in map names only, "
                                f"not paths ({data['map']!r})")
    try:
        return Benchmark.from_dict(data, origin=origin)
    except BenchmarkError as exc:
        raise ServiceError(422, str(exc)) from None
    except (ValueError, TypeError, RecursionError) as exc:  # anything the schema did not name: still a 422
        raise ServiceError(422, f"{origin}: not a valid benchmark ({exc})") from None


def latest(session: Session, name: str) -> BenchmarkVersion:
    row = session.scalar(select(BenchmarkVersion).where(BenchmarkVersion.name == name)
                         .order_by(BenchmarkVersion.version.desc()).limit(1))
    if row is None:
        raise ServiceError(404, f"no benchmark named {name!r}")
    return row


def benchmark_of(row: BenchmarkVersion) -> Benchmark:
    """The parsed benchmark of a stored version (cached: validating one loads its map, ~10 ms)."""
    return _parsed(row.spec_yaml, f"{row.name} v{row.version}")


@lru_cache(maxsize=128)
def _parsed(text: str, origin: str) -> Benchmark:
    return parse_benchmark(text, origin=origin)


def store_benchmark(session: Session, text: str, *, features: list[str] | None = None,
                    test_seed: int | None = None, hidden_split: bool = True) -> tuple[BenchmarkVersion, bool]:
    """Store a benchmark text; returns (row, created). A new version only when the text changed."""
    bench = parse_benchmark(text)
    digest = hashlib.sha256(text.encode()).hexdigest()
    prev = session.scalar(select(BenchmarkVersion).where(BenchmarkVersion.name == bench.name)
                          .order_by(BenchmarkVersion.version.desc()).limit(1))
    feats = sorted(set(features or ["sim"]))
    if prev is not None and prev.spec_hash == digest and prev.features == feats:
        return prev, False
    version = (session.scalar(select(func.max(BenchmarkVersion.version))
                              .where(BenchmarkVersion.name == bench.name)) or 0) + 1
    if test_seed is None and hidden_split and bench.episodes.poses is None:
        test_seed = secrets.randbelow(2**31)
    row = BenchmarkVersion(name=bench.name, version=version, spec_yaml=text, spec_hash=digest,
                           description=bench.description, features=feats, test_seed=test_seed,
                           created_at=time.time())
    session.add(row)
    session.flush()
    return row, True


def register_builtins(session: Session) -> list[str]:
    """Store every benchmark shipped with proxybench (new versions only where its file changed)."""
    names = []
    for name in builtin_benchmark_names():
        text = (resources.files("proxybench") / "benchmarks" / f"{name}.yaml").read_text(encoding="utf-8")
        _, created = store_benchmark(session, text)
        if created:
            names.append(name)
    return names


def public_view(row: BenchmarkVersion, superuser: bool) -> dict[str, Any]:
    """What the API shows of a benchmark version; the hidden test seed only to super-users."""
    out = {"name": row.name, "version": row.version, "description": row.description, "features": row.features,
           "spec_yaml": row.spec_yaml, "spec_hash": row.spec_hash, "created_at": row.created_at,
           "has_hidden_split": row.test_seed is not None}
    if "autolab" in (row.features or []):  # how often an Autolab runs an invalid episode again (docs/autolab.md)
        out["invalid_retries"] = benchmark_of(row).invalid_retries
    if superuser:
        out["test_seed"] = row.test_seed
    return out
