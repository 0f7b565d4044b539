"""A diff's answer in words: a few console lines and a small self-contained HTML page.

Both say the same, from :class:`pospp.api.diff.DiffResult` alone: how many flights were
compared, which changed and by what (each row out of tolerance, with its note), which are in
one root only.
"""

from __future__ import annotations

import html

from pospp.api.diff import DiffResult
from pospp.io.run_folder import display_path

__all__ = ["diff_html", "diff_lines", "diff_status"]

MAX_NOTES = 8
"""Rows out of tolerance listed per flight on the console (the table holds them all)."""


def diff_status(result: DiffResult) -> str:
    """"unchanged" (every row within its tolerance) or "changed"."""
    return "unchanged" if result.within else "changed"


def _name(flight: str) -> str:
    return flight or "the run"


def diff_lines(result: DiffResult) -> list[str]:
    """The console summary: the counts, then each changed flight with what changed."""
    changed = result.flights(changed=True)
    same = result.flights(changed=False)
    only_a, only_b = result.only_in("a"), result.only_in("b")
    lines = [f"A {display_path(result.a)}", f"B {display_path(result.b)}",
             f"{len(changed) + len(same)} flight(s) compared: {len(same)} within tolerance, "
             f"{len(changed)} changed"
             + (f"; only in A: {', '.join(only_a)}" if only_a else "")
             + (f"; only in B: {', '.join(only_b)}" if only_b else "")]
    t = result.table
    for flight in changed:
        if flight in only_a or flight in only_b:
            continue
        notes = [str(n) for n in t.note[(t.flight == flight) & ~t.within]]
        lines.append(f"  {_name(flight)}: " + "; ".join(notes[:MAX_NOTES])
                     + (f"; and {len(notes) - MAX_NOTES} more (diff.parquet)"
                        if len(notes) > MAX_NOTES else ""))
    return lines


def diff_html(result: DiffResult) -> str:
    """A self-contained page: the summary lines, then every row out of tolerance."""
    esc = html.escape
    t = result.table
    bad = t[~t.within]
    head = "".join(f"<p>{esc(line.strip())}</p>" for line in diff_lines(result)[:3])
    cols = ["flight", "item", "solution", "text_a", "text_b", "max_diff", "rms_diff",
            "tolerance", "unit", "note"]
    rows = "".join("<tr>" + "".join(f"<td>{esc(_cell(r[c]))}</td>" for c in cols) + "</tr>"
                   for r in bad.to_dict("records"))
    table = (f"<table><tr>{''.join(f'<th>{esc(c)}</th>' for c in cols)}</tr>{rows}</table>"
             if len(bad) else "<p>Every row is within its tolerance.</p>")
    style = ("body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:2px 6px;font-size:90%}"
             "div{overflow-x:auto}")
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>pospp diff: "
            f"{esc(diff_status(result))}</title><style>{style}</style></head><body>"
            f"<h1>pospp diff: {esc(diff_status(result))}</h1>{head}<div>{table}</div>"
            "</body></html>")


def _cell(v: object) -> str:
    if isinstance(v, float):
        return "" if v != v else f"{v:.4g}"
    return str(v)
