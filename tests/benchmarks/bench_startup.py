"""Benchmark of start-up: ``pospp --help`` and ``import pospp.pipeline`` (issue 18).

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_startup.py [--repeat 5]

Each measurement is a fresh interpreter (``python -m pospp.cli --help``; ``python -c "import
pospp.pipeline"``), timed from outside (so the interpreter's own start-up is included), best and
median of ``--repeat``; the bare interpreter (``python -c pass``) is the floor. Then the
largest cumulative imports of ``import pospp.pipeline`` from ``python -X importtime``. Numba's
cache is warm (run once before). Prints markdown for docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CASES = {
    "python -c pass": [sys.executable, "-c", "pass"],
    "pospp --help": [sys.executable, "-m", "pospp.cli", "--help"],
    "import pospp.pipeline": [sys.executable, "-c", "import pospp.pipeline"],
}


def _time(cmd: list[str], repeat: int) -> list[float]:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(cmd, cwd=REPO, env=env, check=True, stdout=subprocess.DEVNULL)
        out.append(time.perf_counter() - t0)
    return out


def _top_imports(n: int = 12) -> list[tuple[str, float]]:
    res = subprocess.run([sys.executable, "-X", "importtime", "-c", "import pospp.pipeline"],
                         cwd=REPO, capture_output=True, text=True, check=True)
    rows = []
    for line in res.stderr.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|( *)(\S+)", line)
        if m and len(m.group(3)) <= 3:  # top-level and first nesting level
            rows.append((m.group(4), int(m.group(2)) * 1e-6))
    return sorted(rows, key=lambda r: -r[1])[:n]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    subprocess.run(CASES["import pospp.pipeline"], cwd=REPO, check=True)  # warm caches
    print(f"load average: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("| command | best wall [s] | median wall [s] |")
    print("|---|---:|---:|")
    for name, cmd in CASES.items():
        t = _time(cmd, args.repeat)
        print(f"| `{name}` | {min(t):.3f} | {statistics.median(t):.3f} |")
    print()
    print("| module (import pospp.pipeline, cumulative) | s |")
    print("|---|---:|")
    for name, s in _top_imports():
        print(f"| {name} | {s:.3f} |")


if __name__ == "__main__":
    main()
