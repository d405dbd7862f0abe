"""The sweep's summary: pass rate, failures by kind, the worst points, and a plot of the
summary metric against every swept parameter (``summary.md``, ``worst_error.png``)."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

WORST_SHOWN = 10


def _value(r: dict[str, Any]) -> float:
    v = r.get("metric_value")
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else math.nan


def worst(rows: Sequence[dict[str, Any]], n: int = WORST_SHOWN) -> list[dict[str, Any]]:
    """Points without a result first (they are the worst), then by the metric, largest first."""
    def key(r: dict[str, Any]) -> tuple[int, float]:
        v = _value(r)
        return (0, 0.0) if math.isnan(v) else (1, -v)
    return sorted(rows, key=key)[:n]


def plot(rows: Sequence[dict[str, Any]], params: Sequence[str], metric: str,
         path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = max(1, len(params))
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 3.6), squeeze=False)
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
        ax.set_xlabel(p)
        ax.set_ylabel(metric)
        ax.grid(True, alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.suptitle(f"worst error ({metric}) against each swept parameter")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


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
    lines += ["", "![worst error against each swept parameter](worst_error.png)", "",
              "Every point is a row of `sweep.csv` / `sweep.parquet` (parameters, verdict, "
              "reason, every criterion's value and outcome).", ""]
    return "\n".join(lines)


def write(rows: Sequence[dict[str, Any]], params: Sequence[str], info: dict[str, Any],
          out: Path) -> Path:
    plot(rows, params, str(info.get("metric")), out / "worst_error.png")
    path = out / "summary.md"
    path.write_text(markdown(rows, params, info))
    return path
