"""The convert command's mounting step (issue 17 item 2): the parser leaves the IMU in sensor
axes with the estimate's inputs; ``pospp.convert`` estimates, rotates and writes."""

from __future__ import annotations

import numpy as np
import pytest

from pospp import rotation
from pospp.convert import estimate_parsed_mounting
from pospp.io.converters import MountingInput, ParsedLog, write_parsed
from pospp.io.mcap_reader import read_flight_log
from pospp.types import GnssFixes, GnssVelocities, ImuSamples
from tests.unit.test_mounting import LAT, _synthetic

T0_NS = 1_717_200_000_000_000_000
C_SB = rotation.dcm_from_euler(np.radians([3.0, -4.0, 90.0]))


def _parsed(*, apply: bool, options: dict[str, float] | None = None) -> ParsedLog:
    t, f_s, tv, v = _synthetic(C_SB, noise_mps2=0.0, seed=1)
    w_s = np.tile([0.0, 0.0, 0.01], (t.size, 1)) @ C_SB.T  # a constant body z rate
    time_ns = T0_NS + np.round(t * 1e9).astype(np.int64) + 10_000_000
    fix_ns = T0_NS + np.round(tv * 1e9).astype(np.int64) + 10_000_000
    m = fix_ns.size
    return ParsedLog(
        fmt="synthetic", source="test", imu=ImuSamples(time_ns, w_s, f_s, "s"),
        fix=GnssFixes(fix_ns, np.full(m, LAT), np.zeros(m), np.zeros(m),
                      np.tile(np.eye(3), (m, 1, 1)), np.zeros(m, np.int8)),
        vel=GnssVelocities(fix_ns, v, np.tile(np.eye(3) * 0.01, (m, 1, 1))), reference=None,
        time_system="test", height_datum="test", imu_convention="test", axes="sensor axes",
        mounting=MountingInput(t_s=t, f_s_mps2=f_s, t_vel_s=tv, v_n_mps=v, lat_rad=LAT,
                               height_m=0.0, body_rpy_rad=None, options=options or {},
                               apply=apply, description="test mounting"),
    )


def test_applied_mounting_rotates_the_imu_into_body_axes(tmp_path):
    parsed, est = estimate_parsed_mounting(_parsed(apply=True))
    assert est is not None
    # the data-generating model: C_bs = C_sb^T, so the body rate is [0, 0, 0.01] rad/s
    assert np.degrees(rotation.angle_between_rad(est.c_bs, C_SB.T)) < 0.05
    assert parsed.imu is not None
    np.testing.assert_allclose(parsed.imu.w_ib_b_radps, [[0.0, 0.0, 0.01]] * len(parsed.imu),
                               atol=0.01 * np.radians(0.05))
    assert "rotated to body FRD" in parsed.axes and parsed.notes[0].startswith("test mounting")
    rep = write_parsed(parsed, tmp_path / "x.mcap", mounting=est)
    assert rep.mounting is est and rep.n_imu == len(parsed.imu)
    log = read_flight_log(tmp_path / "x.mcap", check_units=False)  # written FLU, read FRD
    np.testing.assert_allclose(log.imu.w_ib_b_radps, parsed.imu.w_ib_b_radps, rtol=0,
                               atol=1e-15)


def test_reported_mounting_is_not_applied_and_a_failure_is_a_note():
    before = _parsed(apply=False)
    parsed, est = estimate_parsed_mounting(before)
    assert est is not None and parsed.imu is before.imu
    parsed, est = estimate_parsed_mounting(_parsed(apply=False,
                                                   options={"min_static_windows": 10_000}))
    assert est is None and "test mounting not estimated: levelling needs" in parsed.notes[-1]
    with pytest.raises(ValueError, match="levelling needs"):
        estimate_parsed_mounting(_parsed(apply=True, options={"min_static_windows": 10_000}))
