"""Measure the QC checks of docs/qc.md: margins on clean logs and the faults they catch.

    python docs/_qc_margins.py margins [NAMES]   # reference cases and measured logs
    python docs/_qc_margins.py faults [CASES]    # the sample flight with one fault each

Runs ingest, algorithm A and ``pipeline.quality_control`` (no calibration) and prints every
check. Reference cases are read from ../shared/reference_cases (or $POSPP_SHARED/...);
measured logs are converted
from ../shared/data into ./out/qc_realdata first (as tests/realdata does).
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from pospp import pipeline  # noqa: E402
from pospp.config import config_from_dict, load_config  # noqa: E402

SHARED = Path(os.environ.get("POSPP_SHARED", REPO.parent / "shared"))
FAULTS = ("clean", "frd", "late2", "late02", "jump", "lever0", "leversign", "horizon")


def _print(name, rep, seconds):
    print(f"== {name}: status {rep.status} (A + QC {seconds:.1f} s)", flush=True)
    for c in rep.checks:
        print(f"  {c.name:18s} {'pass' if c.passed else 'FAIL'} {c.value:10.4g} / "
              f"{c.threshold:.4g} {c.unit}  {c.statistic}")
        if c.suggestion:
            print(f"      -> {c.suggestion}")


def _qc(name, path, cfg, transform=lambda log: log):
    t0 = time.perf_counter()
    log = transform(pipeline.ingest(path, cfg))
    nav = pipeline.navigate(log, cfg)
    _print(name, pipeline.quality_control(log, nav, None, cfg), time.perf_counter() - t0)


def margins(names):
    rc = SHARED / "reference_cases"
    for name in ("vehicle_errorfree", "flight_survey_errors", "flight_null_200hz",
                 "flight_time_offset_200hz"):
        if names and name not in names:
            continue
        p = json.loads((rc / f"{name}.params.json").read_text())
        cfg = config_from_dict({"imu": {"grade": name.split("_")[0]},
                                "gnss": {"lever_arm_m": p["gnss"]["lever_arm_m"]}})
        _qc(f"{name} (true GNSS offset {p['gnss'].get('time_offset_s')} s)", rc / f"{name}.mcap",
            cfg)
    from pospp.convert import convert
    out = REPO / "out" / "qc_realdata"
    out.mkdir(parents=True, exist_ok=True)
    data = SHARED / "data"
    for stem, folder, kw in (("ardupilot", "ardupilot_plane_testlog2", {}),
                             ("comma", "comma2k19_example1", {}),
                             ("quad", "ansfl_quadrotor_straightline",
                              {"fmt": "ansfl_quadrotor_raw", "unit": 1, "recording": 2})):
        if names and stem not in names:
            continue
        if not (out / f"{stem}.mcap").exists():
            convert(data / folder, out / f"{stem}.mcap", **kw)
        _qc(stem, out / f"{stem}.mcap", load_config(REPO / "pipelines" / "realdata" /
                                                      f"{folder}.toml"))


def _with(cfg, **kw):
    for k, v in kw.items():
        sec, key = k.split("__")
        cfg = replace(cfg, **{sec: replace(getattr(cfg, sec), **{key: v})})
    return cfg


def faults(cases):
    base = load_config(REPO / "pipelines" / "sample.toml")
    sample = REPO / "sample_data" / "sample_flight.mcap"

    def late(s):
        dt = np.int64(round(s * 1e9))
        return lambda log: replace(log, fix=replace(log.fix, time_ns=log.fix.time_ns + dt),
                                   vel=replace(log.vel, time_ns=log.vel.time_ns + dt))

    def jump(log):
        t = (log.fix.time_ns - log.imu.time_ns[0]) * 1e-9
        return replace(log, fix=replace(log.fix, lat_rad=log.fix.lat_rad
                                        + np.where(t > 500.0, 5000.0 / 6.37e6, 0.0)))

    table = {
        "clean": (base, lambda log: log),
        "frd": (_with(base, input__sensor_frame="frd"), lambda log: log),
        "late2": (base, late(2.0)),
        "late02": (base, late(0.2)),
        "jump": (base, jump),
        "lever0": (_with(base, gnss__lever_arm_m=(0.0, 0.0, 0.0)), lambda log: log),
        "leversign": (_with(base, gnss__lever_arm_m=(-0.3, -0.1, 1.5)), lambda log: log),
        "horizon": (_with(base, replay__horizon_s=-300.0), lambda log: log),
    }
    for case in cases or FAULTS:
        cfg, transform = table[case]
        _qc(case, sample, cfg, transform)


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "margins"
    names = sys.argv[2].split(",") if len(sys.argv) > 2 else []
    {"margins": margins, "faults": faults}[what](names)
