"""Figures 3.3 / 3.4, tables and a self-contained HTML page for a predictivity run."""

from __future__ import annotations

import base64
import html
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.usefulness.predictivity import PredictivityResult

__all__ = ["findings", "write_report"]

_FIG33 = (("prpv", "PRPV (↓)"), ("ppv", "PPV (↓)"), ("srcc", "SRCC, Pearson (↑)"), ("pod", "POD (↓)"))
_PARAM_LABEL = {"trim": "trim", "command_delay": "command delay [s]", "blur_time": "blur time [s]",
                "camera_pitch": "camera pitch [deg]"}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _band(ax, x, df, key):
    ax.plot(x, df[key], "o-", color="tab:blue")
    if f"{key}_low" in df:
        ax.fill_between(x, df[f"{key}_low"], df[f"{key}_high"], color="tab:blue", alpha=0.2, lw=0)


def figure_3_3(res: PredictivityResult, path: Path) -> Path:
    """PRPV, PPV, SRCC and POD against trim, side by side; the target's true trim marked."""
    plt = _pyplot()
    df = res.frame()
    df = df[df.parameter == "trim-sweep"].sort_values("value")
    fig, axes = plt.subplots(1, 4, figsize=(15, 3.4))
    for ax, (key, label) in zip(axes, _FIG33, strict=True):
        _band(ax, df.value, df, key)
        ax.axvline(df.truth.iloc[0], color="tab:red", ls="--", lw=1, label="target's true trim")
        ax.set_xlabel("proxy trim")
        ax.set_title(label, fontsize=10)
    axes[0].legend(fontsize=8)
    fig.suptitle("Usefulness of proxies with different trim for predicting the target's ranking "
                 "(target: reality model, simulated)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def figure_3_4(res: PredictivityResult, path: Path) -> Path:
    """PRPV for three values of each parameter around the truth."""
    plt = _pyplot()
    df = res.frame()
    params = list(res.config.grid)
    fig, axes = plt.subplots(1, len(params), figsize=(3.8 * len(params), 3.4), squeeze=False)
    for ax, name in zip(axes[0], params, strict=True):
        d = df[df.parameter == name].sort_values("value")
        _band(ax, d.value, d, "prpv")
        ax.axvline(d.truth.iloc[0], color="tab:red", ls="--", lw=1)
        ax.set_xlabel(_PARAM_LABEL.get(name, name))
        ax.set_title("PRPV (↓)", fontsize=10)
    fig.suptitle("PRPV around the target's calibrated values (red: truth)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def _save(fig, path: Path) -> Path:
    plt = _pyplot()
    fig.savefig(path, dpi=110)
    fig.savefig(path.with_suffix(".svg"))
    plt.close(fig)
    return path


def findings(res: PredictivityResult) -> list[str]:
    """Plain statements about the result: where each metric is best, and whether PRPV is monotone."""
    df = res.frame()
    out = []
    trim = df[df.parameter == "trim-sweep"].sort_values("value")
    truth = float(trim.truth.iloc[0])
    for key, label, best in (("prpv", "PRPV", np.argmin), ("ppv", "PPV", np.argmin), ("srcc", "SRCC", np.argmax),
                             ("pod", "POD", np.argmin)):
        v = trim[key].to_numpy()
        at = float(trim.value.iloc[int(best(v))])
        out.append(f"{label} is best at trim {at:+.2f} (truth {truth:+.2f}): "
                   + ("at the truth." if abs(at - truth) < 1e-9 else f"off by {at - truth:+.2f}."))
    v = trim.prpv.to_numpy()
    k = int(np.argmin(v))
    at_truth = trim[np.isclose(trim.value, truth)]
    if len(at_truth) and k != int(np.argmax(np.isclose(trim.value, truth))):
        overlap = float(at_truth.prpv_low.iloc[0]) <= float(trim.prpv_high.iloc[k])
        out.append("The 95% intervals of PRPV at the truth and at the minimum "
                   + ("overlap: the data do not separate them." if overlap else "do not overlap."))
    mono = bool(np.all(np.diff(v[: k + 1]) <= 0) and np.all(np.diff(v[k:]) >= 0))
    out.append(f"PRPV {'falls then rises monotonically' if mono else 'is not monotone'} around its minimum "
               f"(values {', '.join(f'{x:.0f}' for x in v)}).")
    for name in res.config.grid:
        d = df[df.parameter == name].sort_values("value")
        v = d.prpv.to_numpy()
        lowest = [float(x) for x in d.value[np.isclose(v, v.min())]]
        t = float(d.truth.iloc[0])
        hit = any(abs(x - t) < 1e-9 for x in lowest)
        where = " and ".join(f"{x:g}" for x in lowest) + (" (tie)" if len(lowest) > 1 else "")
        out.append(f"{name}: PRPV lowest at {where} (truth {t:g})" + (" ✓" if hit else ""))
    return out


def _img(path: Path) -> str:
    return f'<img src="data:image/png;base64,{base64.b64encode(path.read_bytes()).decode()}" style="max-width:100%">'


def write_report(res: PredictivityResult, out: str | Path, wall_s: float | None = None) -> dict[str, Path]:
    """PNG + SVG figures, CSV + Parquet tables and one self-contained ``report.html`` in ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    df = res.frame()
    files = {
        "fig3_3": figure_3_3(res, out / "fig3_3_trim.png"),
        "fig3_4": figure_3_4(res, out / "fig3_4_parameters.png"),
        "csv": out / "usefulness.csv",
        "parquet": out / "usefulness.parquet",
        "html": out / "report.html",
    }
    df.to_csv(files["csv"], index=False)
    df.to_parquet(files["parquet"], index=False)
    facts = findings(res)
    cfg: dict[str, Any] = asdict(res.config)
    target_rows = "".join(
        f"<tr><td>{html.escape(a)}</td>" + "".join(f"<td>{v:.2f}</td>" for v in s.values()) + "</tr>"
        for a, s in sorted(res.target_scores.items(), key=lambda kv: -next(iter(kv[1].values())))
    )
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>proxybench predictivity</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:2em auto;line-height:1.4}}
table{{border-collapse:collapse;font-size:13px}}td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}</style>
</head><body><h1>Predictivity of simulator instances</h1>
<p><b>What is simulated:</b> everything. The target is proxybench's <i>reality model</i>, a simulated stand-in for a
real Duckiebot with effects the proxy family cannot express (wheel slip, motor dead-band, latency jitter, fisheye
lens, other light). No real robot was involved.</p>
<p>{len(res.config.agents)} agents × {res.config.episodes} episodes × {res.config.seconds:g} s on
{html.escape(res.config.map)}; metrics {", ".join(res.config.metrics)}; {res.config.n_boot} bootstrap resamples
(shaded: 95% intervals){f"; wall time {wall_s:.0f} s" if wall_s else ""}.</p>
<h2>Findings</h2><ul>{"".join(f"<li>{html.escape(f)}</li>" for f in facts)}</ul>
<h2>Figure 3.3: usefulness metrics against proxy trim</h2>{_img(files["fig3_3"])}
<h2>Figure 3.4: PRPV around the calibrated values</h2>{_img(files["fig3_4"])}
<h2>Table</h2>{df.round(4).to_html(index=False)}
<h2>Agents on the target (mean over episodes)</h2><table><tr><th>agent</th>
{"".join(f"<th>{html.escape(m)}</th>" for m in res.config.metrics)}</tr>{target_rows}</table>
<h2>Configuration</h2><pre>{html.escape(json.dumps(cfg, indent=1, default=str))}</pre>
</body></html>"""
    files["html"].write_text(page)
    return files
