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
