"""A's innovations' linear response to IMU input changes (pospp.calib.innovation_response)
against A itself: the nonlinear filter re-run with the change added to its samples and its
gains replayed, less the unperturbed replay (what the diagnosis did before, 48 passes)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from test_diagnose_null_reference import case_config

from pospp import pipeline, rotation
from pospp import sensor_stage as stage
from pospp.calib import innovation_response
from pospp.calib.innovation_response import innovation_responses
from pospp.diagnose import null_model
from pospp.diagnose.shapes import basis_size, change_basis, knots_s, step_times_s
from pospp.effects_catalog import catalog_entry
from pospp.flight_stages import navigate, rerun_decimation, static_alignment_window
from pospp.nav.alignment import static_attitude_jacobian
from pospp.nav.filter import STATUS_USED
from pospp.units import t_s_from_time_ns

NAME = "flight_accel_ramp_100hz"
FAMS = ("gyro_bias_change", "accel_bias_change", "gravity_disturbance")


def test_the_static_alignment_jacobian_is_the_levelling_closed_form():
    # level at rest, heading 30 deg: f_b = C_bn [0, 0, -g]; an accelerometer change df_b
    # tilts the levelled frame by phi_N = df_E / g, phi_E = -df_N / g (df_n = C_nb df_b);
    # a gyro change turns the gyrocompassed heading by phi_D = dw_E / (Omega cos L) and no tilt
    g, lat, yaw = 9.81, math.radians(45.0), math.radians(30.0)
    c_nb = rotation.dcm_from_euler([0.0, 0.0, yaw])
    om = 7.292115e-5
    w_n = np.array([om * math.cos(lat), 0.0, -om * math.sin(lat)])
    jac = static_attitude_jacobian(c_nb.T @ w_n, c_nb.T @ np.array([0.0, 0.0, -g]))
    tilt = jac[:, 3:] @ c_nb.T  # per NED specific-force change
    np.testing.assert_allclose(tilt[:2, :2], [[0.0, 1.0 / g], [-1.0 / g, 0.0]], atol=1e-7)
    head = jac[:, :3] @ c_nb.T  # per NED rate change
    np.testing.assert_allclose(head[:2], 0.0, atol=1e-6)
    assert head[2, 1] == pytest.approx(1.0 / (om * math.cos(lat)), rel=1e-5)


@pytest.fixture(scope="module")
def ramp_design(reference_cases):
    """The case's A at the re-run rate with its gains, the families' columns, and the linear
    responses to them (M, 3, m)."""
    cfg, _ = case_config(reference_cases, NAME)
    log = pipeline.ingest(reference_cases / f"{NAME}.mcap", cfg)
    log_r = null_model.decimate_imu(log, rerun_decimation(log, cfg.pairs.rerun_imu_rate_hz))
    opts = replace(cfg.filter_options(), smoother=False, covariance_outputs=False)
    base = navigate(log_r, cfg, options=opts, record_gains=True)
    t_run = t_s_from_time_ns(log_r.imu.time_ns, int(log_r.imu.time_ns[0]))
    knots = knots_s(float(base.alignment.t_s), float(t_run[-1]))
    sol = base.forward
    ref = (float(sol.lat_rad[sol.t_s.size // 3]), float(sol.lon_rad[sol.t_s.size // 3]))
    field = stage._field_input(base, ref, 20000.0)
    breaks = np.unique(np.round(np.concatenate([knots, step_times_s(knots)]), 6))
    dnu = {f: innovation_responses(base.gain_replay, sol.trajectory, t_run,
                                   log_r.imu.w_ib_b_radps, log_r.imu.f_ib_b_mps2,
                                   stage._column_input(f, knots, field), breaks_s=breaks,
                                   static_window_s=static_alignment_window(base, opts))
           for f in FAMS}
    return cfg, opts, log_r, base, t_run, knots, field, dnu


def _replayed(cfg, opts, log_r, base, sensor, axis, column):
    """A's innovations with ``column`` added to one axis (or all, -1) of its samples and its
    gains replayed, less the unperturbed replay."""
    def innovations(lg):
        return navigate(lg, cfg, options=opts, replay=base.gain_replay).innovations.dz_ned
    name = "f_ib_b_mps2" if sensor == "accel" else "w_ib_b_radps"
    arr = getattr(log_r.imu, name).copy()
    if axis < 0:
        arr += column
    else:
        arr[:, axis] += column
    perturbed = replace(log_r, imu=replace(log_r.imu, **{name: arr}))
    return innovations(perturbed) - innovations(log_r)


@pytest.mark.reference
@pytest.mark.parametrize(("family", "axis", "knot"), [
    ("gyro_bias_change", 0, 0), ("gyro_bias_change", 1, 4), ("accel_bias_change", 0, 0),
    ("accel_bias_change", 1, 8), ("gravity_disturbance", -1, 0),
    ("gravity_disturbance", -1, 7), ("gyro_bias_change", 0, 20),
    ("accel_bias_change", 1, 30)])
def test_the_linear_responses_are_the_gain_replays(ramp_design, family, axis, knot):
    # ``knot`` indexes the basis (:func:`pospp.diagnose.shapes.change_basis`): the hinges,
    # then the steps (20 and 30: steps at about 1150 and 1600 s)
    # each column whitened by A's S^-1 over the records the fit uses, as the fit sees it:
    # measured 0.1-1.2 % of its norm (the knot-0 hinges and the gravity terms, which act
    # through the static alignment and before the replay's k_from, at the top); without the
    # alignment's response the gravity terms were 6-14 % off, with F at the interval's end
    # rather than its midpoint the hinges 1-8 %
    cfg, opts, log_r, base, t_run, knots, field, dnu = ramp_design
    gains, rec = base.gain_replay, base.innovations
    used = (gains.status == STATUS_USED) & (rec.status == STATUS_USED) & \
        (rec.t_s >= base.alignment.t_s)
    chol = np.linalg.cholesky(gains.s_inv[used])
    step = catalog_entry(family).plausible_si
    if family == "gravity_disturbance":
        sol = base.forward
        at = np.clip(np.searchsorted(sol.t_s, t_run), 0, sol.t_s.size - 1)
        column = field(t_run, rotation.dcm_from_quat(sol.q_nb[at]))[:, :, knot]
        old = _replayed(cfg, opts, log_r, base, "accel", -1, step * column)
        j = knot
    else:
        sensor = "gyro" if family == "gyro_bias_change" else "accel"
        old = _replayed(cfg, opts, log_r, base, sensor, axis,
                        step * change_basis(t_run, knots)[:, knot])
        j = axis * basis_size(knots) + knot
    old_w = np.einsum("kji,kj->ki", chol, old[used] / step).ravel()
    new_w = np.einsum("kji,kj->ki", chol, dnu[family][used, :, j]).ravel()
    assert np.linalg.norm(old_w) > 10.0  # the column is seen on the innovations
    rel = np.linalg.norm(new_w - old_w) / np.linalg.norm(old_w)
    assert rel < 0.02, rel


@pytest.mark.reference
def test_the_grid_a_stretch_at_a_time_is_the_whole_grid_at_once(ramp_design, monkeypatch):
    # the input integrals made per stretch (memory): stretches of 7 intervals, each starting
    # at the last one's end point, give the whole grid's responses (and every record's)
    cfg, opts, log_r, base, t_run, knots, field, dnu = ramp_design
    monkeypatch.setattr(innovation_response, "_STRETCH", 7)
    breaks = np.unique(np.round(np.concatenate([knots, step_times_s(knots)]), 6))
    fam = "accel_bias_change"
    short = innovation_responses(base.gain_replay, base.forward.trajectory, t_run,
                                 log_r.imu.w_ib_b_radps, log_r.imu.f_ib_b_mps2,
                                 stage._column_input(fam, knots, field), breaks_s=breaks,
                                 static_window_s=static_alignment_window(base, opts))
    assert np.count_nonzero(np.any(dnu[fam] != 0.0, axis=(1, 2))) > 1000
    np.testing.assert_allclose(short, dnu[fam], rtol=1e-12, atol=1e-12 * np.abs(dnu[fam]).max())


@pytest.mark.reference
def test_the_time_offset_column_reads_the_whole_offset_at_once(reference_cases):
    # A's response to a GNSS time offset through its own gains (its records' errors, the
    # antenna's velocity and acceleration per second: pospp.diagnose.linear_signatures)
    # reads flight_time_offset_200hz's true 15 ms in one pass (measured 15.6 +- 0.3 ms); the
    # column made by replaying A on the log restamped by 1 ms read 7.1 ms: a restamped record
    # moves by a whole IMU interval in the replay, not by the millisecond
    name = "flight_time_offset_200hz"
    cfg, params = case_config(reference_cases, name)
    log = pipeline.ingest(reference_cases / f"{name}.mcap", cfg)
    design = stage.innovation_design(log, cfg, ("accel_bias_change",))
    late_s, sigma_s, significant = stage._offset_reading(design)  # GNSS stamped c s early
    truth_s = params["gnss"]["time_offset_s"]  # GNSS stamps minus true time
    assert significant and sigma_s < 1e-3
    assert -late_s == pytest.approx(truth_s, abs=1.5e-3)


@pytest.mark.reference
def test_the_design_summed_a_stretch_at_a_time_is_that_of_the_whole_responses(ramp_design,
                                                                              monkeypatch):
    # innovation_design whitens each stretch's records and sums them into the Gram matrix,
    # J^T y and the flexible shapes' columns (no family's responses held whole): the same as
    # whitening the whole responses (innovation_responses) and summing them at once
    from pospp.diagnose.sensor_families import InnovationDesign

    cfg, opts, log_r, base, t_run, knots, field, dnu = ramp_design
    monkeypatch.setattr(innovation_response, "_STRETCH", 97)
    monkeypatch.setattr(stage, "summed_down", lambda log, config: log_r)
    monkeypatch.setattr(stage, "navigate", lambda *a, **k: base)
    fams = ("accel_bias_change", "gyro_bias_change")  # without a reference: no gravity
    got = stage.innovation_design(log_r, cfg, fams)
    gains, rec = base.gain_replay, base.innovations
    used = (gains.status == STATUS_USED) & (rec.status == STATUS_USED) & \
        np.all(np.isfinite(rec.dz_ned), axis=1) & (rec.t_s >= base.alignment.t_s)
    chol = np.linalg.cholesky(gains.s_inv[used])
    whole = {f: np.einsum("kji,kjm->kim", chol, dnu[f][used]).reshape(-1, 2, dnu[f].shape[2] // 2)
             .transpose(0, 2, 1) for f in fams}
    want = InnovationDesign.of_responses(got.y, whole, knots, got.t_end_s, got.record_t_s)
    assert got.gram.shape == (4 * basis_size(knots),) * 2 and np.count_nonzero(got.gram) > 1000
    scale = np.abs(want.gram).max()
    np.testing.assert_allclose(got.gram, want.gram, rtol=1e-10, atol=1e-12 * scale)
    np.testing.assert_allclose(got.jty, want.jty, rtol=1e-10,
                               atol=1e-12 * np.abs(want.jty).max())
    for f in fams:
        np.testing.assert_allclose(got.flexible[f], want.flexible[f], rtol=1e-10,
                                   atol=1e-12 * np.abs(want.flexible[f]).max())


@pytest.mark.reference
def test_the_families_passes_on_two_threads_are_those_on_one(reference_cases):
    # innovation_design's families run one per thread over each stretch (each an independent
    # pass over the same grid): the design is the same bit for bit
    name = "flight_accel_ramp_100hz"
    cfg, _ = case_config(reference_cases, name)
    log = pipeline.ingest(reference_cases / f"{name}.mcap", cfg)
    fams = ("accel_bias_change", "gyro_bias_change")
    one = stage.innovation_design(log, cfg, fams, threads=1)
    two = stage.innovation_design(log, cfg, fams, threads=2)
    assert np.count_nonzero(one.gram) > 1000
    np.testing.assert_array_equal(two.gram, one.gram)
    np.testing.assert_array_equal(two.jty, one.jty)
    for fam in fams:
        np.testing.assert_array_equal(two.flexible[fam], one.flexible[fam])
    np.testing.assert_array_equal(two.y, one.y)


def test_the_running_integrals_a_block_at_a_time_are_one_running_sum():
    # linear_null._running_integrals sums the IMU's increments a block at a time (memory):
    # bit for bit the one running sum over every sample, interpolated, at grid points before,
    # between, on and after the samples
    from pospp.calib.linear_null import _running_integrals

    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.004, 0.006, 1000))
    rate = rng.normal(size=(1000, 3))
    grid = np.sort(np.concatenate([rng.uniform(t[0] - 0.1, t[-1] + 0.1, 300), t[::97],
                                   [t[0], t[-1]]]))
    cum = np.zeros((1000, 3))
    cum[1:] = rate[1:] * np.diff(t)[:, None]
    np.cumsum(cum, axis=0, out=cum)
    whole = np.column_stack([np.interp(grid, t, cum[:, c]) for c in range(3)])
    for block in (7, 64, 999, 1000, 5000):
        np.testing.assert_array_equal(_running_integrals(grid, t, rate, block=block), whole)
