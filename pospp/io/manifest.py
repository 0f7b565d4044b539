"""A batch root's manifest on disk: pospp's own only when marked so, its folder names distrusted.

``ROOT/manifest.parquet`` (table ``manifest`` of :mod:`pospp.io.parquet_tables`) lists every
flight a batch has seen, with the result status of the run in its folder. Three rules keep a
batch from destroying what it does not own:

- The file is pospp's only when its Parquet metadata says so (``pospp.schema_name`` =
  ``manifest``, written by :func:`pospp.io.parquet_tables.write_table`); another tool's
  ``manifest.parquet`` is refused, never rewritten.
- A damaged manifest is refused with the remedy, never silently rebuilt: a rebuilt manifest
  would hand an earlier flight's folder to a same-stem flight of another archive. With the file
  moved away, the root's run folders' markers (:func:`run_markers`) say which input each folder
  holds, so no folder is given to another input.
- A run folder name read from the manifest is used only when it is one plain path component
  pospp could have made (:func:`is_run_name`): never an absolute path, ``..`` or a separator.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import pandas as pd

from pospp.io import parquet_tables, run_folder

__all__ = ["MANIFEST", "ManifestError", "is_run_name", "read_manifest", "run_markers"]

MANIFEST = "manifest.parquet"
"""File name of a batch root's manifest."""
_NAME = re.compile(r"[A-Za-z0-9_%-][A-Za-z0-9._%-]{0,254}")


class ManifestError(run_folder.RunFolderError):
    """A batch root whose manifest pospp must not rewrite (foreign or damaged): one line."""


def is_run_name(name: Any) -> bool:
    """True when ``name`` is a run folder name a batch could have made: one path component of
    letters, digits, ``-``, ``_``, ``%`` and inner dots, not hidden (no ``..``, no separator,
    no absolute path, no staging folder)."""
    return isinstance(name, str) and _NAME.fullmatch(name) is not None


def read_manifest(root: str | Path) -> pd.DataFrame | None:
    """The manifest of a batch root, or None when the root has none.

    Raises
    ------
    ManifestError
        ``ROOT/manifest.parquet`` is not pospp's (no pospp mark) or cannot be read; the message
        names the file and what to do.
    """
    path = Path(root) / MANIFEST
    shown = run_folder.display_path(path)
    if not os.path.lexists(path):
        return None
    if not path.is_file():
        raise ManifestError(f"{shown}: not a regular file; pospp will not use this root")
    try:
        meta = parquet_tables.read_metadata(path)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is the same answer
        raise ManifestError(_damaged(shown, exc)) from None
    if meta.get("schema_name") != "manifest":
        raise ManifestError(f"{shown}: not a pospp manifest (written by another tool: no "
                            "pospp mark in its metadata); pospp will not rewrite it: choose "
                            "another batch root")
    try:
        table = parquet_tables.read_table(path)
    except Exception as exc:  # noqa: BLE001
        raise ManifestError(_damaged(shown, exc)) from None
    missing = [c for c in ("file", "status", "run_dir") if c not in table.columns]
    if missing:
        raise ManifestError(_damaged(shown, f"no column {', '.join(missing)}"))
    return table


def _damaged(shown: str, why: object) -> str:
    text = " ".join(str(why).split())[:200] or type(why).__name__
    return (f"{shown}: damaged ({text}); pospp will not rebuild it over the run folders: move "
            "it aside, then the next batch rebuilds the manifest from the run folders' markers")


def run_markers(root: str | Path) -> dict[str, dict[str, Any]]:
    """The markers of the run folders directly under ``root`` (folder name -> marker), for
    folders with a name :func:`is_run_name` accepts."""
    out: dict[str, dict[str, Any]] = {}
    try:
        entries = sorted(os.scandir(root), key=lambda e: e.name)
    except OSError:
        return out
    for entry in entries:
        if is_run_name(entry.name) and entry.is_dir(follow_symlinks=False):
            marker = run_folder.read_marker(entry.path)
            if marker is not None:
                out[entry.name] = marker
    return out
