"""B's reach 300 s into each leg, before / after compensation, on every case (on demand).

    python tests/benchmarks/bench_reach.py [--seeds N] [--code DIR ...] [--cases DIR]

For every shared reference case (../shared/reference_cases, each with its lever arm from
params.json; pipelines/vehicle.toml for a vehicle case, pipelines/flight.toml otherwise) and
for each flight of pospp's simulator drift grid (Gauss-Markov drift of 0.3 deg/h with tau
100 s, 300 s, 1 h, 10 h, or none; seeds 0..N-1, the median of the seeds' ratios), the ratio of
the medians over the legs of B's horizontal error at 300 s before / after, velocity x /
position x (tests/reference/_reach.py). This tree is measured in-process; each ``--code`` is
another checkout (e.g. a worktree of 4f58f25 made with ``git worktree add --detach DIR
4f58f25``), measured through its own CLI on the same MCAPs with its own pipelines/ files.
The drift grid's MCAPs are written by this tree's simulator into a temporary folder.
tests/reference/test_reach.py records this tree's values; docs/calibration.md quotes the
table.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "reference")]  # this tree's pospp, _reach
import _reach  # noqa: E402


def _cell(rs: list[dict]) -> str:
    v = float(np.median([r["v"] for r in rs]))
    p = float(np.median([r["p"] for r in rs]))
    src = ", ".join(sorted({r["source"] for r in rs if r["source"]}))
    return f"{v:.1f}x / {p:.1f}x" + (f" ({src})" if src else "")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--code", type=Path, action="append", default=[],
                    help="another checkout's root, measured through its CLI (repeatable)")
    ap.add_argument("--cases", type=Path, default=ROOT.parent / "shared" / "reference_cases")
    args = ap.parse_args()
    heads = ["this tree"] + [c.name for c in args.code]
    print("| case | " + " | ".join(heads) + " |")
    print("|---|" + "---|" * len(heads))

    def row(label: str, items: list[tuple[Path, str, list[float]]]) -> None:
        t0 = time.perf_counter()
        cells = [_cell([_reach.reach_here(m, k, lev) for m, k, lev in items])]
        cells += [_cell([_reach.reach_of_checkout(code, m, k, lev) for m, k, lev in items])
                  for code in args.code]
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)
        print(f"({label}: {time.perf_counter() - t0:.0f} s wall)", file=sys.stderr)

    cases = _reach.cases_in(args.cases) if args.cases.is_dir() else []
    for name, mcap, lever in cases:
        row(name, [(mcap, _reach.pipeline_kind(name), lever)])
    with tempfile.TemporaryDirectory() as tmp:
        for tau in _reach.GRID_TAUS_S:
            label = f"pospp.sim drift tau {'none' if tau is None else f'{tau:g} s'}"
            mcaps = [_reach.grid_mcap(tau, seed, Path(tmp)) for seed in range(args.seeds)]
            row(label, [(m, "flight", [0.0, 0.0, 0.0]) for m in mcaps])


if __name__ == "__main__":
    main()
