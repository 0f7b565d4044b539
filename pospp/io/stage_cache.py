"""Cached stage outputs in a run folder: named arrays in one ``.npz`` with a key.

The pipeline caches algorithm A (the expensive stage) so that re-running a run folder with the
same input and the same A-relevant configuration, or ``pospp diagnose`` on a finished run, does
not filter the flight again. The key is a hash the pipeline computes from the input's SHA-256
and the configuration sections A depends on; a cache with another key is ignored (and
replaced on the next write). Written atomically like every output.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pospp.io.parquet_tables import atomic_path

__all__ = ["load_arrays", "save_arrays"]

_KEY = "__pospp_cache_key__"


def save_arrays(path: str | Path, arrays: dict[str, np.ndarray], *, key: str) -> Path:
    """Write ``arrays`` (name -> ndarray) and ``key`` to ``path`` (.npz), atomically."""
    if _KEY in arrays:
        raise ValueError(f"array name {_KEY!r} is reserved")
    out = Path(path)
    with atomic_path(out) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays, **{_KEY: np.array(key)})
    return out


def load_arrays(path: str | Path, *, key: str) -> dict[str, np.ndarray] | None:
    """The arrays saved under ``key``, or None when absent, unreadable or of another key."""
    p = Path(path)
    if not p.is_file():
        return None
    try:
        with np.load(p, allow_pickle=False) as data:
            if _KEY not in data.files or str(data[_KEY]) != key:
                return None
            return {name: data[name] for name in data.files if name != _KEY}
    except (OSError, ValueError, KeyError):
        return None
