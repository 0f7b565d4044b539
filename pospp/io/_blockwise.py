"""Row-wise reductions of long (N, 3) IMU arrays with temporaries one block long.

Private to :mod:`pospp.io.mcap_reader`'s checks: they give the same bits as numpy's whole-array
expressions (tests/unit/test_mcap_reader_batches.py), without an (N, 3) temporary, so that
reading a log peaks near its decoded arrays (docs/history/speed_rounds.md, "The reader, third
round").
"""

from __future__ import annotations

import numpy as np

from pospp.units import S_PER_NS

__all__ = ["BLOCK_ROWS", "rotation_sums", "row_norms"]

BLOCK_ROWS = 65536  # rows of the IMU log handled at a time by the checks' temporaries


def row_norms(v: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(v, axis=1)`` for (N, 3) ``v`` (same sums, same bits), its
    temporaries a block long."""
    out = np.empty(len(v))
    for b in range(0, len(v), BLOCK_ROWS):
        blk = v[b : b + BLOCK_ROWS]
        o = out[b : b + BLOCK_ROWS]
        np.multiply(blk[:, 0], blk[:, 0], out=o)  # ((x^2 + y^2) + z^2): add.reduce's order
        o += blk[:, 1] * blk[:, 1]
        o += blk[:, 2] * blk[:, 2]
        np.sqrt(o, out=o)
    return out


def rotation_sums(w: np.ndarray, t_ns: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``S[j] = sum_{i < j} w_i dt_i`` [rad] (rows of (N, 3) ``w`` [rad/s]) at the indices
    ``at`` (0..N), ``dt_i = t_i - t_{i-1}`` [s] (``dt_0 = t_1 - t_0``).

    The running sum is the sequential ``np.cumsum`` order, carried block to block, so the
    values are those of one cumulative sum over the whole log without its (N, 3) array.
    """
    out = np.zeros((len(at), 3))
    carry = np.zeros(3)
    n = len(t_ns)
    for b in range(0, n, BLOCK_ROWS):
        e = min(b + BLOCK_ROWS, n)
        prev = t_ns[b - 1] if b else t_ns[0] - (t_ns[1] - t_ns[0])
        dt = np.diff(t_ns[b:e], prepend=prev) * S_PER_NS
        blk = np.empty((e - b + 1, 3))
        blk[0] = carry
        np.multiply(w[b:e], dt[:, None], out=blk[1:])
        np.cumsum(blk, axis=0, out=blk)  # blk[r] = S[b + r]
        sel = (at > b) & (at <= e)
        out[sel] = blk[at[sel] - b]
        carry = blk[-1].copy()
    return out
