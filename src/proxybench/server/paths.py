"""Benchmark paths: a DAG of benchmark steps whose edges carry the conditions to progress.

A submission entered on a path gets a job for every root step; when a step's job succeeds, each edge
out of it whose condition holds opens a job for the next step (e.g. simulation first, then the target).

>>> spec = PathSpec.model_validate({"steps": [{"id": "sim", "benchmark": "aido_lf"},
...     {"id": "real", "benchmark": "aido_lf", "features": ["target"]}],
...     "edges": [{"source": "sim", "target": "real",
...                "condition": {"metric": "survival_time_median", "min": 30}}]})
>>> [s.id for s in spec.roots()]
['sim']
>>> spec.edges[0].condition.holds({"survival_time_median": 45.0}, None, None)
True
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from proxybench.tasks.scoring import Criterion, compare
from proxybench.untrusted import repeated

__all__ = ["Condition", "Edge", "PathSpec", "Step"]


class _Strict(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class Condition(_Strict):
    """Pass when a score is at least ``min`` / at most ``max``, or when the submission beats a baseline.

    ``better_than`` names a submission label; the newest active submission with that label is the
    baseline, compared under the step's benchmark scoring (lexicographic semiorder).
    """

    metric: str | None = None
    min: float | None = None
    max: float | None = None
    better_than: str | None = None

    @model_validator(mode="after")
    def _one_kind(self) -> Condition:
        if self.better_than is None and self.metric is None:
            raise ValueError("a condition needs 'metric' (with 'min' and/or 'max') or 'better_than'")
        if self.metric is not None and self.min is None and self.max is None:
            raise ValueError(f"condition on {self.metric!r} needs 'min' and/or 'max'")
        return self

    def holds(self, scores: Mapping[str, Any], baseline: Mapping[str, Any] | None,
              criteria: Sequence[Criterion] | None) -> bool:
        if self.metric is not None:
            value = scores.get(self.metric)
            if not isinstance(value, (int, float)):
                return False
            if self.min is not None and not value >= self.min:
                return False
            if self.max is not None and not value <= self.max:
                return False
        if self.better_than is not None:
            if baseline is None or not criteria:
                return False
            return compare(scores, baseline, criteria) > 0
        return True


class Step(_Strict):
    id: str = Field(min_length=1, max_length=64)
    benchmark: str = Field(min_length=1, description="name of a benchmark stored on the server")
    features: list[str] = Field(default_factory=lambda: ["sim"], description="what the evaluator must offer")


class Edge(_Strict):
    source: str
    target: str
    condition: Condition | None = None


class PathSpec(_Strict):
    steps: list[Step] = Field(min_length=1)
    edges: list[Edge] = Field(default_factory=list)

    @model_validator(mode="after")
    def _dag(self) -> PathSpec:
        ids = [s.id for s in self.steps]
        dup = repeated(ids)
        if dup:
            raise ValueError(f"step ids must be unique; repeated: {', '.join(dup)}")
        for k, e in enumerate(self.edges):
            for end in ("source", "target"):
                if getattr(e, end) not in ids:
                    raise ValueError(f"edges.{k}.{end}: no step {getattr(e, end)!r} (steps: {', '.join(ids)})")
        self._topological()
        return self

    def _topological(self) -> list[str]:
        indeg = {s.id: 0 for s in self.steps}
        for e in self.edges:
            indeg[e.target] += 1
        order, ready = [], [i for i, d in indeg.items() if d == 0]
        while ready:
            n = ready.pop()
            order.append(n)
            for e in self.edges:
                if e.source == n:
                    indeg[e.target] -= 1
                    if indeg[e.target] == 0:
                        ready.append(e.target)
        if len(order) != len(self.steps):
            raise ValueError("edges form a cycle; a path must be a DAG")
        return order

    def step(self, step_id: str) -> Step:
        return next(s for s in self.steps if s.id == step_id)

    def roots(self) -> list[Step]:
        targets = {e.target for e in self.edges}
        return [s for s in self.steps if s.id not in targets]

    def edges_from(self, step_id: str) -> list[Edge]:
        return [e for e in self.edges if e.source == step_id]
