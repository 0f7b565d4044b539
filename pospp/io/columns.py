"""The column declaration of pospp's Parquet tables (``pospp.io.parquet_tables.TABLES``).

One :class:`Column` per column: name (unit suffix included), pyarrow type, unit, description,
frame, and whether a writer must give it. The unit, frame and description go into each field's
metadata when a table is written.
"""

from __future__ import annotations

from typing import NamedTuple

import pyarrow as pa

__all__ = ["BOOL", "FLOAT", "INT", "TEXT", "Column", "optional"]

FLOAT = pa.float64()
INT = pa.int64()
TEXT = pa.string()
BOOL = pa.bool_()


class Column(NamedTuple):
    """One column: name (unit suffix included), pyarrow type, unit, description, frame."""

    name: str
    type: pa.DataType
    unit: str
    description: str
    frame: str = ""
    required: bool = True


def optional(c: Column) -> Column:
    """``c`` as a column a writer may leave out (written as nulls)."""
    return c._replace(required=False)
