"""The smoothed compensation's pieces (pospp.calib.bias_smoother, compensate's modes).

- the compiled RTS smoother against the Gaussian conditional mean of the same model written
  out densely (covariances from their definition, numpy solve);
- the decorrelation of a filter's output into its measurements: a scalar Kalman filter's
  outputs give back the measurements and variances it was fed;
- the fit's estimate of a leg's mean gyro error sees a bias that only one leg carries, with
  its sign;
- the choice of a history: the least score wins, and the constant is kept when every other
  candidate does worse on the fitted legs.
"""

from __future__ import annotations

import numpy as np
import pytest

from pospp.calib._bias_kernel import smooth_two_gm
from pospp.calib.bias_smoother import (
    ForwardBiases,
    fit_bias_history,
    fitted_leg_bias,
    pseudo_measurements,
)
from pospp.units import DEG_PER_H_RADPS as DPH


def _dense_conditional_mean(t: np.ndarray, z: np.ndarray, r: np.ndarray,
                            comps: list[tuple[float, float]]) -> np.ndarray:
    """E[x1 + x2 | z] for independent stationary Gauss-Markov components (covariance
    s2 exp(-|t_i - t_j| / tau)), z = x1 + x2 + e at the cells where r is finite."""
    dt = np.abs(t[:, None] - t[None, :])
    k = sum(s2 * np.exp(-dt / tau) for s2, tau in comps)
    m = np.isfinite(r)
    kzz = k[np.ix_(m, m)] + np.diag(r[m])
    return k[:, m] @ np.linalg.solve(kzz, z[m])


@pytest.mark.parametrize("taus", [(300.0, 10.0), (3600.0, 10.0), (50.0, 5.0)])
def test_compiled_smoother_is_the_gaussian_conditional_mean(taus):
    rng = np.random.default_rng(4)
    n, step = 400, 1.0
    t = np.arange(n) * step
    s2 = np.array([0.3, 0.05])
    r = np.full(n, np.inf)
    seen = rng.random(n) < 0.7  # gaps: cells with no measurement
    r[seen] = rng.uniform(0.05, 2.0, seen.sum())
    z = np.where(seen, rng.normal(0.0, 1.0, n), 0.0)
    f = np.exp(-step / np.array(taus))
    got = smooth_two_gm(z[:, None].copy(), r[:, None].copy(), f, s2)[:, 0]
    want = _dense_conditional_mean(t, z, r, [(s2[0], taus[0]), (s2[1], taus[1])])
    assert np.allclose(got, want, rtol=1e-8, atol=1e-10 * np.abs(want).max())


def test_pseudo_measurements_give_back_a_scalar_filters_measurements():
    """A scalar random-walk filter (PSD q) with a measurement every second, output every
    0.1 s: the decorrelation returns each measurement and its variance."""
    rng = np.random.default_rng(1)
    q, dt = 2e-4, 0.1
    t = np.arange(0.0, 60.0 + 1e-9, dt)
    meas_t = np.arange(1.0, 60.0 + 1e-9, 1.0)
    z_true = rng.normal(0.0, 1.0, meas_t.size)
    r_true = rng.uniform(0.2, 3.0, meas_t.size)
    b, p = 0.0, 4.0
    out_b, out_p = [], []
    j = 0
    for k, tk in enumerate(t):
        if k:
            p += q * dt
        if j < meas_t.size and abs(tk - meas_t[j]) < 1e-9:
            gain = p / (p + r_true[j])
            b += gain * (z_true[j] - b)
            p *= 1.0 - gain
            j += 1
        out_b.append(b)
        out_p.append(p)
    col = np.array(out_b)[:, None] * np.ones(3)
    sig = np.sqrt(np.array(out_p))[:, None] * np.ones(3)
    fwd = ForwardBiases(t, col, sig, meas_t, q)
    t_m, z, var = pseudo_measurements(fwd)
    assert np.allclose(t_m, meas_t)
    assert np.allclose(z[:, 0], z_true, rtol=1e-6, atol=1e-8)
    assert np.allclose(var[:, 1], r_true, rtol=1e-6)


def test_a_bias_on_one_leg_only_moves_that_legs_estimate(gm_legs):
    """The gyro carrying on leg 1 only an extra 0.05 deg/h on x, which the fitted constant
    takes a third of: each leg's estimated mean gyro error moves from the constant with the
    sign of its true deviation (+2/3 of the extra on leg 1, -1/3 on the others), leg 1's by
    at least 40 % of it (measured 63 %; the drift's mean alone moves it by less than 1 %);
    the history holds it inside leg 1 and the constant outside."""
    cal, reps, extra = gm_legs[:3]
    b0 = cal.gyro_bias_b_radps()
    true_dev = {lid: (extra if lid == 1 else 0.0) - (b0[0] - 0.3 * DPH) for lid in reps}
    moved = {lid: (fitted_leg_bias(cal, rep) - b0)[0] for lid, rep in reps.items()}
    assert all(np.sign(moved[i]) == np.sign(true_dev[i]) for i in reps), (moved, true_dev)
    assert moved[1] > 0.4 * true_dev[1]
    assert abs(cal.leg_drift_b_radps(reps[1])[0]) < 0.01 * true_dev[1]
    hist = fit_bias_history(cal, reps, np.array([reps[1].t0_s + 100.0, reps[1].t0_s - 30.0]))
    assert np.allclose(hist[0], fitted_leg_bias(cal, reps[1]))
    assert abs(hist[1, 0] - b0[0]) < abs(hist[0, 0] - b0[0])


@pytest.fixture(scope="module")
def gm_legs():
    """Three 300 s legs (headings 20 / 200 / 20 deg, 60 m/s, 20 Hz) of a synthetic survey
    whose truth is the strapdown's own solution (tests/unit/_synthetic.py); the gyro carries
    [0.3, -0.2, 0] deg/h and, over leg 1 only, 0.05 deg/h more on x; B minus A with 5 mm/s
    of white noise. Joint body fit with an ARW of 0.01 deg/sqrt(h) (a leg's white-noise mean
    then has a sigma of 0.035 deg/h) and a Gauss-Markov drift too small to take the offset
    (0.001 deg/h, 300 s given): what moves leg 1 is the white noise's leg mean."""
    from _synthetic import noisy_replays, survey_flight

    from pospp.calib.solve import FitOptions, fit_calibration

    flight = survey_flight(headings_deg=(20.0, 200.0, 20.0), rate_hz=20.0)
    extra = 0.05 * DPH
    imu = flight.imu
    bias = np.tile(np.array([0.3, -0.2, 0.0]) * DPH, (imu.t_s.size - 1, 1))
    leg1 = flight.legs[1]
    on1 = (imu.t_s[:-1] >= leg1.start_s - 5.0) & (imu.t_s[:-1] <= leg1.end_s + 5.0)
    bias[on1, 0] += extra
    noisy = type(imu)(imu.t_s, imu.dtheta_b_rad + bias * np.diff(imu.t_s)[:, None],
                      imu.dv_b_mps)
    reps = {r.leg.leg_id: r for r in noisy_replays(flight, noisy, sigma_mps=0.005,
                                                    rng=np.random.default_rng(3))}
    cal = fit_calibration(tuple(reps.values()), "body",
                          FitOptions(gyro_arw_radpsqrts=0.01 * np.pi / 180 / 60,
                                     gyro_gm_sigma_radps=0.001 * DPH, gyro_gm_tau_s=300.0))
    return cal, reps, extra, noisy, flight.solution_a(0.005), bias


def _replayed_score_m(inputs, history) -> float:
    """The score :func:`history_scores_m` stands for, by replaying B on each fitted leg with
    the history removed from the gyro increments (interpolated at each interval's middle)."""
    from pospp.calib.replay import ImuIncrements, replay_errors

    cal, rc, imu = inputs.cal, inputs.replay, inputs.imu
    mid = 0.5 * (imu.t_s[:-1] + imu.t_s[1:])
    bias = np.stack([np.interp(mid, history[0], history[1][:, c]) for c in range(3)], axis=1)
    removed = ImuIncrements(imu.t_s, imu.dtheta_b_rad - bias * np.diff(imu.t_s)[:, None],
                            imu.dv_b_mps)
    sq = []
    for lid in cal.leg_ids:
        rep = inputs.replays[lid]
        dr = replay_errors(removed, inputs.solution_a, rep.leg, gyro_bias_b_radps=np.zeros(3),
                           attitude_correction_n_rad=cal.misalignment_n_rad(lid),
                           accel_compensation=rc.accel_compensation,
                           sample_rate_hz=rc.sample_rate_hz).dr_n_m
        k = int(np.searchsorted(rep.t_s, rc.horizon_s - 1e-9))
        sq.append(np.sum(np.square(dr[1:k + 1, 0:2]), axis=1))
    return float(np.sqrt(np.mean(np.concatenate(sq))))


def test_the_history_chosen_is_the_one_b_matches_best(gm_legs):
    """Among the constant, the fit's history (which holds leg 1's offset) and the injected
    bias 1 deg/h off, the fitted legs take the fit's (B's position error over the legs 1.6 m
    RMS against 2.5 m with the constant); time outside the fitted legs takes the best of the
    candidates named for it (the constant over the off one). Without the fit's, the constant
    everywhere. The scores (one replay per leg and B's linear response to each history) are
    B replayed with each history removed, to 1e-4 of the score."""
    from pospp.calib.compensate import ModeInputs, choose_bias_history, history_scores_m
    from pospp.calib.replay import ReplayOptions

    cal, reps, _, imu, sol, bias = gm_legs
    inputs = ModeInputs(imu, sol, reps, cal, np.full(3, 0.01 * DPH), ReplayOptions())
    grid = np.arange(0.0, imu.t_s[-1], 1.0)
    const_h = (grid, np.tile(cal.gyro_bias_b_radps(), (grid.size, 1)))
    fit_h = (grid, fit_bias_history(cal, reps, grid))
    off_h = (grid, np.interp(grid, imu.t_s[:-1], bias[:, 0])[:, None] * [1, 0, 0]
             + bias[0] * [0, 1, 1] + 1.0 * DPH)
    made = {"constant": const_h, "fit": fit_h, "off": off_h}
    pick = choose_bias_history(inputs, made, ("constant", "off"))
    assert pick.source == "fit on the fitted legs, constant elsewhere"
    t, b = pick.kwargs["gyro_bias_history"]
    inside = (t >= reps[1].t0_s) & (t <= reps[1].t0_s + reps[1].t_s[-1])
    assert np.array_equal(b[inside], fit_h[1][inside])
    before = t < reps[0].t0_s - 2.0
    assert before.any() and np.array_equal(b[before], const_h[1][before])
    del made["fit"]
    pick = choose_bias_history(inputs, made, ("constant", "off"))
    assert pick.source == "constant"
    scores = history_scores_m(inputs, {"fit": fit_h, "constant": const_h, "off": off_h})
    assert scores["fit"] < scores["constant"] < scores["off"]
    for name, h in (("fit", fit_h), ("constant", const_h), ("off", off_h)):
        assert scores[name] == pytest.approx(_replayed_score_m(inputs, h), rel=1e-4), name


def test_two_sigmas_from_null_realisations(gm_legs):
    """Null realisations that are each a constant gyro offset on every leg (B minus A's exact
    response to it, the offset recorded as what was injected): the turn-on constant's sigma
    is the offsets' spread (the fit cannot tell an offset from the constant), the flight's
    bias follows each offset exactly, so its sigma against the injected truth is ~0; without
    the injected means the flight's sigma is the constant's."""
    from pospp.calib.null_covariance import with_null_covariance
    from pospp.calib.replay import replay_leg
    from pospp.calib.stage import CalibrationOptions, calibrate_flight

    cal, reps, _, imu, sol, _ = gm_legs
    legs = tuple(r.leg for r in reps.values())
    run = calibrate_flight(imu, sol,
                           CalibrationOptions(formulations=("body",), gyro_arw_dpsh=0.01,
                                              gyro_gm_sigma_dph=0.001, gyro_gm_tau_s=300.0),
                           legs=legs)
    rng = np.random.default_rng(11)
    offsets = rng.normal(0.0, 0.05, (6, 3)) * DPH * np.array([1.0, 1.0, 0.0])
    null, injected = [], []
    for d in offsets:
        shifted = type(imu)(imu.t_s, imu.dtheta_b_rad + d * np.diff(imu.t_s)[:, None],
                            imu.dv_b_mps)
        null.append([replay_leg(shifted, sol, r.leg).dv_n_mps - replay_leg(imu, sol, r.leg)
                     .dv_n_mps for _, r in sorted(run.replays.items())])
        injected.append(np.tile(d, (len(run.replays), 1)))
    spread = np.sqrt(np.mean(offsets[:, :2] ** 2, axis=0))
    both = with_null_covariance(run, null, injected)
    assert np.allclose(both.gyro_bias_sigma_b_radps[:2], spread, rtol=0.02)
    assert np.all(both.flight_gyro_bias_sigma_b_radps[:2] < 0.02 * spread)
    one = with_null_covariance(run, null)
    assert np.allclose(one.flight_gyro_bias_sigma_b_radps[:2], one.gyro_bias_sigma_b_radps[:2])
    cols = both.tables(0)["calibration"]
    rows = {p: s for p, s, pid in zip(cols["parameter"], cols["sigma"], cols["pair_id"],
                                      strict=True) if pid == -1}
    assert rows["gyro_bias_x_flight"] == pytest.approx(
        both.flight_gyro_bias_sigma_b_radps[0] / DPH)
    assert rows["gyro_bias_x"] == pytest.approx(both.gyro_bias_sigma_b_radps[0] / DPH)
    summary = both.summary()
    assert summary["gyro_bias_y_flight_sigma_dph"] == pytest.approx(
        both.flight_gyro_bias_sigma_b_radps[1] / DPH)
