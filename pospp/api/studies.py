"""Studies beside the pipeline, each writing its table and figure: a finished run's
solutions against a reference trajectory (``pospp evaluate``) and the paper's observability
curves (``pospp observability``, paper Fig. 4 and 5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pospp.calib.observability import observability_table
from pospp.evaluate import evaluation_rows, solution_errors
from pospp.io import parquet_tables, report_files, run_folder
from pospp.io.run_lock import locked
from pospp.report import figures


@locked("pospp evaluate")
def evaluate_run(run_dir: str | Path, truth_file: str | Path, *, skip_s: float = 0.0
                 ) -> pd.DataFrame:
    """``pospp evaluate``: every solution of a run against a reference trajectory.

    Writes RUN_DIR/evaluation.parquet (long form) and RUN_DIR/evaluation.png; returns the
    table.
    """
    run = run_folder.require_run_folder(run_dir)
    if not (run / "trajectory.parquet").is_file():
        raise FileNotFoundError(f"{run}: the run has no trajectory.parquet (it failed)")
    traj = parquet_tables.read_table(run / "trajectory.parquet")
    ref = parquet_tables.read_reference_trajectory(truth_file)
    errors = {}
    for name, g in traj.groupby("solution", sort=False):
        errors[str(name)] = solution_errors(
            g.time_ns.to_numpy(np.int64), np.radians(g.lat_deg.to_numpy()),
            np.radians(g.lon_deg.to_numpy()), g.height_m.to_numpy(),
            g[["vn_mps", "ve_mps", "vd_mps"]].to_numpy(),
            np.radians(g[["roll_deg", "pitch_deg", "yaw_deg"]].to_numpy()),
            ref_time_ns=ref.time_ns, ref_lat_rad=ref.lat_rad, ref_lon_rad=ref.lon_rad,
            ref_height_m=ref.height_m, ref_v_n_mps=ref.v_n_mps, ref_rpy_rad=ref.rpy_rad,
        )
    cols = evaluation_rows(errors, skip_s=skip_s)
    cols["reference_file"] = [str(truth_file)] * len(cols["solution"])
    table = pd.DataFrame(cols)
    meta = {"run_dir": str(run), "reference_file": str(truth_file)}
    parquet_tables.write_table(run / "evaluation.parquet", table, "evaluation", metadata=meta)
    report_files.write_figure(run / "evaluation.png",
                              figures.evaluation_errors(errors, skip_s=skip_s))
    return table


def observability_study(out_dir: str | Path, *, speed_mps: float = 60.0,
                        duration_s: float = 300.0, lat_deg: float = 40.0,
                        transition: str = "closed_form") -> pd.DataFrame:
    """``pospp observability``: paper Fig. 4 and 5 as observability.parquet and a figure."""
    out = Path(out_dir)
    cols = observability_table(speed_mps=speed_mps, duration_s=duration_s,
                               lat_rad=np.radians(lat_deg), transition=transition)
    n = len(cols["formulation"])
    cols.update({"speed_mps": np.full(n, speed_mps), "duration_s": np.full(n, duration_s),
                 "lat_deg": np.full(n, lat_deg)})
    table = pd.DataFrame(cols)
    meta = {"speed_mps": speed_mps, "duration_s": duration_s, "lat_deg": lat_deg,
            "transition": transition}
    parquet_tables.write_table(out / "observability.parquet", table, "observability",
                               metadata=meta)
    report_files.write_figure(out / "observability.png", figures.observability_curves(table))
    return table
