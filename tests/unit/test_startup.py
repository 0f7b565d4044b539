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


def test_the_console_entry_keeps_the_commands_exit_status_and_output(tmp_path):
    # pospp.cli.entry (the console script and ``python -m pospp.cli``) freezes the garbage
    # collector after the command: the status, stdout and stderr are the command's
    ok = subprocess.run([sys.executable, "-m", "pospp.cli", "--version"], cwd=REPO,
                        capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0 and ok.stdout.startswith("pospp")
    bad = subprocess.run([sys.executable, "-m", "pospp.cli", "run", str(tmp_path / "no.mcap"),
                          "-o", str(tmp_path / "out")], cwd=REPO, capture_output=True,
                         text=True, timeout=120)
    assert bad.returncode != 0 and "pospp: error:" in bad.stderr and "no.mcap" in bad.stderr
