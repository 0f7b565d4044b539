"""Evaluation against a reference: known offsets and rotations are recovered exactly."""

from __future__ import annotations

import numpy as np

from pospp import earth, rotation
from pospp.evaluate import solution_errors


def test_known_offsets_are_recovered():
    rng = np.random.default_rng(3)
    n = 200
    t_ref = np.arange(n, dtype=np.int64) * 100_000_000 + 1_700_000_000_000_000_000
    lat = np.radians(40.0) + np.linspace(0, 1e-3, n)
    lon = np.radians(116.0) + np.linspace(0, 2e-3, n)
    h = np.full(n, 500.0)
    v = rng.normal(0, 5, (n, 3))
    rpy = np.column_stack([np.radians(2.0) * np.ones(n), np.radians(-1.0) * np.ones(n),
                           np.linspace(0.1, 0.4, n)])
    # the solution: 1 m north, -2 m east, 0.5 m down; v + [0.1, 0, -0.2]; attitude rotated by
    # a known phi: C_est = exp(-[phi x]) C_ref
    offset = np.array([1.0, -2.0, 0.5])
    # the solution epochs fall half-way between reference epochs; position and heading are
    # linear in time, so the interpolated reference there is exact
    lat_mid = lat + 0.5 * (lat[1] - lat[0])
    lon_mid = lon + 0.5 * (lon[1] - lon[0])
    r_m, r_n = earth.principal_radii_m(lat_mid)
    lat_s = lat_mid + offset[0] / (r_m + h)
    lon_s = lon_mid + offset[1] / ((r_n + h) * np.cos(lat_mid))
    h_s = h - offset[2]
    v_mid = np.vstack([0.5 * (v[:-1] + v[1:]), v[-1:]])
    rpy_mid = rpy.copy()
    rpy_mid[:, 2] += 0.5 * (rpy[1, 2] - rpy[0, 2])
    phi = np.radians([10.0, -20.0, 60.0]) / 3600.0
    c_ref = rotation.dcm_from_euler(rpy_mid)
    c_est = rotation.dcm_from_rotvec(-phi) @ c_ref
    err = solution_errors(
        t_ref[5:-5] + 50_000_000, lat_s[5:-5], lon_s[5:-5], h_s[5:-5], v_mid[5:-5] +
        [0.1, 0.0, -0.2], rotation.euler_from_dcm(c_est)[5:-5],
        ref_time_ns=t_ref, ref_lat_rad=lat, ref_lon_rad=lon, ref_height_m=h, ref_v_n_mps=v,
        ref_rpy_rad=rpy,
    )
    # half-way between reference epochs the reference is interpolated: the offsets stand
    np.testing.assert_allclose(err.pos_ned_m, np.tile(offset, (len(err.time_ns), 1)),
                               atol=2e-3)
    np.testing.assert_allclose(err.att_ned_rad, np.tile(phi, (len(err.time_ns), 1)),
                               atol=np.radians(0.01 / 3600))
    np.testing.assert_allclose(err.vel_ned_mps, np.tile([0.1, 0.0, -0.2], (len(err.time_ns), 1)),
                               atol=1e-9)
    rms = err.rms()
    assert abs(rms["heading_rms_rad"] - phi[2]) < 1e-9
