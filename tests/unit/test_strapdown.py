"""Strapdown mechanization against error-free increments computed independently (issue 2).

The truths come from tests/unit/_truth_imu.py (analytic stationary rates; a rhumb line at
constant NED velocity integrated by scipy's DOP853 with Gauss-Legendre increments), never from
pospp's own kernel.
"""

from __future__ import annotations

import numpy as np
import pytest
from _truth_imu import TruthImu, oscillating_attitude, rhumb_line, stationary

from pospp import earth, rotation, units
from pospp.nav import closed_form, strapdown

ARCSEC = units.ARCSEC_RAD
ARCMIN = 60.0 * ARCSEC


def _integrate_truth(tr: TruthImu, *, rpy_error_rad=None, **kw) -> strapdown.Trajectory:
    c0 = tr.c_nb if rpy_error_rad is None else rpy_error_rad @ tr.c_nb
    x0 = strapdown.NavState(
        float(tr.lat_rad[0]), float(tr.lon_rad[0]), tr.height_m, tr.v_n_mps.copy(),
        rotation.quat_from_dcm(c0),
    )
    return strapdown.integrate(tr.t_s, tr.dtheta_b_rad, tr.dv_b_mps, x0, **kw)


def _errors(nav: strapdown.Trajectory, tr: TruthImu, every: int = 100):
    """Norms of the position [m], velocity [m/s] and attitude [rad] errors at every k-th epoch."""
    s = slice(0, None, every)
    dr = earth.llh_difference_ned_m(
        nav.lat_rad[s], nav.lon_rad[s], nav.height_m[s], tr.lat_rad[s], tr.lon_rad[s],
        tr.height_m,
    )
    dv = nav.v_n_mps[s] - tr.v_n_mps
    att = rotation.angle_between_rad(nav.c_nb[s], tr.c_nb)
    return np.linalg.norm(dr, axis=1), np.linalg.norm(dv, axis=1), att


def test_stationary_error_free_one_hour_at_40n():
    tr = stationary(np.radians(40.0), 120.0, np.radians([2.0, -3.0, 120.0]), 200.0, 3600.0)
    assert tr.dtheta_b_rad.shape == (720_000, 3)
    dr, dv, att = _errors(_integrate_truth(tr), tr)
    assert dv.max() < 1e-3  # m/s (brief: < 1 mm/s); measured ~1e-8
    assert dr.max() < 1.0  # m; measured ~1e-5
    assert att.max() < 0.01 * ARCSEC


@pytest.fixture(scope="module")
def flight_1h() -> TruthImu:
    # constant NED velocity: 60 m/s, heading 30 deg, 1000 m, from 40 N; 1 h at 200 Hz
    return rhumb_line(np.radians(40.0), 1000.0, 60.0, np.radians(30.0), 200.0, 3600.0)


def test_constant_velocity_level_flight_one_hour(flight_1h):
    tr = flight_1h
    assert tr.dtheta_b_rad.shape == (720_000, 3)
    # the truth really flies ~3.1 km north-east per minute at heading 30 deg
    d = earth.llh_difference_ned_m(tr.lat_rad[12_000], tr.lon_rad[12_000], 1000.0,
                                   tr.lat_rad[0], tr.lon_rad[0], 1000.0)
    assert np.degrees(np.arctan2(d[1], d[0])) == pytest.approx(30.0, abs=0.01)
    assert np.hypot(d[0], d[1]) == pytest.approx(3600.0, rel=1e-4)
    dr, dv, att = _errors(_integrate_truth(tr), tr)
    assert dr.max() < 1.0  # m (measured ~2e-5 m)
    assert dv.max() < 0.01  # m/s (measured ~4e-8 m/s)
    assert att.max() < 2.0 * ARCSEC  # (measured ~4e-6 arcsec)


def _height_aided(tr: TruthImu, c0: np.ndarray, chunk: int) -> strapdown.Trajectory:
    """Free-inertial horizontal channels, vertical channel reset to the truth every chunk.

    The pure-inertial vertical channel is unstable (time constant sqrt(R / 2 g) ~ 9.5 min) and
    the Schuler velocity error feeds it through the Coriolis term (2 Omega cos L dv_E), which
    would wreck an 85 min run; an altimeter-like reset of h and v_D isolates the horizontal
    Schuler loop that the closed forms model.
    """
    n = tr.dtheta_b_rad.shape[0]
    x = strapdown.NavState(float(tr.lat_rad[0]), float(tr.lon_rad[0]), tr.height_m,
                           tr.v_n_mps.copy(), rotation.quat_from_dcm(c0))
    parts = [x.as_vector()[None]]
    for k in range(0, n, chunk):
        prev = None if k == 0 else (tr.dtheta_b_rad[k - 1], tr.dv_b_mps[k - 1])
        seg = strapdown.integrate(tr.t_s[k:k + chunk + 1], tr.dtheta_b_rad[k:k + chunk],
                                  tr.dv_b_mps[k:k + chunk], x, previous_increments=prev)
        end = seg.state(len(seg) - 1)
        v = end.v_n_mps.copy()
        v[2] = tr.v_n_mps[2]
        x = strapdown.NavState(end.lat_rad, end.lon_rad, tr.height_m, v, end.q_nb)
        parts.append(np.column_stack([seg.lat_rad, seg.lon_rad, seg.height_m, seg.v_n_mps,
                                      seg.q_nb])[1:])
    return strapdown.Trajectory.from_state_array(tr.t_s, np.concatenate(parts))


def test_one_arcmin_tilt_gives_the_schuler_oscillation_of_the_closed_form():
    lat, h = np.radians(40.0), 0.0
    tr = stationary(lat, h, np.radians([0.0, 0.0, 0.0]), 50.0, 5400.0)
    phi = np.array([ARCMIN, 0.0, 0.0])  # tilt about north, C_nb_hat = (I - [phi x]) C_nb
    nav = _height_aided(tr, rotation.dcm_from_rotvec(-phi) @ tr.c_nb, chunk=500)
    dv_e = nav.v_n_mps[:, 1]
    t = tr.t_s
    # the sign of the closed form: dv_E = -omega R sin(omega t) phi_N (first swing negative)
    _, om_e = closed_form.schuler_frequencies_radps(lat, h)
    amp = om_e * float(earth.principal_radii_m(lat)[1] + h) * ARCMIN  # ~2.3 m/s
    assert dv_e[np.argmin(np.abs(t - np.pi / 2 / om_e))] < 0
    # period from the zero crossings of dv_E (half and full period)
    sgn = np.signbit(dv_e[1:])
    k = np.nonzero(sgn[1:] != sgn[:-1])[0] + 1
    tz = t[k] - dv_e[k] * (t[k + 1] - t[k]) / (dv_e[k + 1] - dv_e[k])
    tz = tz[tz > 60.0]
    period_min = tz[1] / 60.0
    assert abs(period_min - 84.4) < 0.5
    assert abs(2 * tz[0] / 60.0 - 84.4) < 0.5
    # amplitude: peak horizontal speed error in the first half period (Foucault rotation of
    # the oscillation plane is 0.06 rad at the peak, a 0.2 % effect)
    first = t < tz[0]
    peak = np.linalg.norm(nav.v_n_mps[first, 0:2], axis=1).max()
    assert peak == pytest.approx(amp, rel=0.02)
    # and the whole first swing follows the closed form within 2 % of the amplitude
    rows = closed_form.velocity_error_rows(t[first], lat_rad=lat, height_m=h, v_n_mps=[0, 0])
    assert np.abs(dv_e[first] - rows[:, 1, 0] * ARCMIN).max() < 0.02 * amp


def _coning_errors(amp_deg, freq_hz, rate_hz, duration_s):
    lat = np.radians(40.0)
    t, dth, dv, c_nb = oscillating_attitude(
        lat, 100.0, np.radians(amp_deg), freq_hz, np.radians(60.0), rate_hz, duration_s
    )
    x0 = strapdown.NavState(lat, 0.0, 100.0, np.zeros(3), rotation.quat_from_dcm(c_nb[0]))
    nav = strapdown.integrate(t, dth, dv, x0)
    att = rotation.angle_between_rad(nav.c_nb[-1], c_nb[-1])
    return att, np.abs(nav.v_n_mps).max(axis=0)


def test_coning_and_sculling_under_an_oscillating_attitude():
    """Roll and pitch oscillating 90 deg apart (coning) with the specific force rotating in the
    body (sculling), on a stationary IMU: the truth attitude is analytic, velocity is zero."""
    # realistic: 1 deg at 2 Hz, 200 Hz IMU, 30 s (measured 0.007 arcsec, 2.8e-7 m/s
    # horizontal, 5e-8 m/s vertical; without the second-order rotation term
    # dtheta x (dtheta x dv) / 6 of the velocity update the vertical error was 5.9e-5 m/s)
    att, v = _coning_errors(1.0, 2.0, 200.0, 30.0)
    assert att < 0.05 * ARCSEC
    assert v.max() < 3e-6
    # severe coning (0.5 deg at 10 Hz): the uncompensated coning drift would be
    # Omega a^2 / 2 = 2.4e-3 rad/s (500 arcsec/s); the two-sample correction leaves a residual
    # of 4th order in the sampling interval, so halving dt divides it by ~16 (measured 15.4)
    att_100, _ = _coning_errors(0.5, 10.0, 100.0, 10.0)
    att_200, _ = _coning_errors(0.5, 10.0, 200.0, 10.0)
    assert att_100 < 30.0 * ARCSEC
    assert 12.0 < att_100 / att_200 < 20.0


def test_split_integration_with_previous_increments_is_seamless():
    tr = rhumb_line(np.radians(-20.0), 300.0, 60.0, np.radians(200.0), 100.0, 20.0)
    full = _integrate_truth(tr)
    k = 777
    x_k = full.state(k)
    second = strapdown.integrate(
        tr.t_s[k:], tr.dtheta_b_rad[k:], tr.dv_b_mps[k:], x_k,
        previous_increments=(tr.dtheta_b_rad[k - 1], tr.dv_b_mps[k - 1]),
    )
    # only the first step differs: no state before x_k for the mid-interval extrapolation
    np.testing.assert_allclose(second.v_n_mps, full.v_n_mps[k:], rtol=0, atol=1e-10)
    np.testing.assert_allclose(second.q_nb, full.q_nb[k:], rtol=0, atol=1e-15)
    np.testing.assert_allclose(second.lat_rad, full.lat_rad[k:], rtol=0, atol=1e-15)


def test_bias_arguments_remove_measured_bias():
    rng = np.random.default_rng(7)
    tr = rhumb_line(np.radians(50.0), 0.0, 30.0, np.radians(75.0), 100.0, 30.0)
    n = tr.dtheta_b_rad.shape[0]
    dt = np.diff(tr.t_s)[:, None]
    bg = rng.normal(0, 1e-5, 3)
    ba = rng.normal(0, 1e-3, (n, 3))  # per interval
    clean = _integrate_truth(tr)
    biased = TruthImu(tr.t_s, tr.dtheta_b_rad + bg * dt, tr.dv_b_mps + ba * dt, tr.lat_rad,
                      tr.lon_rad, tr.height_m, tr.v_n_mps, tr.c_nb, tr.rpy_rad)
    comp = _integrate_truth(biased, gyro_bias_b_radps=bg, accel_bias_b_mps2=ba)
    np.testing.assert_allclose(comp.v_n_mps, clean.v_n_mps, rtol=0, atol=1e-11)
    raw = _integrate_truth(biased)
    assert np.abs(raw.v_n_mps - clean.v_n_mps).max() > 1e-3


def test_increments_from_rates_drops_the_first_sample():
    t_ns = 1_000_000_000 + np.arange(5, dtype=np.int64) * 5_000_000
    w = np.arange(15.0).reshape(5, 3)
    f = -np.arange(15.0).reshape(5, 3)
    t_s, dth, dv = strapdown.increments_from_rates(t_ns, w, f, epoch_ns=1_000_000_000)
    np.testing.assert_allclose(t_s, np.arange(5) * 0.005)
    np.testing.assert_allclose(dth, w[1:] * 0.005)
    np.testing.assert_allclose(dv, f[1:] * 0.005)


# --- bad input ------------------------------------------------------------------------------


def _small_series(n=10):
    tr = stationary(0.5, 0.0, [0.0, 0.0, 0.0], 100.0, n / 100.0)
    x0 = strapdown.NavState(0.5, 0.0, 0.0, np.zeros(3), np.array([1.0, 0, 0, 0]))
    return tr.t_s.copy(), tr.dtheta_b_rad.copy(), tr.dv_b_mps.copy(), x0


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("which", ["dtheta_b_rad", "dv_b_mps"])
def test_non_finite_sample_is_named(bad, which):
    t, dth, dv, x0 = _small_series()
    (dth if which == "dtheta_b_rad" else dv)[6, 1] = bad
    with pytest.raises(ValueError, match=rf"{which}: non-finite value in sample 6 \(interval "
                       r"ending t = 0\.070000 s\)"):
        strapdown.integrate(t, dth, dv, x0)


@pytest.mark.parametrize(("k", "value"), [(4, None), (4, -1.0)])
def test_non_increasing_time_is_named(k, value):
    t, dth, dv, x0 = _small_series()
    t[k] = t[k - 1] if value is None else t[k - 1] + value  # zero / negative interval
    with pytest.raises(ValueError, match=rf"t_s: time not increasing at sample {k}"):
        strapdown.integrate(t, dth, dv, x0)


def test_non_finite_time_and_shapes_are_reported():
    t, dth, dv, x0 = _small_series()
    t2 = t.copy()
    t2[3] = np.nan
    with pytest.raises(ValueError, match="t_s: non-finite time at sample 3"):
        strapdown.integrate(t2, dth, dv, x0)
    with pytest.raises(ValueError, match=r"t_s: expected shape \(11,\) for 10 increments"):
        strapdown.integrate(t[:-1], dth, dv, x0)
    with pytest.raises(ValueError, match=r"dv_b_mps: expected shape \(10, 3\)"):
        strapdown.integrate(t, dth, dv[:, :2], x0)
    with pytest.raises(ValueError, match=r"gyro_bias_b_radps: expected shape \(3,\) or \(10, 3\)"):
        strapdown.integrate(t, dth, dv, x0, gyro_bias_b_radps=np.zeros(2))


def test_check_increments_returns_the_intervals():
    t, dth, dv, _ = _small_series()
    t[5:] += 0.002  # one longer interval is fine
    np.testing.assert_allclose(strapdown.check_increments(t, dth, dv), np.diff(t))


def test_compiled_step_equals_the_plain_python_step():
    """numba's compiled step against the same source run by the interpreter (no fastmath
    surprises); random states, increments and extrapolation weights."""
    from pospp.nav import _kernels

    rng = np.random.default_rng(11)
    for _ in range(20):
        x = np.concatenate([[rng.uniform(-1.4, 1.4), rng.uniform(-3, 3), rng.uniform(-100, 9e3)],
                            rng.normal(0, 50, 3), rotation.quat_from_rotvec(rng.normal(0, 1, 3))])
        x_prev = x + np.concatenate([rng.normal(0, 1e-6, 3), rng.normal(0, 0.1, 3), np.zeros(4)])
        args = (x, x_prev, rng.normal(0, 1e-2, 3), rng.normal(0, 5e-2, 3),
                rng.normal(0, 1e-2, 3), rng.normal(0, 5e-2, 3), 0.005, rng.uniform(0, 0.6))
        out_c, out_p = np.empty(10), np.empty(10)
        _kernels.strapdown_step(*args, out_c)
        _kernels.strapdown_step.py_func(*args, out_p)
        np.testing.assert_allclose(out_c, out_p, rtol=1e-14, atol=1e-15)
