"""The calibration stage on bad geometry: it completes, returns what it could and says why.

Exact IMU data of a stationary IMU and of straight rhumb lines (tests/unit/_truth_imu.py);
the truth is algorithm A. Also the observability study (paper Fig. 4 and 5) on its table.
"""

from __future__ import annotations

import numpy as np
import pytest
from _truth_imu import rhumb_line, stationary

from pospp import rotation, units
from pospp.calib.observability import condition_grid, observability_table
from pospp.calib.pairs import PairPolicy
from pospp.calib.replay import ImuIncrements, solution_a_from_trajectory
from pospp.calib.segment import Leg
from pospp.calib.stage import CalibrationOptions, calibrate_flight
from pospp.io.parquet_tables import write_table
from pospp.nav.strapdown import Trajectory

LAT = np.radians(40.0)


def _flight(tr, n):
    v = np.tile(tr.v_n_mps, (n, 1))
    q = np.tile(rotation.quat_from_dcm(tr.c_nb), (n, 1))
    traj = Trajectory(tr.t_s, tr.lat_rad, tr.lon_rad, np.full(n, tr.height_m), v, q)
    return (ImuIncrements(tr.t_s, tr.dtheta_b_rad, tr.dv_b_mps),
            solution_a_from_trajectory(traj, v_sigma_n_mps=[0.02, 0.02, 0.05]))


def _check_tables(run, tmp_path):
    for name, cols in run.tables(epoch_ns=1_700_000_000_000_000_000).items():
        write_table(tmp_path / f"{name}.parquet", cols, name, metadata={})


def test_no_straight_leg(tmp_path):
    tr = stationary(LAT, 100.0, [0.0, 0.0, 0.3], 10.0, 400.0)
    run = calibrate_flight(*_flight(tr, tr.t_s.size))
    assert not run.calibrated and run.legs == () and run.pairs == ()
    assert run.reason.startswith("no calibration: no straight, level, uniform leg")
    assert np.all(run.gyro_bias_b_radps == 0) and np.all(np.isinf(run.gyro_bias_sigma_b_radps))
    _check_tables(run, tmp_path)


def test_legs_too_short():
    tr = rhumb_line(LAT, 100.0, 20.0, 0.5, 10.0, 200.0)
    run = calibrate_flight(*_flight(tr, tr.t_s.size))
    assert not run.calibrated and "285 s" in run.reason


def test_single_leg(tmp_path):
    tr = rhumb_line(LAT, 100.0, 20.0, 0.5, 10.0, 400.0)
    run = calibrate_flight(*_flight(tr, tr.t_s.size))
    assert len(run.legs) == 1 and len(run.replays) == 1
    assert not run.calibrated and "only one leg" in run.reason
    _check_tables(run, tmp_path)


@pytest.fixture(scope="module")
def one_line():
    tr = rhumb_line(LAT, 100.0, 20.0, 0.5, 10.0, 700.0)
    hd = 0.5
    legs = (Leg(0, 10.0, 330.0, hd, 20.0, 100.0, 0, 0, 0, 0),
            Leg(1, 340.0, 660.0, hd, 20.0, 100.0, 0, 0, 0, 0))
    return _flight(tr, tr.t_s.size), legs


def test_same_heading_pair_is_rejected_with_its_reason(one_line, tmp_path):
    (imu, ref), legs = one_line
    run = calibrate_flight(imu, ref, legs=legs)
    (pair,) = run.pairs
    assert not pair.used and "heading change 0.0 deg below the minimum 30 deg" in pair.reason
    assert not run.calibrated and "no pair passed the screening" in run.reason
    # without the heading rule, the condition number rejects it
    run = calibrate_flight(imu, ref,
                           CalibrationOptions(pairs_cfg=PairPolicy(min_dheading_deg=0.0)),
                           legs=legs)
    (pair,) = run.pairs
    assert not pair.used and pair.reason.startswith("ill-conditioned: body cond_scaled")
    assert pair.cond_gate > 1e4 and not run.calibrated
    _check_tables(run, tmp_path)


def test_leg_outside_the_imu_data_is_reported_not_raised(one_line):
    (imu, ref), legs = one_line
    late = Leg(2, 800.0, 1100.0, 0.5 + np.pi, 20.0, 100.0, 0, 0, 0, 0)
    run = calibrate_flight(imu, ref, legs=(legs[0], late))
    assert any("leg 2: B replay failed" in m for m in run.messages)
    assert run.pairs[0].reason == "no B replay for leg(s) [2]" and not run.calibrated


def test_replays_on_two_threads_are_the_replays_on_one(one_line):
    """B's replays before (replay_legs) and after the compensation (compensate_legs, through
    the stage) made two legs at once are those made one at a time, bit for bit, in the legs'
    order, and a failed leg is named in its message either way."""
    from _synthetic import survey_flight

    from pospp.calib.replay import replay_legs

    (imu, ref), legs = one_line
    late = Leg(2, 800.0, 1100.0, 0.5 + np.pi, 20.0, 100.0, 0, 0, 0, 0)
    one, failed_one = replay_legs(imu, ref, (*legs, late), threads=1)
    two, failed_two = replay_legs(imu, ref, (late, *legs), threads=2)
    assert list(one) == [0, 1] and list(two) == [0, 1]
    assert failed_one == failed_two and failed_one[0].startswith("leg 2: B replay failed")
    fl = survey_flight(headings_deg=(0.0, 90.0, 180.0), rate_hz=20.0, leg_duration_s=300.0)
    drift = type(fl.imu)(fl.imu.t_s, fl.imu.dtheta_b_rad + np.diff(fl.imu.t_s)[:, None]
                         * np.radians([0.5, -0.3, 0.2]) / 3600.0, fl.imu.dv_b_mps)
    runs = [calibrate_flight(drift, fl.solution_a(), CalibrationOptions(noise="white"),
                             legs=fl.legs, threads=t)
            for t in (1, 2)]
    assert runs[0].calibrated and len(runs[0].replays_after) == 3
    assert runs[0].improvements == runs[1].improvements
    for i, rep in runs[0].replays_after.items():
        np.testing.assert_array_equal(rep.dv_n_mps, runs[1].replays_after[i].dv_n_mps)
        np.testing.assert_array_equal(runs[0].replays[i].dv_n_mps, runs[1].replays[i].dv_n_mps)
        assert np.abs(rep.dv_n_mps - runs[0].replays[i].dv_n_mps).max() > 1e-3


def test_condition_number_follows_paper_fig4_and_fig5():
    dh = np.array([0.0, 10.0, 30.0, 60.0, 90.0, 120.0, 150.0, 170.0, 180.0])
    dv = np.array([0.0, 10.0, 20.0, 40.0])
    g = condition_grid(dh, dv, formulation="paper", transition="closed_form")
    # Fig. 4: at equal speed the best pair reverses heading
    assert dh[np.argmin(g.cond_scaled[:, 0])] == 180.0
    assert np.all(np.diff(g.cond_scaled[:, 0]) < 0)
    # Fig. 5: a speed difference helps, a lot at small dH ...
    assert np.all(np.diff(g.cond_scaled, axis=1) < 0)
    assert g.cond_scaled[0, 0] / g.cond_scaled[0, -1] > 1e3
    # ... and little beyond 30 deg
    spread = g.cond_scaled[:, 0] / g.cond_scaled[:, -1]
    assert np.all(spread[dh >= 30.0] < 2.0)
    # the numerical rows give the same picture on these ideal legs
    n = condition_grid(dh[2:], dv[:2], formulation="paper", transition="numerical")
    assert np.allclose(n.cond_scaled, g.cond_scaled[2:, :2], rtol=0.02)


def test_observability_table_columns(tmp_path):
    tab = observability_table([0.0, 90.0, 180.0], [0.0, 20.0])
    assert set(tab) == {"formulation", "dheading_deg", "dspeed_mps", "cond_raw", "cond_scaled"}
    assert len(tab["formulation"]) == 12 and set(tab["formulation"]) == {"paper", "body"}


def test_legs_of_a_few_seconds_never_crash_the_stage(tmp_path):
    """Legs shorter than the 10 s noise step (found on a quadrotor log) once raised
    IndexError in the REML fit; now every leg gets noise rows and a degenerate pair is
    rejected with its reason."""
    tr = rhumb_line(LAT, 100.0, 20.0, 0.5, 10.0, 60.0)
    imu, ref = _flight(tr, tr.t_s.size)
    legs = tuple(Leg(i, t0, t0 + 8.0, np.radians(20.0), 10.0, 100.0, 0.0, 0.0, 0.0, 0.0)
                 for i, t0 in enumerate((5.0, 30.0)))
    policy = PairPolicy("adjacent", 1e30, 0.0, "body", "numerical")
    run = calibrate_flight(imu, ref, CalibrationOptions(pairs_cfg=policy), legs=legs)
    assert len(run.replays) == 2 and len(run.pairs) == 1
    # with the condition gate opened the pair is used, and on error-free increments the
    # truth is zero: the bias comes out at 3e-5 deg/h (measured; asserted < 1e-3 deg/h), with
    # a sigma that says how little two 8 s legs tell (measured 470 and 780 deg/h)
    assert run.reason == "ok" and run.calibrated and run.pairs[0].used, run.reason
    assert np.all(np.abs(run.gyro_bias_b_radps) < 1e-3 * units.DEG_PER_H_RADPS)
    sig_dph = run.gyro_bias_sigma_b_radps[0:2] / units.DEG_PER_H_RADPS
    assert np.all((sig_dph > 100.0) & np.isfinite(sig_dph)), sig_dph
    # B over 8 s of exact data: errors of the mechanization only (measured 2e-10 m/s)
    assert all(i.vel_before_mps < 1e-6 and i.vel_after_mps < 1e-6 for i in run.improvements)
    _check_tables(run, tmp_path)


def test_causal_compensation_removes_a_known_changing_bias_and_uses_no_later_data():
    """compensate_legs(gyro_bias_history=...) on exact increments with a drifting gyro bias
    injected (tests/unit/_truth_imu.py): given the true bias history, B's error at the leg
    end drops to the mechanization's level; changing the history after some instant leaves
    B before it untouched (only the last value at or before each interval's start is used)."""
    from dataclasses import dataclass

    from pospp.calib.compensate import causal_gyro_bias_b_radps, compensate_legs
    from pospp.calib.replay import replay_leg

    @dataclass(frozen=True)
    class _NoFit:  # a calibration that fitted no leg and holds no bias
        leg_ids: tuple = ()

        def gyro_bias_b_radps(self, c_nb=None):
            return np.zeros(3)

    dph = units.DEG_PER_H_RADPS
    tr = rhumb_line(LAT, 1000.0, 60.0, 0.5, 10.0, 340.0)
    n = tr.t_s.size
    mid = 0.5 * (tr.t_s[1:] + tr.t_s[:-1])

    def bias(t):  # 0.5, -0.3, 0.2 deg/h plus a ramp of 1, -0.6 deg/h per 300 s
        return (np.array([0.5, -0.3, 0.2]) + np.outer(t / 300.0, [1.0, -0.6, 0.0])) * dph

    imu_true, ref = _flight(tr, n)
    imu = type(imu_true)(tr.t_s, tr.dtheta_b_rad + bias(mid) * np.diff(tr.t_s)[:, None],
                         tr.dv_b_mps)
    leg = Leg(0, 5.0, 335.0, 0.5, 60.0, 1000.0, 0, 0, 0, 0)
    before = {0: replay_leg(imu, ref, leg)}
    grid = np.arange(0.0, 341.0, 0.1)
    a, (imp,) = compensate_legs(imu, ref, before, _NoFit(),
                                gyro_bias_history=(grid, bias(grid + 0.05)))
    # measured 2.1 m/s -> 7e-9 m/s (each 0.1 s interval holds the ramp's value at its middle)
    assert imp.vel_before_mps > 1.0 and imp.vel_after_mps < 1e-6, imp
    # causality: a history that differs only from t = 200 s on leaves B before 200 s alone
    late = bias(grid + 0.05)
    late[grid >= 200.0] += 5.0 * dph
    b, _ = compensate_legs(imu, ref, before, _NoFit(), gyro_bias_history=(grid, late))
    t_abs = a[0].t0_s + a[0].t_s
    early, after200 = t_abs < 199.0, t_abs > 230.0
    np.testing.assert_array_equal(a[0].dv_n_mps[early], b[0].dv_n_mps[early])
    assert np.abs(a[0].dv_n_mps[after200] - b[0].dv_n_mps[after200]).max() > 1e-3
    # the fusion: inverse-variance weights; an infinite prior sigma gives A's estimate
    fwd, s_fwd = np.array([[1.0, 2.0, 3.0]]), np.array([[1.0, 1.0, 1.0]])
    fused = causal_gyro_bias_b_radps(fwd, s_fwd, np.array([3.0, 0.0, 0.0]),
                                     np.array([1.0, np.sqrt(3.0), np.inf]))
    np.testing.assert_allclose(fused, [[2.0, 1.5, 3.0]], rtol=1e-12)


def test_replay_velocity_error_is_replay_legs_dv():
    """replay_velocity_error and replay_errors (no transition matrices) give replay_leg's B
    minus A exactly, with and without a gyro bias, an attitude correction and A's
    accelerometer bias."""
    from pospp.calib.replay import replay_errors, replay_leg, replay_velocity_error

    tr = rhumb_line(LAT, 1000.0, 60.0, 0.5, 10.0, 200.0)
    imu_true, ref = _flight(tr, tr.t_s.size)
    imu = type(imu_true)(tr.t_s, tr.dtheta_b_rad + 1e-6, tr.dv_b_mps)
    leg = Leg(0, 5.0, 195.0, 0.5, 60.0, 1000.0, 0, 0, 0, 0)
    for kw in ({}, {"gyro_bias_b_radps": np.array([1e-6, -2e-6, 0.0]),
                    "attitude_correction_n_rad": np.array([1e-4, 0.0, -2e-4]),
                    "accel_compensation": "none", "sample_rate_hz": 2.0}):
        dv = replay_velocity_error(imu, ref, leg, **kw)
        assert np.abs(dv).max() > 1e-3  # the injected bias shows
        full = replay_leg(imu, ref, leg, **kw)
        np.testing.assert_array_equal(dv, full.dv_n_mps)
        errors = replay_errors(imu, ref, leg, **kw)
        for name in ("t0_s", "t_s", "dv_n_mps", "dr_n_m"):
            np.testing.assert_array_equal(getattr(errors, name), getattr(full, name))


def test_rates_give_the_whole_logs_increments_and_replays_bit_for_bit():
    """ImuRates' windows are increments_from_rates' over the whole log, bit for bit (uneven
    stamps), and B replayed from the rates (increments made per leg) equals B replayed from
    the whole log's increments exactly (issue 18: the increments are never all held)."""
    from pospp.calib.replay import ImuRates, replay_leg
    from pospp.nav.strapdown import increments_from_rates

    tr = rhumb_line(LAT, 1000.0, 60.0, 0.5, 10.0, 200.0)
    rng = np.random.default_rng(3)
    epoch_ns = 1_700_000_000_000_000_000
    time_ns = epoch_ns + np.round(tr.t_s * 1e9).astype(np.int64)
    time_ns[1:-1] += rng.integers(-200_000, 200_000, time_ns.size - 2)  # jitter
    dt = np.diff(tr.t_s)[:, None]
    w = np.vstack([tr.dtheta_b_rad[:1] / dt[:1], tr.dtheta_b_rad / dt]) + 1e-6
    f = np.vstack([tr.dv_b_mps[:1] / dt[:1], tr.dv_b_mps / dt])
    t_s, dth, dv = increments_from_rates(time_ns, w, f, epoch_ns=epoch_ns)
    rates = ImuRates.from_rates(time_ns, w, f, epoch_ns=epoch_ns)
    np.testing.assert_array_equal(rates.t_s, t_s)
    for k0, k1 in ((0, t_s.size - 1), (17, 4000), (5, 6)):
        win = rates.window(k0, k1)
        np.testing.assert_array_equal(win.t_s, t_s[k0:k1 + 1])
        np.testing.assert_array_equal(win.dtheta_b_rad, dth[k0:k1])
        np.testing.assert_array_equal(win.dv_b_mps, dv[k0:k1])
    held = ImuIncrements(t_s, dth, dv)
    traj = Trajectory(t_s, np.full(t_s.size, LAT), np.full(t_s.size, 0.0),
                      np.full(t_s.size, tr.height_m), np.tile(tr.v_n_mps, (t_s.size, 1)),
                      np.tile(rotation.quat_from_dcm(tr.c_nb), (t_s.size, 1)))
    ref = solution_a_from_trajectory(traj, v_sigma_n_mps=[0.02, 0.02, 0.05])
    leg = Leg(0, 5.0, 195.0, 0.5, 60.0, 1000.0, 0, 0, 0, 0)
    a, b = replay_leg(held, ref, leg), replay_leg(rates, ref, leg)
    for name in ("dv_n_mps", "dr_n_m", "phi", "c_nb"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert np.abs(a.dv_n_mps).max() > 1e-3  # the injected gyro bias shows
