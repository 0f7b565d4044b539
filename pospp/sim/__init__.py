"""Simulator: mission profiles, exact IMU increments, sensor errors, GNSS (docs/simulator.md).

Modules: ``profile`` (TOML -> plan), ``ramps`` (C2 smooth schedules), ``trajectory`` (true
motion), ``imu`` (exact increments), ``sensors`` (IMU error models), ``gnss``, ``api``
(``simulate``, ``simulate_along``, ``load_profile``, ``imu_grade``). Nothing is imported here.
"""
