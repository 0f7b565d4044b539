"""Write a simulation to disk (design.md data contract) and read its parameters back.

Files, for a name NAME in an output folder:

- ``NAME.mcap``: ROS 2 MCAP through :func:`pospp.io.mcap_writer.write_flight_log` (IMU in the
  FLU sensor frame, GNSS fix and ENU velocity), with a ``pospp`` metadata record;
- ``NAME.truth.parquet``: the IMU's true state through
  :func:`pospp.io.parquet_tables.write_reference_trajectory` (default 10 Hz);
- ``NAME.bias.parquet``: the realised IMU biases (constant + ramp + Gauss-Markov, white noise
  excluded) at the truth epochs, body FRD: time_ns, gyro_bias_{x,y,z}_dph,
  accel_bias_{x,y,z}_ug (the bias of the IMU interval ending at each epoch; columns as the
  reference cases');
- ``NAME.params.json``: everything injected (``Simulation.params``), plus an ``outputs``
  section (file names, message counts, sizes). Layout mirrors the reference cases'.

All are written atomically (temporary name, then rename).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pospp.io.mcap_writer import write_flight_log
from pospp.io.parquet_tables import atomic_path, write_reference_trajectory
from pospp.rotation import DEG_PER_H_RADPS
from pospp.sim.api import Simulation
from pospp.sim.gnss import GnssModel
from pospp.sim.sensors import UG_MPS2, ImuErrorModel

__all__ = ["gnss_model_from_params", "imu_error_model_from_params", "read_bias_table",
           "read_params", "write_simulation"]

_BIAS_META = {
    b"pospp.generator": b"pospp.sim",
    b"frames": b"body FRD; realised bias = constant + ramp + Gauss-Markov, white noise "
               b"excluded; value of the IMU interval ending at time_ns",
}


def _write_bias(path: Path, sim: Simulation, rate_hz: float) -> None:
    dt_ns = int(sim.params["time"]["imu_dt_ns"])
    step = round(1e9 / rate_hz) // dt_ns
    j = np.arange(0, len(sim.truth), step)
    k = np.maximum(j - 1, 0)  # interval ending at epoch j
    g = sim.imu_errors.gyro_bias_radps[k] / DEG_PER_H_RADPS
    a = sim.imu_errors.accel_bias_mps2[k] / UG_MPS2
    cols = {"time_ns": pa.array(sim.truth_time_ns[j], pa.int64())}
    for i, ax in enumerate("xyz"):
        cols[f"gyro_bias_{ax}_dph"] = pa.array(g[:, i], pa.float64())
    for i, ax in enumerate("xyz"):
        cols[f"accel_bias_{ax}_ug"] = pa.array(a[:, i], pa.float64())
    table = pa.table(cols).replace_schema_metadata(_BIAS_META)
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp, compression="zstd")


def read_bias_table(path: str | Path) -> dict[str, np.ndarray]:
    """Columns of a NAME.bias.parquet as numpy arrays (ours or the reference cases')."""
    t = pq.read_table(path)
    return {n: t.column(n).to_numpy() for n in t.column_names}


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
    truth_rate_hz: float = 10.0, events_rate_hz: float | None = None,
    events_topic: str = "/events",
) -> dict[str, Path]:
    """Write NAME.mcap, NAME.truth.parquet, NAME.bias.parquet, NAME.params.json.

    ``events_rate_hz``: also write trigger events (``sensor_msgs/msg/TimeReference`` on
    ``events_topic``) at this rate, stamped by ``Simulation.trigger_stamps_ns``.

    Returns
    -------
    dict
        ``{"mcap": path, "truth": path, "bias": path, "params": path}``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = name or sim.name
    paths = {
        "mcap": out / f"{name}.mcap",
        "truth": out / f"{name}.truth.parquet",
        "bias": out / f"{name}.bias.parquet",
        "params": out / f"{name}.params.json",
    }
    meta = {"generator": "pospp.sim", "name": name, "seed": str(sim.params["seed"]),
            "params": paths["params"].name}
    events = None if events_rate_hz is None else sim.trigger_stamps_ns(events_rate_hz)
    write_flight_log(paths["mcap"], sim.imu, sim.fix, sim.vel, metadata=meta,
                     events_ns=events, events_topic=events_topic)
    write_reference_trajectory(
        paths["truth"], sim.truth_reference(truth_rate_hz),
        metadata={"generator": "pospp.sim", "params": paths["params"].name,
                  "truth_rate_hz": truth_rate_hz},
    )
    _write_bias(paths["bias"], sim, truth_rate_hz)
    params = dict(sim.params)
    params["outputs"] = {
        "mcap": paths["mcap"].name,
        "truth": paths["truth"].name,
        "bias": paths["bias"].name,
        "params": paths["params"].name,
        "truth_rate_hz": truth_rate_hz,
        "message_counts": {"/imu/data": len(sim.imu), "/gnss/fix": len(sim.fix),
                           "/gnss/vel": len(sim.vel),
                           **({} if events is None else {events_topic: len(events)})},
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
