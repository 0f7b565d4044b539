"""Converter helpers: GPS -> UTC, velocity from positions, kinematic attitude, lag estimate."""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
import pytest

from pospp import earth
from pospp.io.converters._common import (
    ConversionError,
    gps_minus_utc_s,
    gps_to_unix_ns,
    kinematic_attitude,
    lag_by_correlation,
    velocity_from_positions,
)

GPS_EPOCH = datetime(1980, 1, 6, tzinfo=UTC)


def _gps_seconds(dt: datetime, leap: int) -> float:
    return (dt - GPS_EPOCH).total_seconds() + leap


@pytest.mark.parametrize(("when", "leap"), [
    (datetime(2013, 11, 29, 22, 0, 0, tzinfo=UTC), 16),   # IERS Bulletin C: 2012-07-01 -> 16
    (datetime(2018, 8, 2, 16, 14, 48, tzinfo=UTC), 18),   # 2017-01-01 -> 18
    (datetime(2016, 12, 31, 23, 59, 0, tzinfo=UTC), 17),
    (datetime(2005, 6, 1, tzinfo=UTC), 13),
])
def test_gps_to_utc_against_datetime(when, leap):
    g = _gps_seconds(when, leap) + 0.25
    assert gps_minus_utc_s(when.timestamp()) == leap
    assert int(gps_to_unix_ns([g])[0]) == int(when.timestamp()) * 10**9 + 250_000_000


def test_known_gps_week_tow():
    # GPS week 1768, TOW 511214.5 s (first ArduPilot GPS record): 2013-11-29T21:59:58.5 UTC
    ns = int(gps_to_unix_ns([1768 * 604800 + 511214.5])[0])
    assert datetime.fromtimestamp(ns // 10**9, tz=UTC) == datetime(2013, 11, 29, 21, 59, 58,
                                                                    tzinfo=UTC)
    assert ns % 10**9 == 500_000_000


def test_leap_second_inside_log_is_refused():
    g0 = _gps_seconds(datetime(2016, 12, 31, 23, 0, tzinfo=UTC), 17)
    with pytest.raises(ConversionError, match="leap second"):
        gps_to_unix_ns([g0, g0 + 7200.0])


def test_velocity_from_positions_recovers_constant_velocity():
    lat0, lon0, h0 = np.radians(30.0), np.radians(114.0), 20.0
    t = np.arange(0.0, 60.0, 1.0)
    v = np.array([8.0, -6.0, 0.5])
    lat, lon, h = earth.ned_to_llh(np.outer(t, v), lat0, lon0, h0)
    vn = velocity_from_positions(t, lat, lon, h)
    # straight line in a tangent plane at 480 m: curvature effect well below 1 mm/s
    np.testing.assert_allclose(vn, np.tile(v, (t.size, 1)), atol=2e-3)


def test_kinematic_attitude_holds_through_stops():
    v = np.array([[0.0, 0.0, 0.0], [0.0, 5.0, 0.0], [0.0, 0.1, 0.0], [-5.0, 0.0, -5.0]])
    rpy = kinematic_attitude(v)
    np.testing.assert_allclose(np.degrees(rpy[:, 2]), [90.0, 90.0, 90.0, 180.0])
    np.testing.assert_allclose(np.degrees(rpy[3, 1]), 45.0)  # climbing: v_D < 0
    assert np.all(rpy[:, 0] == 0.0)


def test_lag_by_correlation_finds_known_delay():
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 120.0, 0.01)
    x = np.convolve(rng.standard_normal(t.size), np.ones(50) / 50, mode="same")
    delay = 0.23
    lag, corr = lag_by_correlation(t, x, t + delay, x, max_lag_s=0.5)
    assert lag == pytest.approx(delay, abs=0.006)
    assert corr > 0.99
