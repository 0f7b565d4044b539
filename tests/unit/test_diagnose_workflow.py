"""The model-discrepancy workflow on simulated flights with one hidden effect.

Truth: ``tests/unit/_synthetic.survey_flight`` (the strapdown solution of exact
increments). Each hidden effect is injected into the IMU increments by its physical definition
(independently of the library's signatures), on top of a body-frame horizontal gyro bias that
the base model does estimate; A is the truth plus white velocity noise (``SIGMA``). The
workflow must name the effect, estimate its size within 20 %, and halve the held-out gap (the
part of the leave-one-leg-out RMS above the noise floor, sqrt(gap^2 - sigma^2)).
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from _synthetic import noisy_replays, survey_flight

from pospp import earth
from pospp.calib.replay import ImuIncrements
from pospp.diagnose.tables import (
    DIAGNOSIS_COLUMNS,
    candidate_columns,
    diagnosis_columns,
    leg_gap_columns,
    residual_curve_columns,
)
from pospp.diagnose.workflow import DiagnosisOptions, diagnose_replays
from pospp.units import ARCSEC_RAD, DEG_PER_H_RADPS, G0_MPS2, UG_MPS2

SIGMA = 0.003  # A's velocity noise [m/s]
BIAS_B = np.array([0.02, -0.015, 0.0]) * DEG_PER_H_RADPS  # present in every case, in the base


@pytest.fixture(scope="module")
def reversal():
    """Four 300 s legs back and forth at 60 m/s (the usual survey pattern)."""
    return survey_flight(headings_deg=(0.0, 180.0, 0.0, 180.0), rate_hz=50.0)


@pytest.fixture(scope="module")
def crossing():
    """Legs on two perpendicular lines at two speeds (breaks the equal-speed confounds)."""
    return survey_flight(headings_deg=(0.0, 180.0, 90.0, 270.0),
                         speeds_mps=(40.0, 80.0, 80.0, 40.0), rate_hz=50.0)


@pytest.fixture(scope="module")
def long_legs():
    """Four 600 s legs back and forth (long legs: Earth-rate effects grow as t^3)."""
    return survey_flight(headings_deg=(0.0, 180.0, 0.0, 180.0), leg_duration_s=600.0,
                         rate_hz=50.0)


def _increments(fl, bias_b=BIAS_B):
    dt = np.diff(fl.imu.t_s)[:, None]
    return fl.imu.dtheta_b_rad + bias_b * dt, fl.imu.dv_b_mps.copy()


def _run(fl, dth, dv, seed, **kw):
    imu = ImuIncrements(fl.imu.t_s, dth, dv)
    ref = fl.solution_a(SIGMA)
    reps = noisy_replays(fl, imu, sigma_mps=SIGMA, rng=np.random.default_rng(seed),
                         solution_a=ref)
    return diagnose_replays(reps, DiagnosisOptions(**kw), imu=imu, solution_a=ref)


def _excess(gap):
    return np.sqrt(max(gap**2 - SIGMA**2, 0.0))


def _assert_named(d, effect_id, size):
    assert d.named == (effect_id,), (d.named, candidate_columns(d))
    assert d.conclusion == "none"
    s = d.step_of(effect_id)
    assert s.significant and s.p_value < 1e-6
    assert abs(s.value - size) < 0.2 * abs(size), (s.value, size)
    # the estimate is consistent with its own sigma too (4 sigma)
    assert abs(s.value - size) < 4 * s.sigma + 0.02 * abs(size)
    assert _excess(s.heldout_gap_after_mps) <= 0.5 * _excess(s.heldout_gap_before_mps)
    assert s.gap_after_mps < s.gap_before_mps


def test_null_nothing_significant(reversal):
    dth, dv = _increments(reversal)
    d = _run(reversal, dth, dv, seed=11)
    assert d.named == ()
    assert d.conclusion == "none"
    assert not d.steps[-1].significant
    assert not any(c.significant for c in d.candidates)
    # uniform straight legs cannot reveal these (docs/diagnose.md)
    assert {"time_offset", "lever_arm", "vertical_gyro_drift"} <= set(d.unobservable)
    assert d.in_base == ("body_fixed_gyro_bias", "earth_rate_coupling")


def test_accel_bias_change(reversal):
    fl = reversal
    dth, dv = _increments(fl)
    t = fl.imu.t_s
    tm, dt = 0.5 * (t[1:] + t[:-1]), np.diff(t)
    db = np.array([250.0, -150.0])  # ug, warm-up with T = 1200 s
    dv[:, 0:2] += np.outer(np.exp(-tm / 1200.0), db * UG_MPS2) * dt[:, None]
    d = _run(fl, dth, dv, seed=12)
    _assert_named(d, "accel_bias_change", np.linalg.norm(db))


def test_body_fixed_gyro_bias_against_paper_base(crossing):
    b = np.array([0.05, -0.03, 0.0])
    dth, dv = _increments(crossing, b * DEG_PER_H_RADPS)
    d = _run(crossing, dth, dv, seed=13, base_formulation="paper")
    _assert_named(d, "body_fixed_gyro_bias", np.linalg.norm(b))
    np.testing.assert_allclose(d.step_of("body_fixed_gyro_bias").values, b[:2], atol=0.01)


def test_gravity_disturbance(crossing):
    fl = crossing
    dth, dv = _increments(fl)
    tr, t = fl.truth, fl.imu.t_s
    gg = np.array([0.3, 0.1, -0.2])  # arcsec/km: [G_NN, G_NE, G_EE] / g
    g = gg * G0_MPS2 * ARCSEC_RAD / 1000.0
    gm = np.array([[g[0], g[1]], [g[1], g[2]]])
    d_n = earth.llh_to_ned_m(tr.lat_rad[:-1], tr.lon_rad[:-1], tr.height_m[:-1],
                             tr.lat_rad[0], tr.lon_rad[0], tr.height_m[0])
    dg = np.zeros((t.size - 1, 3))
    dg[:, 0:2] = d_n[:, 0:2] @ gm.T
    dv -= np.einsum("kji,kj->ki", tr.c_nb[:-1], dg) * np.diff(t)[:, None]
    d = _run(fl, dth, dv, seed=14)
    _assert_named(d, "gravity_disturbance", np.linalg.norm(gg))


@pytest.mark.slow
def test_vertical_gyro_drift(long_legs):
    dth, dv = _increments(long_legs, BIAS_B + np.array([0.0, 0.0, 1.0]) * DEG_PER_H_RADPS)
    d = _run(long_legs, dth, dv, seed=15)
    _assert_named(d, "vertical_gyro_drift", 1.0)


@pytest.mark.slow
def test_earth_rate_coupling_missing_from_closed_form(long_legs):
    # no injection: the data obey the full error model; the closed-form base drops the
    # Earth-rate coupling, whose fraction must come out as 1
    dth, dv = _increments(long_legs, np.array([0.3, -0.2, 0.0]) * DEG_PER_H_RADPS)
    d = _run(long_legs, dth, dv, seed=16, base_transition="closed_form")
    _assert_named(d, "earth_rate_coupling", 1.0)


def test_out_of_library_gyro_bias_jumps_unexplained(reversal):
    # the gyro bias jumps at every turn (instability, not a library effect)
    fl = reversal
    dth, dv = _increments(fl)
    t = fl.imu.t_s
    tm, dt = 0.5 * (t[1:] + t[:-1]), np.diff(t)
    jumps = np.array([[0.01, 0.005], [-0.008, 0.01], [0.012, -0.006], [-0.01, -0.008]])
    for leg, j in zip(fl.legs, jumps, strict=True):
        m = (tm >= leg.start_s - 30.0) & (tm < leg.end_s + 30.0)
        dth[m, 0:2] += j * DEG_PER_H_RADPS * dt[m, None]
    d = _run(fl, dth, dv, seed=17)
    assert d.named == (), d.named
    assert d.conclusion == "unexplained"
    assert d.steps[-1].significant
    # some candidates were individually significant yet explained too little to be named
    assert any(c.significant for c in d.candidates)


def test_out_of_library_oscillating_accel_bias_unexplained(reversal):
    fl = reversal
    dth, dv = _increments(fl)
    t = fl.imu.t_s
    tm, dt = 0.5 * (t[1:] + t[:-1]), np.diff(t)
    dv[:, 0] += 300.0 * UG_MPS2 * np.sin(2 * np.pi * tm / 90.0) * dt
    d = _run(fl, dth, dv, seed=18)
    assert d.named == ()
    assert d.conclusion == "unexplained"


def test_tables(reversal):
    fl = reversal
    dth, dv = _increments(fl)
    t = fl.imu.t_s
    tm, dt = 0.5 * (t[1:] + t[:-1]), np.diff(t)
    dv[:, 0:2] += np.outer(np.exp(-tm / 1200.0), np.array([250.0, -150.0]) * UG_MPS2) \
        * dt[:, None]
    d = _run(fl, dth, dv, seed=12, effects=("accel_bias_change", "gravity_disturbance"))
    cols = diagnosis_columns(d)
    assert tuple(cols) == DIAGNOSIS_COLUMNS
    table = pa.table(cols)
    assert table.num_rows == len(d.steps) == 2
    assert list(cols["effect"]) == ["accel_bias_change", "none"]
    assert cols["unit"][0] == "ug" and np.isnan(cols["value"][1])
    assert cols["gap_after_mps"][0] < cols["gap_before_mps"][0]
    legs = pa.table(leg_gap_columns(d))
    assert legs.num_rows == 4
    assert set(legs.column("heading_deg").to_pylist()) == {0.0, 180.0}
    cand = candidate_columns(d)
    assert set(cand["effect"]) <= {"accel_bias_change", "gravity_disturbance"}
    # the first leg after power-up carries most of the warm-up gap
    lg = leg_gap_columns(d)
    assert lg["gap_before_mps"][0] == max(lg["gap_before_mps"])
    curves = pa.table(residual_curve_columns(d)).to_pandas()
    assert set(curves.model) == {"before", "after"} and set(curves.kind) == {"fit", "heldout"}
    fit = curves[curves.kind == "fit"]
    for model, col in (("before", "gap_before_mps"), ("after", "gap_after_mps")):
        c = fit[fit.model == model]
        rms = np.sqrt(np.mean(np.concatenate([c.dvn_mps, c.dve_mps]) ** 2))
        assert rms == pytest.approx(cols[col][0], rel=1e-9)


def test_input_contract(reversal):
    dth, dv = _increments(reversal)
    imu = ImuIncrements(reversal.imu.t_s, dth, dv)
    reps = noisy_replays(reversal, imu, sigma_mps=SIGMA, rng=np.random.default_rng(1))
    with pytest.raises(ValueError, match="base_formulation"):
        DiagnosisOptions(base_formulation="nav")
    with pytest.raises(ValueError, match="at least 2 legs"):
        diagnose_replays(reps[:1])
    with pytest.raises(ValueError, match="expected one of"):
        DiagnosisOptions(effects=("wind",))
    # no IMU given: cannot re-run B
    d = diagnose_replays(reps, DiagnosisOptions(effects=("time_offset",)))
    assert d.not_evaluated == ("time_offset",)


@pytest.mark.slow
def test_time_offset_needs_wander():
    # uniform legs cannot reveal a time offset (null test: it is in `unobservable`); legs with
    # heading / pitch wander do, confounded with the lever arm (docs/diagnose.md)
    fl = survey_flight(headings_deg=(0.0, 180.0, 0.0, 180.0), rate_hz=50.0,
                       wander_heading_deg=2.0, wander_pitch_deg=1.0)
    dth, dv = _increments(fl)
    t = fl.imu.t_s
    tau = 0.02  # IMU tag minus true time: the sample labelled t was sensed at t - tau

    def shift(arr):
        cum = np.concatenate([np.zeros((1, 3)), np.cumsum(arr, axis=0)])
        return np.diff(np.stack([np.interp(t - tau, t, cum[:, c]) for c in range(3)], 1), axis=0)

    d = _run(fl, shift(dth), shift(dv), seed=19)
    _assert_named(d, "time_offset", 20.0)
    assert "lever_arm" in d.step_of("time_offset").confounded_with


@pytest.mark.slow
def test_null_with_gyro_random_walk(reversal):
    # white gyro noise (ARW 0.002 deg/sqrt(h)) makes B's error a correlated random walk: with
    # the gyro_rw noise model nothing is significant and no structured gap remains
    fl = reversal
    dth, dv = _increments(fl)
    dt = np.diff(fl.imu.t_s)[:, None]
    arw = np.radians(0.002) / 60.0
    rng = np.random.default_rng(21)
    dth = dth + rng.normal(0.0, 1.0, dth.shape) * arw * np.sqrt(dt)
    d = _run(fl, dth, dv, seed=21, noise="gyro_rw", gyro_arw_radpsqrts=arw)
    assert d.named == () and d.conclusion == "none"
