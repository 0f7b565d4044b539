"""The linear-covariance null (pospp.calib.linear_null) against independent computations.

One short simulated flight (pospp.sim: 60 s static, two 60 s legs joined by a 180 deg turn,
50 Hz ``paper_flight`` IMU, 1 Hz GNSS), pospp's A recording its gains, the first 20 s of the
two legs. Checked:

- one interval's transition against ``scipy.linalg.expm`` of the same augmented F, assembled
  here from A's F (:func:`pospp.nav._filter_kernel.fill_extended_f`) and the equations of the
  module docstring;
- the adjoint's covariance against ``L L^T``, L the forward pass's matrix (the system run on
  unit noise vectors): the two passes are each other's transpose, to rounding;
- the exact covariance against a brute-force Monte Carlo of the same linear system written
  in other coordinates (A's bias *estimates* and the true drifts as states, F integrated by
  scipy's expm on 0.1 s steps, Euler-Maruyama noise, the textbook smoother, B re-run from the
  smoothed state in a second pass): the likelihood-ratio test of Sigma = C on projections of
  B minus A (chi-square, p(p + 1) / 2 degrees of freedom).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _missions import SimLog, three_leg_survey
from scipy import linalg, stats

from pospp import flight_stages, null_stage, pipeline
from pospp.calib import _null_kernel as kernel
from pospp.calib.design import design_matrix
from pospp.calib.linear_null import NullNoise, linear_null
from pospp.calib.solve import FitOptions, fit_calibration
from pospp.config import config_from_dict
from pospp.nav._filter_kernel import fill_extended_f
from pospp.nav.strapdown import interpolate_trajectory
from pospp.sim.api import simulate
from pospp.sim.gnss import GnssModel
from pospp.sim.profile import parse_profile

DPH = np.pi / 180.0 / 3600.0
NOISE = NullNoise(gyro_arw_radpsqrts=0.01 * np.pi / 180 / 60,
                  accel_vrw_mpspsqrts=2e-4, pos_sigma_ned_m=np.array([0.05, 0.05, 0.1]),
                  vel_sigma_ned_mps=np.array([0.02, 0.02, 0.03]),
                  gyro_gm_sigma_radps=0.3 * DPH, gyro_gm_tau_s=200.0,
                  accel_gm_sigma_mps2=5e-4, accel_gm_tau_s=900.0)
"""Drifts whose tau differ from A's (300 s, 3600 s): the coupling into A's slot is not 0."""
SAMPLES = 21


@pytest.fixture(scope="module")
def flight():
    prof = three_leg_survey("linear_null", 60.0, lat_deg=34.0, lon_deg=108.0,
                            height_m=1000.0, heading_deg=40.0)
    prof["segment"] = prof["segment"][:6]
    sim = simulate(parse_profile(prof), imu_grade="paper_flight",
                   gnss=GnssModel(rate_hz=1.0, pos_noise_m=(0.05, 0.1),
                                  vel_noise_mps=(0.02, 0.03)), seed=3)
    cfg = config_from_dict({"imu": {"grade": "flight"},
                            "filter": {"output_rate_hz": 10.0, "smoother": True},
                            "legs": {"min_duration_s": 40.0, "min_speed_mps": 20.0,
                                     "settle_s": 30.0}})
    log = SimLog(sim.imu, sim.fix, sim.vel)
    nav = pipeline.navigate(log, cfg, record_gains=True)
    imu = pipeline.imu_increments(log)
    made = flight_stages.calibration_replays(imu, nav, cfg)
    reps = [dataclasses.replace(r, t_s=r.t_s[:SAMPLES])
            for _, r in sorted(made.replays.items())]
    assert len(reps) == 2
    model = linear_null(nav.gain_replay, nav.smoothed.trajectory, imu.t_s, imu.w_ib_b_radps,
                        imu.f_ib_b_mps2, reps, NOISE)
    return nav, imu, reps, model, (log, cfg, made)


def _augmented_f(model, g: int) -> np.ndarray:
    """F of z at grid point g, from A's F and the module docstring's equations."""
    xs, fm, wm, _ = model.grid
    n_a, i_gm, i_sf, slot_g, slot_a = model.lay
    fa = np.zeros((n_a, n_a))
    fill_extended_f(xs[g], fm[g], wm[g], i_gm, i_sf, model.inv_tau_a, np.empty((3, 3)), fa)
    inv_g, inv_a = 1.0 / NOISE.gyro_gm_tau_s, 1.0 / NOISE.accel_gm_tau_s
    fz = np.zeros((n_a + 18, n_a + 18))
    fz[:n_a, :n_a] = fa
    ib, jb = n_a, n_a + 6
    for k in range(3):  # e_s' = -e_s / tau_A + (1 / tau_A - 1 / tau) beta
        fz[slot_g + k, ib + k] = model.inv_tau_a[0] - inv_g
        fz[slot_a + k, ib + 3 + k] = model.inv_tau_a[1] - inv_a
        fz[ib + k, ib + k] = -inv_g
        fz[ib + 3 + k, ib + 3 + k] = -inv_a
    fz[jb:jb + 9, jb:jb + 9] = fa[:9, :9]
    fz[jb:jb + 9, ib:ib + 3] = fa[:9, 9:12]  # B's gyro error: beta_g
    fz[jb:jb + 9, ib + 3:ib + 6] = fa[:9, 12:15]  # B's accelerometer error: beta_a + c_B
    fz[jb:jb + 9, jb + 9:jb + 12] = fa[:9, 12:15]
    return fz


def test_interval_transition_is_expm_of_the_augmented_f(flight):
    model = flight[3]
    xs, fm, wm, dt = model.grid
    g = int(np.argmax(np.linalg.norm(wm[1:], axis=1))) + 1  # in the turn
    nz = model.lay[0] + 18
    phi, gam = np.empty((nz, nz)), np.empty((nz, kernel.N_NOISE))
    n_a = nz - 18
    blocks = {"A": np.s_[:n_a, :n_a], "A <- drift": np.s_[:n_a, n_a:n_a + 6],
              "drift": np.s_[n_a:n_a + 6, n_a:n_a + 6], "B": np.s_[n_a + 6:, n_a + 6:],
              "B <- drift": np.s_[n_a + 6:, n_a:n_a + 6]}
    # the fourth-order series, relative to each block's largest entry, measured at t = 0.1 /
    # 1 s: A 6e-12 / 6e-8, A <- drift 5e-8 / 4.2e-4 (the fifth-order chain position <- velocity
    # <- attitude <- slot <- drift), B 3e-16 / 3e-12, B <- drift 1.5e-10 / 4e-7
    for t, bound in ((0.1, 1e-6), (1.0, 2e-3)):
        kernel.interval_matrices(xs[g], fm[g], wm[g], t, model.lay, model.inv_tau_a,
                                 model.inj, phi, gam, np.empty((5, n_a + 6, n_a + 6)),
                                 np.empty((4, 15, 15)), np.empty((nz, kernel.N_IN)))
        ref = linalg.expm(_augmented_f(model, g) * t)
        for name, b in blocks.items():
            err = np.max(np.abs(phi[b] - ref[b])) / np.max(np.abs(ref[b]))
            assert err <= bound, (t, name, err)


@pytest.fixture(scope="module")
def ell(flight):
    """The system's matrix L (3 J, n_noise): a realisation is L xi."""
    return flight[3].matrix()


def _injected_matrix(model) -> np.ndarray:
    """(3 L, n_noise): the injected gyro error's leg means as a matrix of the normals
    (:meth:`LinearNull.injected_leg_means` on unit vectors)."""
    n = model.n_noise
    cols = [model.injected_leg_means(np.eye(n)[:, c:c + 2000]) for c in range(0, n, 2000)]
    return np.concatenate(cols, axis=2).reshape(-1, n)


def _lr_p(exact: np.ndarray, f: np.ndarray) -> float:
    """p-value of the likelihood-ratio test that zero-mean samples ``f`` (n, p) have the
    covariance ``exact`` (chi-square, p (p + 1) / 2 degrees of freedom)."""
    n, p = f.shape
    m = np.linalg.solve(exact, f.T @ f / n)
    return float(stats.chi2.sf(n * (np.trace(m) - np.linalg.slogdet(m)[1] - p),
                               p * (p + 1) / 2))


def test_adjoint_covariance_is_the_forward_matrix_squared(flight, ell):
    model = flight[3]
    assert ell.shape[1] == model.n_noise
    dense = ell @ ell.T
    eye = np.eye(3 * model.n_samples).reshape(-1, model.n_samples, 3)
    exact = model.covariance(eye)
    scale = np.sqrt(np.outer(np.diag(dense), np.diag(dense))) + 1e-30
    assert np.max(np.abs(exact - dense) / scale) < 1e-9
    # B starts on A: the first sample of each leg is zero in every realisation
    first = np.cumsum([0, *model.leg_sizes[:-1]])
    assert np.max(np.abs(ell.reshape(model.n_samples, 3, -1)[first])) < 1e-12
    assert np.min(np.diag(dense).reshape(-1, 3)[first + 5, :2]) > 0.0


def _brute_force(nav, imu, reps, n_draws: int, rng: np.random.Generator, h_s: float = 0.1
                 ) -> tuple[np.ndarray, np.ndarray]:
    """B minus A at the replays' samples (n_draws, J, 3), by Monte Carlo of the linear system
    in state coordinates (module docstring): y = [A's navigation error (9), A's bias estimates
    (constant gyro, accel, Gauss-Markov gyro, accel: 12), the true drifts (6)], over A's whole
    pass (its smoother reads every node), in batches of 50 draws; and the gyro error injected
    (drift plus white rate noise), averaged over each leg (n_draws, L, 3)."""
    gains = nav.gain_replay
    assert (gains.layout.n, gains.layout.i_gm, gains.layout.i_sf) == (21, 15, -1)
    t_nodes = gains.t_s[gains.node_k]
    t_samp = np.concatenate([r.t0_s + r.t_s for r in reps])
    events = np.unique(np.concatenate([t_nodes, t_samp]).round(9))
    steps = [np.linspace(a, b, max(1, int(np.ceil((b - a) / h_s - 1e-9))) + 1)[1:]
             for a, b in zip(events[:-1], events[1:], strict=True)]
    ends = np.concatenate(steps)
    starts = np.concatenate([[events[0]], ends[:-1]])
    traj = interpolate_trajectory(nav.smoothed.trajectory, ends)
    xs = np.column_stack([traj.lat_rad, traj.lon_rad, traj.height_m, traj.v_n_mps, traj.q_nb])
    dti = np.diff(imu.t_s)
    mean = []
    for rate in (imu.f_ib_b_mps2, imu.w_ib_b_radps):
        cum = np.vstack([np.zeros(3), np.cumsum(rate[1:] * dti[:, None], axis=0)])
        at = [np.column_stack([np.interp(t, imu.t_s, cum[:, a]) for a in range(3)])
              for t in (starts, ends)]
        mean.append((at[1] - at[0]) / (ends - starts)[:, None])
    decay = np.diag(np.repeat([1.0 / NOISE.gyro_gm_tau_s, 1.0 / NOISE.accel_gm_tau_s], 3))
    fas, e_y, e_u = [], [], {}
    leg_steps = [np.flatnonzero((ends > r.t0_s + 1e-9) & (ends <= r.t0_s + r.t_s[-1] + 1e-9))
                 for r in reps]
    in_leg = set(np.concatenate(leg_steps).tolist())
    for i in range(ends.size):  # the linear system's matrices, the same for every draw
        fa = np.zeros((21, 21))
        fill_extended_f(xs[i], mean[0][i], mean[1][i], 15, -1, gains.gm_inv_tau,
                        np.empty((3, 3)), fa)
        fy = np.zeros((27, 27))  # nav error driven by (drift - estimates), estimates decay
        fy[:9, :9] = fa[:9, :9]
        for blk, sgn in ((9, -1), (15, -1), (21, 1)):
            fy[:9, blk:blk + 3] = sgn * fa[:9, 9:12]
            fy[:9, blk + 3:blk + 6] = sgn * fa[:9, 12:15]
        fy[15:21, 15:21] = -np.diag(np.repeat(gains.gm_inv_tau, 3))
        fy[21:27, 21:27] = -decay
        fas.append(fa)
        e_y.append(linalg.expm(fy * (ends[i] - starts[i])))
        if i in in_leg:  # B: [its nav error, the drifts, A's smoothed accel bias at t0]
            fu = np.zeros((18, 18))
            fu[:9, :9] = fa[:9, :9]
            fu[:9, 9:12] = fa[:9, 9:12]
            fu[:9, 12:15] = fa[:9, 12:15]
            fu[:9, 15:18] = -fa[:9, 12:15]
            fu[9:15, 9:15] = -decay
            e_u[i] = linalg.expm(fu * (ends[i] - starts[i]))
    parts = [_brute_force_batch(gains, reps, t_nodes, t_samp, events, starts, ends, fas, e_y,
                                e_u, leg_steps, min(50, n_draws - c), rng)
             for c in range(0, n_draws, 50)]
    return np.concatenate([q[0] for q in parts]), np.concatenate([q[1] for q in parts])


def _brute_force_batch(gains, reps, t_nodes, t_samp, events, starts, ends, fas, e_y, e_u,
                       leg_steps, n, rng):
    """:func:`_brute_force` for ``n`` draws."""
    st = gains.status
    used = ((st == 0) | (st == 2)) & (gains.meas_k >= gains.node_k[0])
    rec_node = np.searchsorted(gains.node_k, gains.meas_k[used])
    rec_k, rec_h, rec_kind = gains.gains[used], gains.h[used], gains.meas_kind[used]
    qg = NOISE.gyro_gm_sigma_radps * np.sqrt(2 / NOISE.gyro_gm_tau_s)
    qa = NOISE.accel_gm_sigma_mps2 * np.sqrt(2 / NOISE.accel_gm_tau_s)
    me = np.zeros((21, 27))  # A's error: [dx; -b_g; -b_a; beta_g - b_gm; beta_a - b_am]
    me[:9, :9] = np.eye(9)
    me[9:21, 9:21] = -np.eye(12)
    me[15:21, 21:27] = np.eye(6)
    y = np.zeros((27, n))
    y[21:24] = NOISE.gyro_gm_sigma_radps * rng.standard_normal((3, n))
    y[24:27] = NOISE.accel_gm_sigma_mps2 * rng.standard_normal((3, n))
    dx_nodes = np.zeros((t_nodes.size, 21, n))
    e_samp, beta0, xis = {}, {}, {}

    def at_event(t):
        k = int(np.searchsorted(t_nodes, t - 1e-6))
        if k < t_nodes.size and abs(t_nodes[k] - t) < 1e-6:
            for i in np.flatnonzero(rec_node == k):
                sig = (NOISE.pos_sigma_ned_m if rec_kind[i] == 0 else NOISE.vel_sigma_ned_mps
                       if rec_kind[i] == 1 else np.zeros(3))
                dz = rec_h[i] @ (me @ y) - sig[:, None] * rng.standard_normal((3, n))
                dx = rec_k[i] @ dz
                y[:9] -= dx[:9]
                y[9:21] += dx[9:21]
                dx_nodes[k] += dx
        for j in np.flatnonzero(np.abs(t_samp - t) < 1e-6):
            e_samp[j] = me @ y
            beta0[j] = y[21:27].copy()

    at_event(events[0])
    ev = set(np.round(events, 6).tolist())
    for i in range(ends.size):
        xi = rng.standard_normal((12, n))
        y = e_y[i] @ y
        sq, fa = np.sqrt(ends[i] - starts[i]), fas[i]
        y[:3] += NOISE.gyro_arw_radpsqrts * sq * fa[:3, 9:12] @ xi[:3]
        y[3:6] += NOISE.accel_vrw_mpspsqrts * sq * fa[3:6, 12:15] @ xi[3:6]
        y[21:24] += qg * sq * xi[6:9]
        y[24:27] += qa * sq * xi[9:12]
        if i in e_u:
            xis[i] = xi
        if round(ends[i], 6) in ev:
            at_event(ends[i])
    # A's smoother (textbook recursion with its gains), interpolated as A does
    e_plus = np.zeros_like(dx_nodes)
    e_minus = dx_nodes.copy()
    for k in range(t_nodes.size - 2, -1, -1):
        e_plus[k] = gains.smoother_gains[k] @ e_minus[k + 1]
        e_minus[k] = e_plus[k] + dx_nodes[k]
    s = {}
    for j, t in enumerate(t_samp):
        i = int(np.searchsorted(t_nodes, t + 1e-6, side="right")) - 1
        al = float(np.clip((t - t_nodes[i]) / (t_nodes[i + 1] - t_nodes[i]), 0, 1))
        s[j] = e_samp[j] - ((1 - al) * e_plus[i] + al * e_minus[i + 1])
    out = np.zeros((n, t_samp.size, 3))
    inj = np.zeros((n, len(reps), 3))
    inv_tau = 1.0 / NOISE.gyro_gm_tau_s
    j0 = 0
    for leg, (r, steps) in enumerate(zip(reps, leg_steps, strict=True)):  # B from A's smoothed
        est = e_samp[j0] - s[j0]  # the smoother's estimate of A's error at t0
        bhat_a = beta0[j0][3:6] - e_samp[j0][12:15] - e_samp[j0][18:21]  # b_a + b_am
        u = np.vstack([s[j0][:9], beta0[j0], bhat_a + est[12:15] + est[18:21]])
        for i in steps:  # the injected gyro error: the drift's path inside the step, and
            h = ends[i] - starts[i]  # the white rate noise's integral over it
            inj[:, leg] += ((1.0 - np.exp(-h * inv_tau)) / inv_tau * u[9:12]
                            + NOISE.gyro_arw_radpsqrts * np.sqrt(h) * xis[i][:3]).T
            u = e_u[i] @ u
            sq, fa, xi = np.sqrt(ends[i] - starts[i]), fas[i], xis[i]
            u[:3] += NOISE.gyro_arw_radpsqrts * sq * fa[:3, 9:12] @ xi[:3]
            u[3:6] += NOISE.accel_vrw_mpspsqrts * sq * fa[3:6, 12:15] @ xi[3:6]
            u[9:12] += qg * sq * xi[6:9]
            u[12:15] += qa * sq * xi[9:12]
            for j in np.flatnonzero(np.abs(t_samp - ends[i]) < 1e-6):
                out[:, j] = (u[3:6] - s[j][3:6]).T
        inj[:, leg] /= sum(ends[i] - starts[i] for i in steps)
        j0 += r.t_s.size
    return out, inj


def _legendre_weights(model) -> np.ndarray:
    """(12, J, 3): per leg and horizontal channel, the samples' projections on the first three
    Legendre polynomials of the time since the leg start."""
    w = np.zeros((12, model.n_samples, 3))
    start = np.cumsum([0, *model.leg_sizes[:-1]])
    row = 0
    for j0, m in zip(start, model.leg_sizes, strict=True):
        x = np.linspace(-1.0, 1.0, m)
        for c in range(2):
            for deg in range(3):
                w[row, j0:j0 + m, c] = np.polynomial.legendre.legval(x, np.eye(3)[deg]) / m
                row += 1
    return w


def test_exact_covariance_against_a_brute_force_monte_carlo(flight, ell):
    nav, imu, reps, model, _ = flight
    w = _legendre_weights(model)
    exact = model.covariance(w)
    rng = np.random.default_rng(11)
    n = 1500
    d, inj = _brute_force(nav, imu, reps, n, rng)
    f = np.einsum("pja,rja->rp", w, d)
    s = f.T @ f / n
    p = w.shape[0]
    m = np.linalg.solve(exact, s)
    stat = n * (np.trace(m) - np.linalg.slogdet(m)[1] - p)
    assert stats.chi2.sf(stat, p * (p + 1) / 2) > 1e-3, (stat, np.diag(s) / np.diag(exact))
    # and the draws of the model itself, the same test
    dm = np.stack([np.concatenate(r) for r in model.draws(n, 5)])
    fm = np.einsum("pja,rja->rp", w, dm)
    mm = np.linalg.solve(exact, fm.T @ fm / n)
    stat_m = n * (np.trace(mm) - np.linalg.slogdet(mm)[1] - p)
    assert stats.chi2.sf(stat_m, p * (p + 1) / 2) > 1e-3, stat_m
    # the gyro error each draw injected, averaged over each leg (the truth the flight's bias
    # is measured against: pospp.calib.null_covariance.with_null_covariance), jointly with B minus A
    m_inj = _injected_matrix(model)
    big = np.vstack([np.einsum("pja,jan->pn", w, ell.reshape(model.n_samples, 3, -1)), m_inj])
    g = np.hstack([f, inj.reshape(n, -1)])
    assert _lr_p(big @ big.T, g) > 1e-3
    # ... which rejects the truths with their sign flipped (uncorrelated: the same)
    assert _lr_p(big @ big.T, np.hstack([f, -inj.reshape(n, -1)])) < 1e-6
    # and their variance: white noise q / T plus the stationary drift's mean over T
    t_leg = np.array([r.t_s[-1] for r in reps])
    s2, tau = NOISE.gyro_gm_sigma_radps**2, NOISE.gyro_gm_tau_s
    var = (NOISE.gyro_arw_radpsqrts**2 / t_leg
           + 2 * s2 * tau**2 / t_leg**2 * (t_leg / tau - 1 + np.exp(-t_leg / tau)))
    assert np.allclose(np.sum(m_inj**2, axis=1), np.repeat(var, 3), rtol=2e-3)


@pytest.mark.parametrize("noise", ["gyro_rw", "gm", "white"])
def test_calibration_gain_is_the_fits_linear_map(flight, noise):
    # the least squares' estimate is gain @ z at its fitted variances, in each noise model
    # (the sandwich covariance reads it: pospp.null_stage.with_null_sigmas)
    made = flight[4][2]
    legs = tuple(r for _, r in sorted(made.replays.items()))
    kw = {"gm": {"gyro_gm_sigma_radps": 0.5 * DPH, "gyro_gm_tau_s": 300.0},
          "gyro_rw": {}, "white": {"noise": "white"}}[noise]
    cal = fit_calibration(legs, "body",
                          FitOptions(gyro_arw_radpsqrts=NOISE.gyro_arw_radpsqrts, **kw))
    _, z, _, _ = design_matrix(legs, "body")
    assert cal.gain is not None and cal.gain.shape == (cal.x.size, z.size)
    assert np.allclose(cal.gain @ z, cal.x, rtol=1e-9, atol=1e-12 * np.max(np.abs(cal.x)))


def test_null_stage_linear_by_default_reruns_on_request_and_its_fallbacks(flight):
    nav, imu, _, _, (log, cfg, _) = flight
    run, _ = pipeline.calibrate_from_a(imu, nav, cfg)
    assert run.calibrated, run.reason
    stage = null_stage.null_stage(log, nav, run, cfg, n=4, seed=1)
    assert stage.calibration.sigma_source == "linear_null"
    sizes = [r.dv_n_mps.shape for _, r in sorted(run.replays.items())]
    assert len(stage.realisations) == 4
    assert [d.shape for d in stage.realisations[0]] == sizes
    model = null_stage.linear_null_model(log, nav, run, cfg,
                                         null_stage.null_noise(log, nav, run, cfg))
    cov = model.calibration_covariance(run.chosen)
    assert np.allclose(stage.calibration.chosen.cov, cov, rtol=1e-12, atol=0.0)
    # on two threads (the exact covariance beside the refits): the same calibration
    two = null_stage.null_stage(log, nav, run, cfg, n=4, seed=1, threads=2).calibration
    np.testing.assert_array_equal(two.chosen.cov, stage.calibration.chosen.cov)
    np.testing.assert_array_equal(two.flight_gyro_bias_sigma_b_radps,
                                  stage.calibration.flight_gyro_bias_sigma_b_radps)
    # A without recorded gains: run again to record them, the same system to rounding
    again = null_stage.linear_null_model(log, dataclasses.replace(nav, gain_replay=None), run,
                                         cfg, model_noise := null_stage.null_noise(
                                             log, nav, run, cfg))
    assert np.allclose(again.calibration_covariance(run.chosen), cov, rtol=1e-9)
    # A that reset its covariance: the gains of A on its GNSS-on-A log (the re-run null's
    # base), the same here within 2 % (this A gated nothing)
    reset = null_stage.linear_null_model(
        log, dataclasses.replace(nav, resets=((200.0, "position"),)), run, cfg, model_noise)
    sig = np.sqrt(np.diag(cov))
    assert np.max(np.abs(np.sqrt(np.diag(reset.calibration_covariance(run.chosen))) / sig - 1)
                  ) < 0.02
    # a leg before A's heading converged (the gain replay's switch epoch): the A re-runs
    t0 = min(r.t0_s for r in run.replays.values())
    late = dataclasses.replace(nav.gain_replay, k_from=int(np.searchsorted(
        nav.gain_replay.t_s, t0 + 1.0)))
    rerun = null_stage.null_stage(log, dataclasses.replace(nav, gain_replay=late), run, cfg,
                                  n=3, seed=1)
    assert rerun.calibration.sigma_source == "null_realisations"
    assert any("before A's heading has converged" in m for m in rerun.calibration.messages)
    assert [d.shape for d in rerun.realisations[0]] == sizes
    # and on request
    cfg_r = dataclasses.replace(cfg, pairs=dataclasses.replace(cfg.pairs, null_reruns=True))
    assert null_stage.null_stage(log, nav, run, cfg_r, n=3).calibration.sigma_source \
        == "null_realisations"


def test_response_to_record_errors_spans_the_gnss_noise_exactly(flight):
    # B minus A's response to an error v at each record axis in turn (v = its sigma): the
    # sum of their outer products is the null's covariance with the GNSS noise alone, made
    # column by column from the draws' own normals (LinearNull.matrix with no IMU noise);
    # a record error put in another record's place, or in an interval's, breaks the equality
    nav, imu, reps, _, _ = flight
    gnss_only = dataclasses.replace(NOISE, gyro_arw_radpsqrts=0.0, accel_vrw_mpspsqrts=0.0,
                                    gyro_gm_sigma_radps=0.0, accel_gm_sigma_mps2=0.0)
    model = linear_null(nav.gain_replay, nav.smoothed.trajectory, imu.t_s, imu.w_ib_b_radps,
                        imu.f_ib_b_mps2, reps, gnss_only)
    sig = model.records[3]
    rec, axis = np.nonzero(sig > 0.0)
    v = np.zeros((sig.shape[0], 3, rec.size))
    v[rec, axis, np.arange(rec.size)] = sig[rec, axis]
    cols = np.concatenate(model.response(v)).reshape(-1, rec.size)
    ell = model.matrix()
    np.testing.assert_allclose(cols @ cols.T, ell @ ell.T, rtol=1e-9,
                               atol=1e-12 * np.max(np.abs(ell @ ell.T)))
    assert np.count_nonzero(np.linalg.norm(cols, axis=0)) > 0.5 * rec.size
