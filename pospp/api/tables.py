"""A run's documented tables read back with their schema checked (``pospp.api``).

Reads only the tables of ``pospp.io.parquet_tables.TABLES`` (docs/formats.md), by column name:
every documented column is there with its documented type (an optional column an older run did
not write is added as nulls), and columns the schema does not name (added by a later pospp)
are kept as they are. A file whose documented column has another type, or that misses a
required one, is refused in one line naming the file and the column.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from pospp.io import parquet_tables
from pospp.io.run_folder import display_path

__all__ = ["SchemaError", "column_table", "read_documented"]


class SchemaError(ValueError):
    """A table whose columns do not match its documented schema (names file and column)."""


def read_documented(path: str | Path, name: str) -> pd.DataFrame:
    """Table ``name`` (a key of ``TABLES``) from ``path`` as a DataFrame, schema checked.

    Integer columns holding nulls come back as float64 with NaN (as pyarrow gives them);
    :func:`pospp.io.parquet_tables.write_table` takes such a frame back to the same schema.
    """
    shown = display_path(path)
    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise SchemaError(f"{shown}: not a readable Parquet table ({exc})") from None
    n = table.num_rows
    for col in parquet_tables.TABLES[name]:
        if col.name not in table.column_names:
            if col.required:
                raise SchemaError(f"{shown}: no column {col.name!r} (table {name!r} of "
                                  "docs/formats.md)")
            table = table.append_column(pa.field(col.name, col.type), pa.nulls(n, col.type))
            continue
        got = table.schema.field(col.name).type
        if got == col.type:
            continue
        if pa.types.is_null(got):
            i = table.column_names.index(col.name)
            table = table.set_column(i, pa.field(col.name, col.type), pa.nulls(n, col.type))
            continue
        raise SchemaError(f"{shown}: column {col.name!r} is {got}, documented as {col.type} "
                          f"(table {name!r} of docs/formats.md)")
    return table.to_pandas()


def column_table(path: str | Path) -> pd.DataFrame:
    """The columns of a pospp Parquet file with the unit, frame and description stored in each
    field's metadata (column, type, unit, frame, description)."""
    rows = []
    for f in pq.read_schema(path):
        meta = {k.decode(): v.decode() for k, v in (f.metadata or {}).items()}
        rows.append({"column": f.name, "type": str(f.type), "unit": meta.get("unit", ""),
                     "frame": meta.get("frame", ""), "description": meta.get("description", "")})
    return pd.DataFrame(rows, columns=["column", "type", "unit", "frame", "description"])
