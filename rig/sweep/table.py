"""The sweep's table: one row per point, the same columns in CSV and Parquet (pyarrow)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq


def columns(rows: Sequence[dict[str, Any]]) -> list[str]:
    """Every key of every row, in first-seen order (failed rows have fewer)."""
    seen: dict[str, None] = {}
    for r in rows:
        for k in r:
            seen.setdefault(k, None)
    return list(seen)


def to_arrow(rows: Sequence[dict[str, Any]]) -> pa.Table:
    cols = columns(rows)
    data: dict[str, list[Any]] = {c: [r.get(c) for r in rows] for c in cols}
    arrays = {}
    for c, values in data.items():
        if all(v is None or isinstance(v, bool) for v in values):
            arrays[c] = pa.array(values, type=pa.bool_())
        elif all(v is None or (isinstance(v, int | float) and not isinstance(v, bool))
                 for v in values):
            arrays[c] = pa.array([None if v is None else float(v) for v in values],
                                 type=pa.float64())
        else:
            arrays[c] = pa.array([None if v is None else str(v) for v in values],
                                 type=pa.string())
    return pa.table(arrays)


def write(rows: Sequence[dict[str, Any]], out: Path) -> tuple[Path, Path]:
    table = to_arrow(rows)
    csv_path, parquet_path = out / "sweep.csv", out / "sweep.parquet"
    pacsv.write_csv(table, csv_path)
    pq.write_table(table, parquet_path)
    return csv_path, parquet_path


def read(path: Path) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = pq.read_table(path).to_pylist()
    return rows
