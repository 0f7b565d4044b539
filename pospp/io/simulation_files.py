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
from typing import Any, Protocol

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from pospp.io.files import atomic_path
from pospp.io.mcap_writer import write_flight_log
from pospp.io.parquet_tables import write_reference_trajectory
from pospp.types import GnssFixes, GnssVelocities, ImuSamples, ReferenceTrajectory
from pospp.units import DEG_PER_H_RADPS, UG_MPS2

__all__ = ["SimulationRecord", "read_bias_table", "read_params", "write_simulation"]


class SimulationRecord(Protocol):
    """What :func:`write_simulation` needs of a simulation (``pospp.sim.api.Simulation`` is
    one; io does not import sim)."""

    @property
    def name(self) -> str: ...
    @property
    def imu(self) -> ImuSamples: ...
    @property
    def fix(self) -> GnssFixes: ...
    @property
    def vel(self) -> GnssVelocities: ...
    @property
    def params(self) -> dict[str, Any]: ...

    def truth_reference(self, rate_hz: float = 10.0) -> ReferenceTrajectory: ...

    def trigger_stamps_ns(self, rate_hz: float) -> np.ndarray: ...

    def realised_bias(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...

_BIAS_META = {
    b"pospp.generator": b"pospp.sim",
    b"frames": b"body FRD; realised bias = constant + ramp + Gauss-Markov, white noise "
               b"excluded; value of the IMU interval ending at time_ns",
}


def _write_bias(path: Path, sim: SimulationRecord, rate_hz: float) -> None:
    time_ns, gyro_bias_b_radps, accel_bias_b_mps2 = sim.realised_bias(rate_hz)
    g = gyro_bias_b_radps / DEG_PER_H_RADPS
    a = accel_bias_b_mps2 / UG_MPS2
    cols = {"time_ns": pa.array(time_ns, pa.int64())}
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
    sim: SimulationRecord, out_dir: str | Path, name: str | None = None, *,
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
