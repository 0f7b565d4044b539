"""The output tables' schemas as markdown, for docs/formats.md (generated, never hand-edited).

No I/O: returns text; docs/formats.md embeds :func:`render_all_schemas_markdown` verbatim
between its ``schemas:begin`` / ``schemas:end`` markers (tests/unit/test_parquet_tables.py).
"""

from __future__ import annotations

from pospp.io.parquet_tables import EXTENSIBLE_TABLES, TABLES


def render_schema_markdown(name: str) -> str:
    """A markdown table of one schema: column, type, unit, frame, required, description."""
    lines = [
        f"### {name}" + (" (extra columns allowed)" if name in EXTENSIBLE_TABLES else ""),
        "",
        "| column | type | unit | frame | required | description |",
        "|---|---|---|---|---|---|",
    ]
    for c in TABLES[name]:
        lines.append(
            f"| `{c.name}` | {c.type} | {c.unit} | {c.frame} | "
            f"{'yes' if c.required else 'no'} | {c.description} |"
        )
    return "\n".join(lines) + "\n"


def render_all_schemas_markdown() -> str:
    """All schemas, in ``TABLES`` order, for docs/formats.md."""
    return "\n".join(render_schema_markdown(n) for n in TABLES)
