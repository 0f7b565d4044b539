"""The null realisations' two shortcuts give the same realisations.

At a lower IMU rate (``[pairs] rerun_imu_rate_hz``): one noise draw added to a simulated
200 Hz flight, and B minus A's response to it computed at 200 Hz and again with the IMU summed
down to 50 Hz and 25 Hz (:func:`pospp.diagnose.null_model.decimate_imu`), agree to a small
fraction of the response. What the claim rests on: the response is the noise's density
through the error dynamics, and the strapdown's own algorithm error is in the base and the
realisation alike.

With the base's gains (:class:`pospp.nav.filter.GainReplay`): A on the noisy log with the
base's Kalman and smoother gains instead of its own covariance gives B minus A's response of
the full A to a small fraction of it (the gains move at second order in the noise); on the
base itself, A's states exactly; recording the gains changes nothing; a log whose records
differ from the base's runs in full."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from _missions import SimLog, three_leg_survey

from pospp import flight_stages as fs
from pospp import null_stage, pipeline
from pospp.calib.replay import SolutionA, replay_velocity_error
from pospp.config import config_from_dict
from pospp.diagnose import null_model
from pospp.nav import filter as nav_filter
from pospp.sim.api import simulate
from pospp.sim.gnss import GnssModel
from pospp.sim.profile import parse_profile
from pospp.types import ImuSamples


@pytest.fixture(scope="module")
def flight():
    profile = dict(three_leg_survey("decimation", 120.0, lat_deg=40.0, lon_deg=116.0,
                                    height_m=1000.0, heading_deg=30.0), imu_rate_hz=200)
    gnss = GnssModel(rate_hz=1.0, pos_noise_m=(0.05, 0.1), vel_noise_mps=(0.02, 0.03))
    sim = simulate(parse_profile(profile), imu_grade="paper_flight", gnss=gnss, seed=4)
    cfg = config_from_dict({
        "imu": {"grade": "flight"},
        "filter": {"output_rate_hz": 10.0, "smoother": True},
        "legs": {"min_duration_s": 100.0, "min_speed_mps": 20.0},
        "replay": {"reference": "smoothed", "horizon_s": 120.0}})
    log = SimLog(sim.imu, sim.fix, sim.vel)
    nav = pipeline.navigate(log, cfg)
    run, _ = pipeline.calibrate_from_a(pipeline.imu_increments(log), nav, cfg)
    assert len(run.replays) >= 2, run.reason
    return log, nav, run, cfg


def _b_minus_a(log, run, cfg, **nav_kw):
    """(A, B minus A per leg) on ``log``; ``nav_kw`` to flight_stages.navigate."""
    nav = fs.navigate(log, cfg, **nav_kw)
    ref = SolutionA(*nav_filter.solution_a_fields(nav, which="smoothed"))
    imu = fs.imu_increments(log)
    legs = {leg.leg_id: leg for leg in run.legs}
    return nav, [replay_velocity_error(imu, ref, legs[i], sample_rate_hz=cfg.replay.sample_rate_hz,
                                       accel_compensation=cfg.replay.accel_compensation)[:, 0:2]
                 for i in sorted(run.replays)]


NOISE = null_model.NullNoise(
    gyro_arw_radpsqrts=np.radians(0.01) / 60.0, accel_vrw_mpspsqrts=5e-5,
    pos_sigma_ned_m=np.array([0.05, 0.05, 0.1]), vel_sigma_ned_mps=np.full(3, 0.02),
    gyro_gm_sigma_radps=np.radians(0.5) / 3600.0, gyro_gm_tau_s=300.0)
"""The injected noise: the paper_flight grade's ARW and drift, GNSS 0.05 / 0.1 m, 0.02 m/s."""


def _t_align_ns(log, nav):
    return int(log.imu.time_ns[0]) + round(nav.alignment.t_s * 1e9)


def test_decimation_factor_from_the_rate(flight):
    log, _, _, _ = flight
    assert fs.rerun_decimation(log, 50.0) == 4
    assert fs.rerun_decimation(log, 25.0) == 8
    assert fs.rerun_decimation(log, 60.0) == 3
    assert fs.rerun_decimation(log, 0.0) == 1
    assert fs.rerun_decimation(log, 400.0) == 1


def test_summed_down_response_is_the_full_rate_response(flight):
    log, nav, run, cfg = flight
    base = null_model.gnss_on_solution(log, nav.smoothed, int(log.imu.time_ns[0]),
                                       nav.lever_arm.lever_b_m)
    t_align_ns = _t_align_ns(log, nav)
    rng = np.random.default_rng(11)
    for _ in range(2):
        pert = null_model.perturb_log(base, NOISE, rng, from_time_ns=t_align_ns)
        full = [a - b for a, b in zip(_b_minus_a(pert, run, cfg)[1], _b_minus_a(base, run, cfg)[1],
                                      strict=True)]
        size = np.sqrt(np.mean(np.concatenate(full) ** 2))
        assert size > 1e-3  # the response is there: mm/s
        keep = null_stage.leg_epochs_ns(log, run.legs)
        for factor in (4, 8):
            dec = [a - b for a, b in zip(
                _b_minus_a(null_model.decimate_imu(pert, factor, keep), run, cfg)[1],
                _b_minus_a(null_model.decimate_imu(base, factor, keep), run, cfg)[1],
                strict=True)]
            # B starts and ends on the flight's epochs: the flight's rows, sample for sample
            assert [d.shape for d in dec] == [r.dv_n_mps[:, 0:2].shape
                                              for _, r in sorted(run.replays.items())]
            gap = np.sqrt(np.mean((np.concatenate(dec) - np.concatenate(full)) ** 2))
            # measured: 2-6e-5 of the 100-140 mm/s response here; on flight_null_200hz
            # 1-3e-4 of 20-36 mm/s (docs/diagnose.md, "The null at a lower IMU rate")
            assert gap < 0.01 * size, (factor, gap, size)


def test_decimated_increments_are_the_flights_summed():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.integers(4_000_000, 6_000_000, 1003)).astype(np.int64)
    t[500:] += 300_000_000  # a gap inside a group
    w, f = rng.normal(size=(1003, 3)), rng.normal(size=(1003, 3))
    log = SimLog(ImuSamples(t, w, f), None, None)
    dec = null_model.decimate_imu(log, 4).imu
    assert dec.time_ns.size == 251 and np.array_equal(dec.time_ns, t[::4])
    for full, down in ((w, dec.w_ib_b_radps), (f, dec.f_ib_b_mps2)):
        inc = np.cumsum(full[1:] * (np.diff(t) * 1e-9)[:, None], axis=0)[3::4]
        inc_d = np.cumsum(down[1:] * (np.diff(dec.time_ns) * 1e-9)[:, None], axis=0)
        np.testing.assert_allclose(inc_d, inc, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(down[0], full[0])
    assert null_model.decimate_imu(log, 1).imu.time_ns is t
    # stamps to keep (a leg's epochs) split the groups: kept, and the sums still exact
    keep = t[[101, 102, 517, 1001]]
    dec = null_model.decimate_imu(log, 4, keep).imu
    assert set(keep) <= set(dec.time_ns) and set(t[::4][:-1]) <= set(dec.time_ns)
    at = np.searchsorted(t, dec.time_ns)
    inc = np.concatenate([np.zeros((1, 3)), np.cumsum(w[1:] * (np.diff(t) * 1e-9)[:, None],
                                                      axis=0)])[at]
    inc_d = np.concatenate([np.zeros((1, 3)), np.cumsum(
        dec.w_ib_b_radps[1:] * (np.diff(dec.time_ns) * 1e-9)[:, None], axis=0)])
    np.testing.assert_allclose(inc_d, inc, rtol=0, atol=1e-12)
    # summed a few groups at a time (memory): bit for bit the sums over the whole log
    whole = null_model.decimate_imu(log, 4, keep).imu
    for groups in (1, 7, 1000):
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(null_model, "_GROUPS", groups)
            part = null_model.decimate_imu(log, 4, keep).imu
        np.testing.assert_array_equal(part.w_ib_b_radps, whole.w_ib_b_radps)
        np.testing.assert_array_equal(part.f_ib_b_mps2, whole.f_ib_b_mps2)


def test_gain_replay_response_is_the_full_response(flight):
    log, nav, run, cfg = flight

    def rerun(log_r, **gain_kw):  # A as the null realisations run it
        return _b_minus_a(log_r, run, cfg, options=fs.rerun_options(cfg), **gain_kw)

    base = null_model.decimate_imu(null_model.gnss_on_solution(
        log, nav.smoothed, int(log.imu.time_ns[0]), nav.lever_arm.lever_b_m), 4,
        null_stage.leg_epochs_ns(log, run.legs))
    plain, dv_plain = rerun(base)
    rec, dv_base = rerun(base, record_gains=True)
    gains = rec.gain_replay
    assert plain.gain_replay is None and gains is not None
    n_rec = rec.innovations.t_s.size
    assert gains.gains.shape == (n_rec, 21, 3) and gains.s_inv.shape == (n_rec, 3, 3)
    # the switch: after the static alignment, once the heading has converged (here +70 s)
    t_switch = gains.t_s[gains.k_from] - gains.t_s[gains.k_start]
    assert 20.0 < t_switch < run.legs[0].start_s, t_switch
    for a, b in zip(dv_plain, dv_base, strict=True):  # recording changes nothing
        np.testing.assert_array_equal(a, b)
    for k_from in (gains.k_from, gains.k_start):  # on the base itself: A's states again
        same, dv_same = rerun(base, replay=replace(gains, k_from=k_from))
        np.testing.assert_array_equal(same.forward.trajectory.v_n_mps,
                                      rec.forward.trajectory.v_n_mps)
        for a, b in zip(dv_same, dv_base, strict=True):  # the smoother's A_k: rounding only
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    t_align_ns = _t_align_ns(log, nav)
    rng = np.random.default_rng(11)

    def response(log_r, **kw):
        return np.concatenate([a - b for a, b in zip(rerun(log_r, **kw)[1], dv_base,
                                                     strict=True)])

    for i in range(3):
        pert = null_model.perturb_log(base, NOISE, rng, from_time_ns=t_align_ns)
        if i == 2:  # one fix 10 m north, after the switch: the gate refuses it in both
            j = int(np.searchsorted(pert.fix.time_ns, log.imu.time_ns[0] + 300_000_000_000))
            lat = pert.fix.lat_rad.copy()
            lat[j] += 10.0 / 6.37e6
            pert = replace(pert, fix=replace(pert.fix, lat_rad=lat))
        full, fast = response(pert), response(pert, replay=gains)
        size = np.sqrt(np.mean(full**2))
        assert size > 1e-3
        gap = np.sqrt(np.mean((fast - full) ** 2))
        # measured 0.03-0.07 % with the switch, 0.7-1.6 % replaying from the alignment on
        assert gap < 0.005 * size, (i, gap, size)
    st = rerun(pert, replay=gains)[0].innovations.status
    assert np.count_nonzero(st == nav_filter.STATUS_GATED) >= 1
    # two fixes in a row 10 m north: the replay ends and A runs in full (the same numbers)
    lat = pert.fix.lat_rad.copy()
    lat[j + 1] += 10.0 / 6.37e6
    pert = replace(pert, fix=replace(pert.fix, lat_rad=lat))
    np.testing.assert_array_equal(response(pert, replay=gains), response(pert))
    # a log with one GNSS fix fewer has other records: A runs in full, as without the gains
    fewer = replace(base, fix=replace(base.fix, **{
        f: getattr(base.fix, f)[np.arange(base.fix.time_ns.size) != 200]
        for f in ("time_ns", "lat_rad", "lon_rad", "height_m", "pos_cov_ned_m2")}))
    for a, b in zip(rerun(fewer, replay=gains)[1],
                    rerun(fewer)[1], strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.reference
@pytest.mark.parametrize("name", ["flight_null_200hz", "flight_survey_errors"])
def test_the_estimate_passes_read_the_flight_rate_s_estimates(reference_cases, name,
                                                             monkeypatch):
    # A's lever-arm passes (the QC stage's estimate, the diagnosis's start) run on the log
    # summed down to [pairs] rerun_imu_rate_hz and, as the scale-factor pass, with the
    # covariance stepped every ESTIMATE_STEP_S (0.5 s): on the independent simulator's flights
    # (200 and 100 Hz) both read the flight rate's estimates at the 0.1 s step within a tenth
    # of their sigma (measured at most 0.07), the sigmas within 1 %, and the lever arm within
    # 5 sigma of the case's true one (flight_survey_errors, with its scale factors and
    # misalignments: 3.6 sigma on x)
    from test_diagnose_null_reference import case_config

    cfg, params = case_config(reference_cases, name)
    log = pipeline.ingest(reference_cases / f"{name}.mcap", cfg)
    nav = fs.navigate(log, cfg)
    seen = fs.lever_arm_seen(nav)
    assert fs.rerun_decimation(log, cfg.pairs.rerun_imu_rate_hz) > 1
    lever = fs.lever_arm_passes(log, seen, cfg)
    sf, sf_sigma = fs.scale_factor_estimate(log, cfg, lever.lever_b_m)
    monkeypatch.setattr(fs, "ESTIMATE_STEP_S", 0.1)
    full_cfg = replace(cfg, pairs=replace(cfg.pairs, rerun_imu_rate_hz=0.0))
    lever_full = fs.lever_arm_passes(log, seen, full_cfg)
    sf_full, sf_sigma_full = fs.scale_factor_estimate(log, cfg, lever.lever_b_m)
    np.testing.assert_allclose(lever.lever_b_m, lever_full.lever_b_m,
                               atol=0.1 * lever_full.sigma_b_m.min())
    np.testing.assert_allclose(lever.sigma_b_m, lever_full.sigma_b_m, rtol=0.01)
    np.testing.assert_allclose(sf, sf_full, atol=0.1 * sf_sigma_full.min())
    np.testing.assert_allclose(sf_sigma, sf_sigma_full, rtol=0.01)
    truth = np.asarray(params["gnss"]["lever_arm_m"], dtype=float)
    assert np.all(np.abs(lever.lever_b_m - truth)[seen] < 5.0 * lever.sigma_b_m[seen])
