"""pospp's whole run against KF-GINS's forward filter, timed side by side in one run.

Run on demand (not collected by pytest)::

    KFGINS_SRC=/path/to/KF-GINS python tests/benchmarks/bench_kfgins.py \
        [--cases flight_null_200hz flight_time_offset_200hz] [--rounds 3] \
        [--base /tmp/pospp_bench/flight_90min_200hz]

``--base``: any case written as the reference cases are (BASE.mcap, .truth.parquet,
.params.json), e.g. the 1.5 h, 200 Hz flight of ``bench_pipeline.py --minutes 90`` (pospp's
simulator: its lever arm under ``gnss.lever_arm_b_m``).

The speed peer is KF-GINS (i2Nav's C++ 21-state forward EKF), built and run by
``../shared/tools/kfgins_anchor.py`` on a reference case of the independent simulator
(``../shared/reference_cases``). Absolute times on a shared machine move by 2x from one session
to the next, so each round runs KF-GINS and then ``pospp run`` (a fresh process: its peak RSS is
its own; numba's cache warmed by an untimed first run) on the same case, and the table gives
the ratio of the two wall times per round (and of the diagnosis stage's wall time to
KF-GINS's): pospp's whole pipeline (ingest, A forward and
smoother, legs, B, calibration, null, compensation, diagnosis, QC, every table, the trajectory
MCAP and the report) over KF-GINS's forward pass alone. pospp is configured as the reference
tests configure it (``pipelines/flight.toml``, the case's lever arm from its params.json).
The rows go to docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared"
sys.path.insert(0, str(REPO / "tests" / "benchmarks"))
sys.path.insert(0, str(REPO / "tests" / "reference"))

from _reach import pipeline_kind, pipeline_text  # noqa: E402
from bench_pipeline import _CHILD  # noqa: E402


def _anchor():  # the shared tool, imported from where it lies (never copied into pospp)
    spec = importlib.util.spec_from_file_location("kfgins_anchor",
                                                  SHARED / "tools" / "kfgins_anchor.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _pospp(mcap: Path, config: Path, out: Path, env: dict[str, str]) -> dict:
    res = subprocess.run([sys.executable, "-c", _CHILD, str(mcap), str(config), str(out),
                          "auto"], check=True, capture_output=True, text=True, env=env)
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", nargs="+", default=["flight_null_200hz"])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--base", nargs="*", default=[],
                    help="more cases by their path without suffix (BASE.mcap, .params.json)")
    args = ap.parse_args()
    anchor = _anchor()
    if anchor.ensure_binary() is None:
        sys.exit("KF-GINS unavailable: fetch github:i2Nav-WHU/KF-GINS and set KFGINS_SRC "
                 "(../shared/tools/README.md)")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "1")}
    rows = []
    with tempfile.TemporaryDirectory(prefix="pospp_kfgins_") as tmp:
        bases = [SHARED / "reference_cases" / n for n in args.cases] + [Path(b) for b in args.base]
        for base in bases:
            name = base.name
            gnss = json.loads(base.with_suffix(".params.json").read_text())["gnss"]
            lever = gnss.get("lever_arm_m", gnss.get("lever_arm_b_m"))
            config = Path(tmp) / f"{name}.toml"
            config.write_text(pipeline_text(pipeline_kind(name), lever))
            mcap, out = base.with_suffix(".mcap"), Path(tmp) / f"run_{name}"
            _pospp(mcap, config, out, env)  # numba's cache warm, the file in the page cache
            for k in range(args.rounds):
                peer = anchor.run(str(base))
                ours = _pospp(mcap, config, out, env)
                rows.append((name, k, peer, ours))
                print(f"  {name} round {k}: KF-GINS {peer['wall_s']:.1f} s, "
                      f"pospp {ours['wall_s']:.1f} s ({ours['status']})", file=sys.stderr)
    print("| case | round | pospp / KF-GINS wall | of it the diagnosis | pospp peak RSS [GiB] "
          "| KF-GINS peak RSS [GiB] | pospp status |")
    print("|---|---|---|---|---|---|---|")
    for name, k, peer, ours in rows:
        diag = ours["stages_s"].get("diagnose", float("nan"))
        print(f"| {name} | {k} | {ours['wall_s'] / peer['wall_s']:.2f} | "
              f"{diag / peer['wall_s']:.2f} | {ours['peak_rss_mib'] / 1024:.2f} | "
              f"{peer['peak_gib']:.3f} | {ours['status']} |")


if __name__ == "__main__":
    main()
