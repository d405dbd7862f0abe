"""The sweep's table: one row per point, the same columns in CSV and Parquet (pyarrow), each
column of its own type whatever the rows hold (a column no row filled keeps its type):

- ``point``: int64; ``param.*``, ``crit.*``, ``metric_value``, ``sim_s``, ``wall_s``: float64
  (a missing value is null); ``passed``: bool;
- ``status``, ``failure_kind``, ``failure``, ``metric``, ``metric_window``, ``outcome.*``,
  ``metric_seeds`` (each seed's summary metric, for a scenario over its own seeds):
  string (``outcome.*`` and ``status`` dictionary-encoded in Parquet: a few distinct values).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

BASE = ("point", "status", "passed", "failure_kind", "failure", "metric", "metric_window",
        "metric_value", "sim_s", "wall_s")
FLOATS = ("metric_value", "sim_s", "wall_s")
FLOAT_PREFIXES = ("param.", "crit.")
CATEGORIES = ("status",)
CATEGORY_PREFIXES = ("outcome.",)


def columns(rows: Sequence[dict[str, Any]], params: Sequence[str] = ()) -> list[str]:
    """Every key of every row, in first-seen order (failed rows have fewer), after the
    point and its parameters."""
    seen: dict[str, None] = {"point": None, **{f"param.{p}": None for p in params}}
    for r in rows:
        for k in r:
            seen.setdefault(k, None)
    if not rows:
        for k in BASE:
            seen.setdefault(k, None)
    return list(seen)


def column_type(name: str) -> pa.DataType:
    if name == "point":
        return pa.int64()
    if name == "passed":
        return pa.bool_()
    if name in FLOATS or name.startswith(FLOAT_PREFIXES):
        return pa.float64()
    return pa.string()


def _value(v: Any, kind: pa.DataType) -> Any:
    if v is None:
        return None
    if kind == pa.float64():
        return float(v)
    if kind == pa.int64():
        return int(v)
    if kind == pa.bool_():
        return bool(v)
    return str(v)


def to_arrow(rows: Sequence[dict[str, Any]], params: Sequence[str] = (), *,
             categories: bool = False) -> pa.Table:
    arrays = {}
    for c in columns(rows, params):
        kind = column_type(c)
        arr = pa.array([_value(r.get(c), kind) for r in rows], type=kind)
        if categories and (c in CATEGORIES or c.startswith(CATEGORY_PREFIXES)):
            arr = arr.dictionary_encode()
        arrays[c] = arr
    return pa.table(arrays)


def write(rows: Sequence[dict[str, Any]], out: Path, params: Sequence[str] = ()
          ) -> tuple[Path, Path]:
    csv_path, parquet_path = out / "sweep.csv", out / "sweep.parquet"
    pacsv.write_csv(to_arrow(rows, params), csv_path)
    pq.write_table(to_arrow(rows, params, categories=True), parquet_path)
    return csv_path, parquet_path


def read(path: Path) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = pq.read_table(path).to_pylist()
    return rows
