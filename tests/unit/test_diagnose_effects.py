"""Signatures of the candidate effects against B re-run on independently perturbed data.

The flight is two legs (headings 0 and 180 deg, 60 m/s, 200 s each, heading weaving +-1 deg
with a 40 s period, 50 Hz) of exact increments from tests/unit/_truth_imu.py's
``weaving_flight`` (DOP853 path, Gauss-Legendre increments: independent of pospp's
mechanization), and the truth (algorithm A) is that generator's analytic state, not a
strapdown output. Each effect is injected into the inputs by its physical definition (sensor
= true + error, gravity disturbance as the specific force the IMU would have sensed, a late IMU
time tag, a wrong lever arm in A), B is re-run by the one strapdown kernel, and B minus A must
equal the signature times the effect size (first order) along these wandering legs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from _truth_imu import weaving_flight, weaving_truth_state

from pospp import earth, rotation
from pospp.calib.replay import (
    ImuIncrements,
    forced_response,
    replay_leg,
    solution_a_from_trajectory,
)
from pospp.calib.segment import Leg
from pospp.diagnose import effects as fx
from pospp.nav import strapdown
from pospp.nav.error_model import BG
from pospp.units import ARCSEC_RAD, DEG_PER_H_RADPS, G0_MPS2, UG_MPS2

RATE_HZ = 50.0
SPEED_MPS = 60.0
WEAVE_RAD = np.radians(1.0)
WEAVE_S = 40.0
LEG_S = 200.0
LEAD_S = 20.0  # each leg starts half a weave period into its stretch: heading at its mean
SPAN_S = LEAD_S + LEG_S + 5.0  # each leg's generated stretch


@dataclass(frozen=True)
class _Flight:
    imu: ImuIncrements
    truth: strapdown.Trajectory
    legs: tuple[Leg, ...]

    def solution_a(self, v_sigma_mps: float):
        return solution_a_from_trajectory(self.truth, v_sigma_n_mps=np.full(3, v_sigma_mps))


def _two_legs() -> _Flight:
    """Two independent weaving stretches one after the other on one time axis.

    The second starts one IMU interval after the first ends; the increment across that seam
    (and the position jump there) lies outside both legs.
    """
    lat0, h = np.radians(40.0), 1000.0
    parts, legs, t_off = [], [], 0.0
    for i, hd in enumerate(np.radians([0.0, 180.0])):
        tr = weaving_flight(lat0, h, SPEED_MPS, hd, WEAVE_RAD, WEAVE_S, RATE_HZ, SPAN_S)
        v, c = weaving_truth_state(tr, hd, WEAVE_RAD, WEAVE_S, SPEED_MPS)
        parts.append((tr.t_s + t_off, tr, v, rotation.quat_from_dcm(c)))
        t0 = t_off + LEAD_S
        legs.append(Leg(i, t0, t0 + LEG_S, float(hd), SPEED_MPS, h, 0.0, 0.0, 0.0, 0.0))
        t_off += tr.t_s[-1] + 1.0 / RATE_HZ
    t = np.concatenate([p[0] for p in parts])
    seam = parts[0][1].dtheta_b_rad[-1:], parts[0][1].dv_b_mps[-1:]
    dth = np.concatenate([parts[0][1].dtheta_b_rad, seam[0], parts[1][1].dtheta_b_rad])
    dv = np.concatenate([parts[0][1].dv_b_mps, seam[1], parts[1][1].dv_b_mps])
    truth = strapdown.Trajectory(
        t, np.concatenate([p[1].lat_rad for p in parts]),
        np.concatenate([p[1].lon_rad for p in parts]), np.full(t.size, h),
        np.concatenate([p[2] for p in parts]), np.concatenate([p[3] for p in parts]))
    return _Flight(ImuIncrements(t, dth, dv), truth, tuple(legs))


@pytest.fixture(scope="module")
def flight():
    fl = _two_legs()
    ref = fl.solution_a(0.01)
    reps = [replay_leg(fl.imu, ref, leg) for leg in fl.legs]
    return fl, ref, reps


def _rerun(fl, ref, dth, dv):
    imu = ImuIncrements(fl.imu.t_s, dth, dv)
    return [replay_leg(imu, ref, leg).dv_n_mps[:, 0:2] for leg in fl.legs]


def _check(measured, reps, sig_fn, p, rtol):
    """B minus A re-run on the perturbed data equals the signature times p within rtol of its
    largest value (the measured relative misfit is stated at each call)."""
    for meas, rep in zip(measured, reps, strict=True):
        pred = sig_fn(rep) @ p
        scale = np.abs(meas).max()
        assert scale > 1e-4, "the injected effect must be visible"
        assert np.abs(meas - pred).max() < rtol * scale


def test_clean_replay_has_no_error(flight):
    # B (pospp's mechanization) against the independent truth, error-free increments
    _, _, reps = flight
    for r in reps:
        assert np.abs(r.dv_n_mps).max() < 1e-8  # measured 4.2e-9 m/s


def test_forced_response_of_constant_gyro_bias_equals_phi_column(flight):
    # variation of constants with G = -C_nb on the attitude rows vs Phi's own bias block
    _, _, reps = flight
    for r in reps:
        g = np.zeros((r.t_s.size, 15, 3))
        g[:, 0:3, :] = -r.c_nb
        got = forced_response(r, g)
        want = r.phi[:, 3:5, BG]
        assert np.abs(got - want).max() < 2e-3 * np.abs(want).max()


def test_body_and_vertical_gyro_bias(flight):
    fl, ref, reps = flight
    dt = np.diff(fl.imu.t_s)[:, None]
    b = np.array([0.03, -0.02, 0.0]) * DEG_PER_H_RADPS
    meas = _rerun(fl, ref, fl.imu.dtheta_b_rad + b * dt, fl.imu.dv_b_mps)
    # measured 4e-7 (first order of a linear effect; the mechanization's nonlinearity)
    _check(meas, reps, lambda r: fx.signature("body_fixed_gyro_bias", r), b[:2], 5e-6)
    bz = np.array([0.0, 0.0, 1.0]) * DEG_PER_H_RADPS
    meas = _rerun(fl, ref, fl.imu.dtheta_b_rad + bz * dt, fl.imu.dv_b_mps)
    _check(meas, reps, lambda r: fx.signature("vertical_gyro_drift", r), bz[2:], 2e-3)  # 2.8e-4


def test_accel_bias_settling(flight):
    fl, ref, reps = flight
    t = fl.imu.t_s
    tm, dt = 0.5 * (t[1:] + t[:-1]), np.diff(t)
    settle = 500.0
    db = np.array([300.0, -200.0]) * UG_MPS2
    dv = fl.imu.dv_b_mps.copy()
    dv[:, 0:2] += np.outer(np.exp(-tm / settle), db) * dt[:, None]
    # A absorbs the bias at each leg start: give A (the reference) that bias as its estimate
    ba = np.zeros((t.size, 3))
    ba[:, 0:2] = np.outer(np.exp(-t / settle), db)
    ref_b = solution_a_from_trajectory(fl.truth, v_sigma_n_mps=np.full(3, 0.01),
                                      accel_bias_b_mps2=ba)
    imu = ImuIncrements(t, fl.imu.dtheta_b_rad, dv)
    meas = [replay_leg(imu, ref_b, leg).dv_n_mps[:, 0:2] for leg in fl.legs]
    _check(meas, reps, lambda r: fx.signature("accel_bias_change", r, accel_settling_s=settle),
           db, 3e-5)  # measured 3.4e-6


def test_gravity_disturbance_gradient(flight):
    fl, ref, reps = flight
    t, tr = fl.imu.t_s, fl.truth
    dt = np.diff(t)
    g = np.array([0.4, 0.15, -0.3]) * G0_MPS2 * ARCSEC_RAD / 1000.0
    gm = np.array([[g[0], g[1]], [g[1], g[2]]])
    meas = []
    for leg, rep in zip(fl.legs, reps, strict=True):
        k0 = int(np.searchsorted(t, rep.t0_s))
        d = earth.llh_to_ned_m(tr.lat_rad[:-1], tr.lon_rad[:-1], tr.height_m[:-1],
                               tr.lat_rad[k0], tr.lon_rad[k0], tr.height_m[k0])
        dg = np.zeros((dt.size, 3))
        dg[:, 0:2] = d[:, 0:2] @ gm.T
        # true gravity = normal + dg: the IMU senses f - dg for the same motion
        dv = fl.imu.dv_b_mps - np.einsum("kji,kj->ki", tr.c_nb[:-1], dg) * dt[:, None]
        imu = ImuIncrements(t, fl.imu.dtheta_b_rad, dv)
        meas.append(replay_leg(imu, ref, leg).dv_n_mps[:, 0:2])
    # measured 7.6e-4: the signature moves along B's initial velocity, the truth weaves
    _check(meas, reps, lambda r: fx.signature("gravity_disturbance", r), g, 2e-3)


def test_gravity_disturbance_field_over_position(flight):
    # a smooth deflection field (issue 34, shape "field"): the disturbing potential a
    # polynomial of degree 2-4 over the flown area, about a reference point between the legs;
    # each leg's signature needs its start relative to that point
    fl, ref, reps = flight
    t, tr = fl.imu.t_s, fl.truth
    dt = np.diff(t)
    k = len(fx.field_monomials())
    c = np.random.default_rng(3).normal(size=k) * 2.0 * G0_MPS2 * ARCSEC_RAD
    lat_r, lon_r = 0.5 * (tr.lat_rad[0] + tr.lat_rad[-1]), 0.5 * (tr.lon_rad[0] + tr.lon_rad[-1])
    extent = 20_000.0
    d = earth.llh_to_ned_m(tr.lat_rad[:-1], tr.lon_rad[:-1], tr.height_m[:-1], lat_r, lon_r,
                           tr.height_m[0])
    field = np.zeros((dt.size, 3))
    field[:, 0:2] = fx.field_gradient(d[:, 0] / extent, d[:, 1] / extent) @ c
    for leg, rep in zip(fl.legs, reps, strict=True):
        k0 = int(np.searchsorted(t, rep.t0_s))
        # true gravity = normal + dg: the IMU senses f - dg for the same motion; the value at
        # the leg start is what A's tilt takes up (here A is the truth: it is left out)
        dg = field - field[k0]
        dv = fl.imu.dv_b_mps - np.einsum("kji,kj->ki", tr.c_nb[:-1], dg) * dt[:, None]
        m = replay_leg(ImuIncrements(t, fl.imu.dtheta_b_rad, dv), ref, leg).dv_n_mps[:, 0:2]
        # measured 1.2e-3 at most: the signature moves along B's initial velocity
        _check([m], [rep], lambda r, o=d[k0, 0:2]: fx.signature(
            "gravity_disturbance", r, shape="field", origin_n_m=o, extent_m=extent), c, 5e-3)
    with pytest.raises(ValueError, match="positions"):
        fx.signature("gravity_disturbance", reps[0], shape="field")


def test_gyro_scale_factor_against_b_re_run(flight):
    fl, ref, reps = flight
    s = np.array([2000.0, -1000.0, 3000.0]) * 1e-6
    meas = _rerun(fl, ref, fl.imu.dtheta_b_rad * (1.0 + s), fl.imu.dv_b_mps)
    _check(meas, reps, lambda r: fx.signature("gyro_scale_factor", r), s, 5e-3)  # 7.2e-4


def test_time_offset(flight):
    fl, ref, reps = flight
    t = fl.imu.t_s
    tau = 0.03  # the sample labelled t was sensed at t - tau

    def shift(arr):
        cum = np.concatenate([np.zeros((1, 3)), np.cumsum(arr, axis=0)])
        return np.diff(np.stack([np.interp(t - tau, t, cum[:, c]) for c in range(3)], 1), axis=0)

    meas = _rerun(fl, ref, shift(fl.imu.dtheta_b_rad), shift(fl.imu.dv_b_mps))
    ctx = fx.ReplayContext(fl.imu, ref)
    _check(meas, reps, lambda r: fx.signature("time_offset", r, context=ctx), np.array([tau]),
           5e-3)  # measured 5.3e-4


def test_lever_arm_error_of_a(flight):
    fl, _, reps = flight
    tr, imu = fl.truth, fl.imu
    dt = np.diff(imu.t_s)
    dl = np.array([0.8, -0.5, 1.2])  # A's lever arm minus the true one, body FRD
    c_nb = tr.c_nb
    w_in = (earth.earth_rate_n_radps(tr.lat_rad)
            + earth.transport_rate_n_radps(tr.lat_rad, tr.height_m, tr.v_n_mps))
    w_nb = imu.dtheta_b_rad / dt[:, None] - np.einsum("kji,kj->ki", c_nb[:-1], w_in[:-1])
    w_nb = np.vstack([w_nb, w_nb[-1:]])
    # A tracks the antenna with the wrong lever arm: its IMU velocity and position err by
    dv_a = -np.einsum("kij,kj->ki", c_nb, np.cross(w_nb, dl))
    dr_a = -c_nb @ dl
    r_m, r_n = earth.principal_radii_m(tr.lat_rad)
    traj_a = strapdown.Trajectory(
        tr.t_s, tr.lat_rad + dr_a[:, 0] / (r_m + tr.height_m),
        tr.lon_rad + dr_a[:, 1] / ((r_n + tr.height_m) * np.cos(tr.lat_rad)),
        tr.height_m - dr_a[:, 2], tr.v_n_mps + dv_a, tr.q_nb)
    ref_a = solution_a_from_trajectory(traj_a, v_sigma_n_mps=np.full(3, 0.01))
    meas = [replay_leg(imu, ref_a, leg).dv_n_mps[:, 0:2] for leg in fl.legs]
    # measured 4.2e-3: B's body rate from its 1 Hz attitude samples
    _check(meas, reps, lambda r: fx.signature("lever_arm", r), dl, 2e-2)


def test_body_rate_from_attitude(flight):
    fl, _, reps = flight
    r = reps[0]
    w = fx.body_rate_nb_radps(r)
    # heading wander 1 deg at 40 s: yaw rate amplitude 2 pi / 40 * 1 deg
    amp = 2 * np.pi / 40.0 * np.radians(1.0)
    assert np.abs(w[:, 2]).max() == pytest.approx(amp, rel=0.05)
    assert rotation.angle_between_rad(r.c_nb[0], r.c_nb0) < 1e-12


def test_unknown_effect_is_refused():
    with pytest.raises(ValueError, match="expected one of"):
        fx.effect_by_id("magnetometer")
