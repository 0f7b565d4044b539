"""Simulated survey missions for the slow Monte Carlo tests (pospp.sim profiles).

Test scaffolding shared by tests/unit/test_diagnose_null_mc.py, test_drift_honesty.py and
test_diagnose_power.py: the three-leg survey mission they fly and the object the pipeline's
stages read a simulated flight from.
"""

from __future__ import annotations

import dataclasses


@dataclasses.dataclass(frozen=True)
class SimLog:
    """A simulated flight as the pipeline's stages read it (the ``imu``, ``fix`` and ``vel``
    of :class:`pospp.io.mcap_reader.FlightLog`, straight from :func:`pospp.sim.api.simulate`)."""

    imu: object
    fix: object
    vel: object


def three_leg_survey(name: str, leg_s: float, *, lat_deg: float, lon_deg: float,
                     height_m: float, heading_deg: float) -> dict:
    """A pospp.sim profile: 60 s static, 20 s to 60 m/s, 60 s straight, then three survey legs
    of ``leg_s`` seconds, the second after a 180 deg turn and the third after a 90 deg turn
    (3 deg/s, coordinated), 50 Hz IMU."""
    return {
        "name": name, "imu_rate_hz": 50,
        "start": {"lat_deg": lat_deg, "lon_deg": lon_deg, "height_m": height_m,
                  "heading_deg": heading_deg},
        "options": {"turn_bank": "coordinated", "blend_s": 5.0},
        "segment": [
            {"type": "static", "duration_s": 60.0},
            {"type": "accelerate", "to_speed_mps": 60.0, "duration_s": 20.0},
            {"type": "straight", "duration_s": 60.0},
            {"type": "straight", "duration_s": leg_s, "kind": "survey"},
            {"type": "turn", "angle_deg": 180.0, "rate_dps": 3.0},
            {"type": "straight", "duration_s": leg_s, "kind": "survey"},
            {"type": "turn", "angle_deg": 90.0, "rate_dps": 3.0},
            {"type": "straight", "duration_s": leg_s, "kind": "survey"},
        ],
    }


def compare_sim_flight(seed: int, effect: str | None, *, noise_scale: float | None = None):
    """tests/benchmarks/bench_compare_sim.py's flight (14 min, take-off roll, two 180 deg
    turns, the IMU's noise 1/3 of the configured grade's unless ``noise_scale`` says
    otherwise: one of the bench's ``SCALES``) with ``effect`` at 3 x its detection limit
    there: the log, its configuration and the bench module
    (its ``run`` and ``_reading`` count a comparison as the Monte Carlo does)."""
    bench = compare_sim_bench()
    scale = bench.SCALES[0] if noise_scale is None else noise_scale
    if effect is None:
        return bench.flight(seed, scale), bench.CONFIG, bench
    size = 3.0 * bench.limit_at(effect, scale)
    return bench.flight(seed, scale, effect, size), bench.CONFIG, bench


def compare_sim_bench():
    """The module tests/benchmarks/bench_compare_sim.py (its mission ``profile()``, IMU
    ``truth_imu``, ``GNSS`` settings and ``LEVER_B_M``, its flights and effects)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_compare_sim.py"
    spec = importlib.util.spec_from_file_location("bench_compare_sim", path)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench
