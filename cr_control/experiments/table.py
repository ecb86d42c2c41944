"""The results table of a sweep: DIR/results.csv and DIR/results.parquet.

One row per point, sorted by point index: ``point``, the varied inputs (``node.param``
columns; a list value as JSON text in the CSV and as a list in parquet), ``status``
(ok / stopped / diverged / failed), ``reason``, then the metrics (``cr_analyze``'s names: the SPEC's
``metrics`` if given, else every metric any point has, in the order the first point with it
lists them). Floats in the CSV are written as Python's shortest round-trip repr, so the file
is the same bytes for the same numbers.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

FIXED = ("point",)
STATUS = ("status", "reason")


def columns(records: list[dict[str, Any]], inputs: list[str], metrics: list[str] | None) -> list[str]:
    """The table's columns (see the module docstring)."""
    if metrics is None:
        metrics = []
        seen = set()
        for record in records:
            for name in record["result"]:
                if name not in STATUS and name not in seen:
                    seen.add(name)
                    metrics.append(name)
    return [*FIXED, *inputs, *STATUS, *metrics]


def rows(records: list[dict[str, Any]], inputs: list[str], metrics: list[str] | None
         ) -> tuple[list[str], list[dict[str, Any]]]:
    """(columns, one dict per point sorted by index); a metric a point lacks is NaN."""
    records = sorted(records, key=lambda r: r["point"])
    names = columns(records, inputs, metrics)
    out = []
    for record in records:
        result = record["result"]
        row: dict[str, Any] = {"point": record["point"]}
        row.update({n: record["inputs"][n] for n in inputs})
        row["status"], row["reason"] = result["status"], result.get("reason", "")
        for name in names[len(FIXED) + len(inputs) + len(STATUS):]:
            value = result.get(name, math.nan)
            row[name] = math.nan if value is None else float(value)
        out.append(row)
    return names, out


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return str(value)


def write_csv(path: Path, names: list[str], table: list[dict[str, Any]]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(names)
        for row in table:
            writer.writerow([_cell(row[n]) for n in names])


def _arrow_type(values: list[Any]) -> Any:
    # lazy: pyarrow only for the parquet table
    import pyarrow as pa

    if all(isinstance(v, bool) for v in values):
        return pa.bool_()
    if all(isinstance(v, int) and not isinstance(v, bool) for v in values):
        return pa.int64()
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return pa.float64()
    if all(isinstance(v, list) and all(isinstance(x, (int, float)) for x in v) for v in values):
        return pa.list_(pa.float64())
    return pa.string()


def write_parquet(path: Path, names: list[str], table: list[dict[str, Any]]) -> None:
    import pyarrow as pa  # lazy: the rest of the package needs no pyarrow
    import pyarrow.parquet as pq

    arrays = []
    for name in names:
        values = [row[name] for row in table]
        kind = _arrow_type(values)
        if kind == pa.float64():
            values = [float(v) for v in values]
        elif kind == pa.list_(pa.float64()):
            values = [[float(x) for x in v] for v in values]
        elif kind == pa.string():
            values = [v if isinstance(v, str) else json.dumps(v) for v in values]
        arrays.append(pa.array(values, type=kind))
    pq.write_table(pa.Table.from_arrays(arrays, names=names), path)


def write(out: Path, records: list[dict[str, Any]], inputs: list[str],
          metrics: list[str] | None) -> tuple[list[str], list[dict[str, Any]]]:
    """Write results.csv and results.parquet in ``out``; return (columns, rows)."""
    names, table = rows(records, inputs, metrics)
    write_csv(out / "results.csv", names, table)
    write_parquet(out / "results.parquet", names, table)
    return names, table
