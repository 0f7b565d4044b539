"""``pospp --help`` stays light: the heavy modules load only inside the commands that use
them (issue 18; the time itself is measured by tests/benchmarks/bench_startup.py, never
asserted here)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
HEAVY = ("numba", "matplotlib", "scipy", "pandas", "dask", "pyarrow", "pospp.pipeline")

_PROBE = """
import json, sys
from click.testing import CliRunner
from pospp.cli import main
for args in (["--help"], ["run", "--help"], ["batch", "--help"]):
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in {HEAVY_ROOTS}
                        or m in {HEAVY})))
"""


def test_help_does_not_import_the_heavy_modules():
    roots = {h for h in HEAVY if "." not in h}
    code = _PROBE.replace("{HEAVY_ROOTS}", repr(roots)).replace("{HEAVY}", repr(set(HEAVY)))
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True,
                         text=True, timeout=120, check=True)
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert loaded == [], f"pospp --help imported {loaded}"
