"""Inline SVG drawn on the server (no JavaScript, no image files): benchmark path DAGs and per-episode bars.

Every text that reaches the SVG is escaped; the result is ``Markup`` so templates embed it as is.

>>> "<script>" in episode_bars(["<script>"], [{"episode": 0, "values": {"<script>": 1.0}}])
False
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping, Sequence
from typing import Any

from markupsafe import Markup, escape

__all__ = ["episode_bars", "path_dag"]

_NODE_W, _NODE_H, _GAP_X, _GAP_Y, _PAD = 170, 46, 190, 22, 12


def _condition_text(cond: Mapping[str, Any] | None) -> str:
    if not cond:
        return ""
    parts = []
    if cond.get("metric"):
        if cond.get("min") is not None:
            parts.append(f"{cond['metric']} ≥ {cond['min']:g}")
        if cond.get("max") is not None:
            parts.append(f"{cond['metric']} ≤ {cond['max']:g}")
    if cond.get("better_than"):
        parts.append(f"beats {cond['better_than']!r}")
    return " and ".join(parts)


def _layers(steps: Sequence[Mapping[str, Any]], edges: Sequence[Mapping[str, Any]]) -> dict[str, int]:
    """Each step's column: the length of the longest edge chain reaching it (the spec is a DAG)."""
    depth = {s["id"]: 0 for s in steps}
    for _ in range(len(steps)):
        changed = False
        for e in edges:
            if e["source"] in depth and e["target"] in depth and depth[e["target"]] < depth[e["source"]] + 1:
                depth[e["target"]] = depth[e["source"]] + 1
                changed = True
        if not changed:
            break
    return depth


def path_dag(spec: Mapping[str, Any], highlight: str | None = None) -> Markup:
    """A benchmark path drawn left to right: steps as boxes (id, benchmark, features), edges with conditions.

    Steps on benchmark ``highlight`` are drawn emphasised.
    """
    steps, edges = list(spec.get("steps", [])), list(spec.get("edges", []))
    depth = _layers(steps, edges)
    columns: dict[int, list[str]] = {}
    for s in steps:
        columns.setdefault(depth[s["id"]], []).append(s["id"])
    pos = {sid: (_PAD + col * (_NODE_W + _GAP_X), _PAD + row * (_NODE_H + _GAP_Y))
           for col, ids in columns.items() for row, sid in enumerate(ids)}
    width = _PAD * 2 + (max(columns, default=0) + 1) * _NODE_W + max(columns, default=0) * _GAP_X
    height = _PAD * 2 + max((len(v) for v in columns.values()), default=1) * (_NODE_H + _GAP_Y) - _GAP_Y
    out = [f'<svg class="dag" xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
           f'viewBox="0 0 {width} {height}" role="img" aria-label="benchmark path">',
           '<defs><marker id="arrow" viewBox="0 0 10 10" refX="10" refY="5" markerWidth="7" markerHeight="7" '
           'orient="auto-start-reverse"><path d="M0,0 L10,5 L0,10 z" class="dag-arrow"/></marker></defs>']
    for e in edges:
        (x1, y1), (x2, y2) = pos[e["source"]], pos[e["target"]]
        x1, y1, y2 = x1 + _NODE_W, y1 + _NODE_H / 2, y2 + _NODE_H / 2
        out.append(f'<path class="dag-edge" d="M{x1},{y1} C{x1 + 40},{y1} {x2 - 40},{y2} {x2},{y2}" '
                   'marker-end="url(#arrow)"/>')
        text = _condition_text(e.get("condition"))
        if text:
            out.append(f'<text class="dag-cond" x="{(x1 + x2) / 2}" y="{(y1 + y2) / 2 - 5}" text-anchor="middle">'
                       f'<title>{escape(text)}</title>{escape(_clip(text, 32))}</text>')
    for s in steps:
        x, y = pos[s["id"]]
        cls = "dag-node hl" if highlight is not None and s.get("benchmark") == highlight else "dag-node"
        feats = ", ".join(s.get("features") or [])
        out.append(f'<g class="{cls}"><rect x="{x}" y="{y}" width="{_NODE_W}" height="{_NODE_H}" rx="6"/>'
                   f'<text x="{x + 10}" y="{y + 18}" class="dag-id">{escape(_clip(s["id"], 22))}</text>'
                   f'<text x="{x + 10}" y="{y + 36}" class="dag-bench">{escape(_clip(s.get("benchmark", ""), 18))}'
                   f'{escape(f" [{feats}]" if feats else "")}</text></g>')
    out.append("</svg>")
    return Markup("".join(out))


def _clip(text: str, n: int) -> str:
    return text if len(text) <= n else text[: n - 1] + "…"


def _finite(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else None


def episode_bars(metrics: Sequence[str], rows: Sequence[Mapping[str, Any]], *, titles: Sequence[str] | None = None,
                 panel_w: int = 250, panel_h: int = 150, columns: int = 3) -> Markup:
    """Small multiples, one panel per metric: a bar per episode and a dashed line at the median; ``titles``:
    the panels' titles (default: the metric names)."""
    if not metrics or not rows:
        return Markup("")
    left, right, top, bottom = 46, 8, 22, 22
    n_rows = math.ceil(len(metrics) / columns)
    width, height = min(len(metrics), columns) * panel_w, n_rows * panel_h
    out = [f'<svg class="bars" xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
           f'viewBox="0 0 {width} {height}" role="img" aria-label="per-episode metrics">']
    for k, metric in enumerate(metrics):
        ox, oy = (k % columns) * panel_w, (k // columns) * panel_h
        values = [_finite(r["values"].get(metric)) for r in rows]
        known = [v for v in values if v is not None]
        lo, hi = min([0.0, *known]), max([0.0, *known])
        if hi == lo:
            hi = lo + 1.0
        plot_w, plot_h = panel_w - left - right, panel_h - top - bottom

        def y_of(v: float, oy: int = oy, lo: float = lo, hi: float = hi, plot_h: int = plot_h) -> float:
            return oy + top + plot_h * (1 - (v - lo) / (hi - lo))

        title = titles[k] if titles is not None else metric
        out.append(f'<text class="bars-title" x="{ox + 6}" y="{oy + 14}"><title>{escape(metric)}</title>'
                   f'{escape(_clip(title, 38))}</text>')
        out.append(f'<line class="bars-axis" x1="{ox + left}" x2="{ox + left + plot_w}" y1="{y_of(0.0):.1f}" '
                   f'y2="{y_of(0.0):.1f}"/>')
        for v in (hi, lo):
            out.append(f'<text class="bars-tick" x="{ox + left - 4}" y="{y_of(v) + 4:.1f}" '
                       f'text-anchor="end">{_tick(v)}</text>')
        slot = plot_w / len(rows)
        bar = max(2.0, slot * 0.7)
        for i, (row, v) in enumerate(zip(rows, values, strict=True)):
            x = ox + left + i * slot + (slot - bar) / 2
            if v is None:
                out.append(f'<text class="bars-missing" x="{x + bar / 2:.1f}" y="{y_of(0.0) - 3:.1f}" '
                           'text-anchor="middle">×</text>')
            else:
                y0, y1 = sorted((y_of(0.0), y_of(v)))
                out.append(f'<rect class="bars-bar" x="{x:.1f}" y="{y0:.1f}" width="{bar:.1f}" '
                           f'height="{max(y1 - y0, 0.5):.1f}"><title>episode {escape(row["episode"])}: '
                           f'{v:.4g}</title></rect>')
            if len(rows) <= 20:
                out.append(f'<text class="bars-tick" x="{x + bar / 2:.1f}" y="{oy + panel_h - 8}" '
                           f'text-anchor="middle">{escape(row["episode"])}</text>')
        if known:
            med = y_of(statistics.median(known))
            out.append(f'<line class="bars-median" x1="{ox + left}" x2="{ox + left + plot_w}" y1="{med:.1f}" '
                       f'y2="{med:.1f}"><title>median {statistics.median(known):.4g}</title></line>')
    out.append("</svg>")
    return Markup("".join(out))


def _tick(v: float) -> str:
    return f"{v:.3g}"
