"""Write a simulation to disk (design.md data contract) and read its parameters back.

Files, for a name NAME in an output folder:

- ``NAME.mcap``: ROS 2 MCAP through :func:`pospp.io.mcap_writer.write_flight_log` (IMU in the
  FLU sensor frame, GNSS fix and ENU velocity), with a ``pospp`` metadata record;
- ``NAME.truth.parquet``: the IMU's true state through
  :func:`pospp.io.parquet_tables.write_reference_trajectory` (default 10 Hz);
- ``NAME.params.json``: everything injected (``Simulation.params``), plus an ``outputs``
  section (file names, message counts, sizes). Layout mirrors the reference cases'.

All three are written atomically (temporary name, then rename).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from pospp.io.mcap_writer import write_flight_log
from pospp.io.parquet_tables import atomic_path, write_reference_trajectory
from pospp.sim.api import Simulation
from pospp.sim.gnss import GnssModel
from pospp.sim.sensors import ImuErrorModel

__all__ = ["gnss_model_from_params", "imu_error_model_from_params", "read_params",
           "write_simulation"]


def _json_default(o: Any) -> Any:
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON-serialisable: {type(o).__name__}")


def write_simulation(
    sim: Simulation, out_dir: str | Path, name: str | None = None, *,
    truth_rate_hz: float = 10.0,
) -> dict[str, Path]:
    """Write NAME.mcap, NAME.truth.parquet, NAME.params.json into ``out_dir``.

    Returns
    -------
    dict
        ``{"mcap": path, "truth": path, "params": path}``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = name or sim.name
    paths = {
        "mcap": out / f"{name}.mcap",
        "truth": out / f"{name}.truth.parquet",
        "params": out / f"{name}.params.json",
    }
    meta = {"generator": "pospp.sim", "name": name, "seed": str(sim.params["seed"]),
            "params": paths["params"].name}
    write_flight_log(paths["mcap"], sim.imu, sim.fix, sim.vel, metadata=meta)
    write_reference_trajectory(
        paths["truth"], sim.truth_reference(truth_rate_hz),
        metadata={"generator": "pospp.sim", "params": paths["params"].name,
                  "truth_rate_hz": truth_rate_hz},
    )
    params = dict(sim.params)
    params["outputs"] = {
        "mcap": paths["mcap"].name,
        "truth": paths["truth"].name,
        "params": paths["params"].name,
        "truth_rate_hz": truth_rate_hz,
        "message_counts": {"/imu/data": len(sim.imu), "/gnss/fix": len(sim.fix),
                           "/gnss/vel": len(sim.vel)},
        "sizes_bytes": {"mcap": paths["mcap"].stat().st_size,
                        "truth": paths["truth"].stat().st_size},
    }
    with atomic_path(paths["params"]) as tmp:
        tmp.write_text(json.dumps(params, indent=2, default=_json_default) + "\n")
    return paths


def read_params(path: str | Path) -> dict[str, Any]:
    """Read a NAME.params.json (ours or the reference simulator's)."""
    with open(path) as fh:
        return json.load(fh)


def imu_error_model_from_params(params: dict[str, Any]) -> ImuErrorModel:
    """The injected :class:`ImuErrorModel` of a params dict (``config.imu_errors``)."""
    d = params["config"]["imu_errors"]
    known = ImuErrorModel.__dataclass_fields__
    return ImuErrorModel.from_dict({k: v for k, v in d.items() if k in known})


def gnss_model_from_params(params: dict[str, Any]) -> GnssModel:
    """The :class:`GnssModel` of a params dict written by pospp (``config.gnss``)."""
    d = dict(params["config"]["gnss"])
    d["outages_s"] = tuple(tuple(x) for x in d.get("outages_s", ()))
    return GnssModel.from_dict(d)
