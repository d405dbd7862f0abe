"""The sweep's summary: pass rate, failures by kind, the worst points, and a plot of the
summary metric against every swept parameter (``summary.md``, ``worst_error.png``)."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

WORST_SHOWN = 10
PLOT = "worst_error.png"


def _value(r: dict[str, Any]) -> float:
    v = r.get("metric_value")
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else math.nan


def worst(rows: Sequence[dict[str, Any]], n: int = WORST_SHOWN) -> list[dict[str, Any]]:
    """Points without a result first (they are the worst), then by the metric, largest first."""
    def key(r: dict[str, Any]) -> tuple[int, float]:
        v = _value(r)
        return (0, 0.0) if math.isnan(v) else (1, -v)
    return sorted(rows, key=key)[:n]


def _label(name: str, unit: str) -> str:
    return f"{name} ({unit})" if unit else name


def plot(rows: Sequence[dict[str, Any]], params: Sequence[str], metric: str,
         path: Path | None = None) -> Any:
    """The summary metric against every swept parameter, each axis with its unit; written to
    ``path`` (the figure returned either way)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from rig.data import metrics
    from rig.sweep.spec import unit_of

    n = max(1, len(params))
    # at least as wide as the title needs (one parameter's 4.2 in cut it off)
    fig = Figure(figsize=(max(6.4, 4.2 * n), 3.8), layout="tight")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, n, squeeze=False)
    metric_unit = metrics.unit_of(metric) if metrics.known(metric) else ""
    for ax, p in zip(axes[0], params, strict=False):
        for passed, color, label in ((True, "tab:green", "pass"), (False, "tab:red", "fail")):
            xs = [r[f"param.{p}"] for r in rows if bool(r.get("passed")) == passed
                  and not math.isnan(_value(r))]
            ys = [_value(r) for r in rows if bool(r.get("passed")) == passed
                  and not math.isnan(_value(r))]
            ax.scatter(xs, ys, s=18, c=color, label=label)
        missing = [r[f"param.{p}"] for r in rows if math.isnan(_value(r))]
        if missing:
            ax.scatter(missing, [0.0] * len(missing), marker="x", c="k", label="no result")
        ax.set_xlabel(_label(p, unit_of(p)))
        ax.set_ylabel(_label(metric, metric_unit))
        ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.suptitle(f"worst error ({metric})\nagainst each swept parameter", fontsize=11)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig


def markdown(rows: Sequence[dict[str, Any]], params: Sequence[str], info: dict[str, Any]) -> str:
    n = len(rows)
    passed = sum(1 for r in rows if r.get("passed"))
    kinds = Counter(str(r.get("failure_kind")) for r in rows if not r.get("passed"))
    metric = info.get("metric", "")
    lines = [f"# Sweep of {info.get('scenario')}", "",
             f"{n} points ({info.get('mode')}), bus {info.get('bus')}, engine "
             f"{info.get('engine')}; metric `{metric}`.", "",
             f"**Pass rate: {passed}/{n} ({100.0 * passed / n if n else 0.0:.1f} %)**", ""]
    if kinds:
        lines += ["| not passed because | points |", "|---|---|"]
        lines += [f"| {k} | {v} |" for k, v in kinds.most_common()]
        lines.append("")
    lines += [f"## Worst points (by `{metric}`)", "",
              "| point | " + " | ".join(params) + f" | {metric} | status | reason |",
              "|---" * (len(params) + 4) + "|"]
    for r in worst(rows):
        v = _value(r)
        cells = [str(r.get("point"))] + [f"{r.get(f'param.{p}'):.6g}" for p in params]
        cells += ["—" if math.isnan(v) else f"{v:.4g}", str(r.get("status")),
                  str(r.get("failure") or "").replace("|", "/")[:120]]
        lines.append("| " + " | ".join(cells) + " |")
    cluster = info.get("cluster") or {}
    if cluster:
        lines += ["", f"Cluster: {cluster.get('workers_seen')} workers, "
                  f"{cluster.get('workers_lost')} lost, {cluster.get('points_rerun')} points "
                  "run again on another worker"
                  + (f"; {cluster['gave_up']}" if cluster.get("gave_up") else "") + "."]
    if info.get("interrupted_after") is not None:
        lines += ["", f"Interrupted after {info['interrupted_after']} of {info.get('points')} "
                  "points: the table holds the points that finished."]
    if rows:
        lines += ["", f"![worst error against each swept parameter]({PLOT})"]
    lines += ["",
              "Every point is a row of `sweep.csv` / `sweep.parquet` (parameters, verdict, "
              "reason, every criterion's value and outcome).", ""]
    return "\n".join(lines)


def write(rows: Sequence[dict[str, Any]], params: Sequence[str], info: dict[str, Any],
          out: Path) -> Path:
    if rows:
        plot(rows, params, str(info.get("metric")), out / PLOT)
    path = out / "summary.md"
    path.write_text(markdown(rows, params, info))
    return path
