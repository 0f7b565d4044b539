"""The null of B minus A from A's own gains: B minus A's response to the flight's noise as a
linear system, its exact Gaussian draws and the exact covariance of linear functionals of it.

What is modelled (frames NED / FRD, SI, errors computed minus true: docs/method.md). The noise
a null realisation injects (:class:`NullNoise`: white gyro and accelerometer noise, first-order
Gauss-Markov gyro and accelerometer drifts beta_g, beta_a, white GNSS position and velocity
noise) drives A's closed-loop error e_A and B's error e_B; for A's recorded gains (the pass's
K, H and smoother gains A_k: :class:`pospp.nav.filter_state.GainReplay`) everything is linear
in that noise:

- A between its updates: ``e_A' = F_A e_A + G_A n`` (F_A A's own F,
  :func:`pospp.nav._filter_kernel.fill_extended_f`), its bias error in the drift's "slot" (its
  Gauss-Markov state, else its bias state) ``e_s = beta - b_hat_s``, so that
  ``e_s' = a_A e_s + (-1/tau - a_A) beta + w`` (a_A = -1/tau_A or 0: A's model of it);
- A at a record (its epoch a smoother node): ``dx = K (H e_A - v)``, ``e_A <- e_A - dx``
  (v the GNSS noise; none for a ZUPT);
- A's smoother over its nodes: ``e^_k^+ = A_k e^_k+1^-``, ``e^_k^- = e^_k^+ + dx_k``; the
  smoothed solution's error at t is ``s(t) = e_A(t) - e^(t)``, e^ linear between e^_i^+ and
  e^_i+1^- (as A interpolates it);
- B from each leg start t0: its navigation error starts at s(t0) (B takes A's smoothed
  state), its gyro error is ``beta_g + n_g`` (raw gyro), its accelerometer error
  ``beta_a(t) - beta_a(t0) + s_ba(t0) + n_a`` (A's smoothed total bias removed at t0), and
  it propagates with the same F (B's trajectory is A's to first order in the errors);
- the realisation: ``d(t) = e_B,v(t) - s_v(t)`` at the replays' samples, all legs jointly.

A grid holds A's nodes, the samples and points at most ``max_step_s`` apart; over each interval
``z = [e_A, beta_g, beta_a, e_B, c_B]`` moves by ``Phi z + Gamma xi`` (:mod:`pospp.calib.
_null_kernel`). :meth:`LinearNull.draws` runs it forward with random xi, then A's smoother
backward: exact draws from N(0, Sigma), Sigma the covariance of d over every sample of every
leg. :meth:`LinearNull.covariance` runs its adjoint (the smoother's forward, then the filter's
and B's backward) for the covariance ``W Sigma W^T`` of p functionals ``W d``, exactly, in one
pass (Sigma itself is not formed: 3 J x 3 J numbers, 0.3 GB at 6000 samples).

What it leaves out, and so where the A re-runs are the reference: A's gate (a record the
flight's A used is used, one it gated is not), its covariance resets and alignment (the noise
starts at A's first epoch, its initial state is the flight's), and second-order effects of the
noise on the trajectory the gains were made along. Measured against them: docs/diagnose.md,
"The linear null".
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from pospp.calib import _null_kernel as kernel
from pospp.calib.replay import LegReplay
from pospp.calib.solve import Calibration
from pospp.nav._filter_kernel import STATUS_RESET, STATUS_USED
from pospp.nav.error_model import I_BA, I_BG
from pospp.nav.filter_state import GainReplay
from pospp.nav.strapdown import Trajectory, interpolate_trajectory

MAX_STEP_S = 1.0
"""Longest grid interval [s] (A's smoother nodes are at most 1 s apart by default)."""
_SAME_S = 1e-6
"""Grid points closer than this are one [s]."""
_DX_BYTES = 256 * 2**20
"""Draws are made in chunks whose nodes' feedback (K x n_a x R) stays below this ..."""
_CHUNK = 64
"""... and of at most this many (wider products start BLAS's threads: on a loaded machine
400 draws of the sample took 37 s of CPU in one chunk, 1.5 s with one thread)."""


@dataclass(frozen=True)
class NullNoise:
    """The noise one null realisation injects (the A re-runs' and the linear null's).

    Attributes
    ----------
    gyro_arw_radpsqrts : float
        Gyro angle random walk [rad/s^0.5] (rate noise sigma = ARW / sqrt(dt)).
    accel_vrw_mpspsqrts : float
        Accelerometer velocity random walk [m/s / s^0.5].
    pos_sigma_ned_m : ndarray, shape (3,)
        GNSS position noise, NED [m].
    vel_sigma_ned_mps : ndarray, shape (3,)
        GNSS velocity noise, NED [m/s].
    gyro_gm_sigma_radps, gyro_gm_tau_s : float
        First-order Gauss-Markov gyro drift per axis (steady-state sigma [rad/s], correlation
        time [s]); 0 / inf: none.
    accel_gm_sigma_mps2, accel_gm_tau_s : float
        The same for the accelerometer bias [m/s^2], [s].
    """

    gyro_arw_radpsqrts: float
    accel_vrw_mpspsqrts: float
    pos_sigma_ned_m: NDArray
    vel_sigma_ned_mps: NDArray
    gyro_gm_sigma_radps: float = 0.0
    gyro_gm_tau_s: float = float("inf")
    accel_gm_sigma_mps2: float = 0.0
    accel_gm_tau_s: float = float("inf")


@dataclass(frozen=True)
class LinearNull:
    """B minus A's noise response along one flight as a linear system (module docstring):
    build with :func:`linear_null`. Samples are the replays' (legs in id order, J in all)."""

    grid: tuple[NDArray, NDArray, NDArray, NDArray]
    """Per grid point: kernel state (G, 10), mean specific force and rate over the interval
    ending there (G, 3) each, its length (G,) [s]."""
    lay: tuple[int, int, int, int, int]
    """(n_a, i_gm, i_sf, slot_g, slot_a): :mod:`pospp.calib._null_kernel`."""
    inv_tau_a: NDArray
    inj: NDArray
    """The injected noise as :mod:`pospp.calib._null_kernel` reads it."""
    events: tuple[NDArray, NDArray, NDArray]
    """(node, leg start, sample) at each grid point, -1 none."""
    records: tuple[NDArray, NDArray, NDArray, NDArray]
    """(first record of each node (K + 1,), K, H, noise sigma (nrec, 3))."""
    smoother_gains: NDArray | None
    """A_k (K, n_a, n_a); None: B is referenced to A's forward solution."""
    interp: tuple[NDArray, NDArray, NDArray, NDArray]
    """Node and weight of the smoother's interpolation at each sample and leg start."""
    sample_leg: NDArray
    """Leg index of each sample (J,)."""
    leg_ids: tuple[int, ...]
    leg_sizes: tuple[int, ...]
    leg_start_grid: NDArray
    """Grid point of each leg's start (L,)."""
    psi: NDArray
    """B's transition's velocity rows from its leg's start (J, 3, 12)."""
    record_t_s: NDArray
    """Each record's epoch [s, A's time axis] (in :attr:`records`' order)."""
    record_kind: NDArray
    """Each record's kind (0 GNSS position, 1 GNSS velocity, else a ZUPT)."""
    grid_t_s: NDArray
    """The grid's times [s, A's time axis]."""

    @property
    def n_samples(self) -> int:
        return int(self.sample_leg.shape[0])

    @property
    def n_noise(self) -> int:
        """Standard normals one realisation is made of (its noise's dimension)."""
        return int(6 + kernel.N_NOISE * (self.grid[0].shape[0] - 1)
                   + np.count_nonzero(self.records[3] > 0.0))

    def matrix(self) -> NDArray:
        """The system's matrix L (3 J, :attr:`n_noise`): a realisation is ``L xi`` (rows
        sample-major, N, E, D), Sigma = L L^T; made :data:`_CHUNK` columns at a time. Small
        systems only (tests)."""
        n = self.n_noise
        cols = []
        for c in range(0, n, _CHUNK):
            xi = np.zeros((n, min(_CHUNK, n - c)))
            xi[c:c + xi.shape[1]] = np.eye(xi.shape[1])
            cols.append(self._draw_chunk(xi.shape[1], np.random.default_rng(0), xi))
        return np.concatenate(cols, axis=2).reshape(3 * self.n_samples, n)

    def draws(self, n: int, seed: int, injected_out: list[NDArray] | None = None
              ) -> list[list[NDArray]]:
        """``n`` realisations of B minus A's null, each one (M, 3) NED array per leg (id
        order) [m/s]: exact draws from N(0, Sigma) of the linear system
        (``numpy.random.default_rng(seed)``: the same draws for the same seed and flight).
        ``injected_out``: when a list, each realisation appends the gyro error it injected,
        averaged over each leg (:meth:`injected_leg_means`; (L, 3), body FRD [rad/s])."""
        n_k, n_a = self.records[0].shape[0] - 1, self.lay[0]
        chunk = max(1, min(n, _CHUNK, _DX_BYTES // max(1, 8 * n_k * n_a)))
        rng = np.random.default_rng(seed)
        parts = []
        for c in range(0, n, chunk):
            if injected_out is None:
                parts.append(self._draw_chunk(min(chunk, n - c), rng))
                continue
            xi = rng.standard_normal((self.n_noise, min(chunk, n - c)))
            parts.append(self._draw_chunk(xi.shape[1], rng, xi))
            means = self.injected_leg_means(xi)
            injected_out.extend(means[:, :, r] for r in range(xi.shape[1]))
        d = np.concatenate(parts, axis=2) if parts else np.zeros((self.n_samples, 3, 0))
        cuts = np.cumsum(self.leg_sizes)[:-1]
        return [np.split(np.ascontiguousarray(d[:, :, r]), cuts) for r in range(n)]

    def injected_leg_means(self, xi: NDArray) -> NDArray:
        """(L, 3, R): the gyro error ``beta_g + n_g`` (body FRD [rad/s]) that the realisations
        made of the standard normals ``xi`` (:meth:`_draw_chunk`'s, in the kernel's order)
        inject, averaged over each leg from its start to its last sample: the truth a
        realisation's flight gyro bias is measured against. As the kernel discretises it
        (:func:`pospp.calib._null_kernel.interval_matrices`: the trapezoid puts an interval's
        driving noise at its two ends, the normals a and b), over an interval of length dt

            int beta_g = c (beta_g(t) + s q_g a_d),  c = tau (1 - exp(-dt / tau)) (dt: no tau),
            int n_g = s ARW (a_w + b_w),  s = sqrt(dt / 2),
            beta_g(t + dt) = exp(-dt / tau) (beta_g(t) + s q_g a_d) + s q_g b_d

        (q_g = sqrt(2 sigma^2 / tau); a_w, a_d the gyro's white and drift rows of a)."""
        dt = np.asarray(self.grid[3], dtype=float)
        g_sample = self.events[2]
        off, rows, _ = self._normal_rows(self.records[3] > 0.0)
        if 6 + rows.sum() != xi.shape[0]:
            raise ValueError(f"xi: expected {6 + rows.sum()} rows, got {xi.shape[0]}")
        cum = kernel.injected_gyro_integrals(
            np.ascontiguousarray(xi, dtype=float), off.astype(np.int64), dt,
            np.ascontiguousarray(self.inj[8] * xi[0:3]), float(self.inj[0]),
            float(self.inj[4]), float(self.inj[6]))
        t_cum = np.concatenate([[0.0], np.cumsum(dt[1:])])
        g_of_j = np.empty(self.n_samples, dtype=np.int64)
        g_of_j[g_sample[g_sample >= 0]] = np.flatnonzero(g_sample >= 0)
        g0 = np.asarray(self.leg_start_grid)
        g1 = g_of_j[np.cumsum(self.leg_sizes) - 1]
        return (cum[g1] - cum[g0]) / (t_cum[g1] - t_cum[g0])[:, None, None]

    def _normal_rows(self, active: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        """Where the kernel reads its normals (:func:`pospp.calib._null_kernel.forward_draws`:
        6 at the start, then per grid point :data:`~pospp.calib._null_kernel.N_NOISE` for its
        interval and one per ``active`` (R, 3) record axis of its node): (first row of each
        grid point's block (G,), rows per block (G,), active axes before each record (R + 1,))."""
        start = self.records[0]
        g_node = self.events[0]
        cnt = np.concatenate([[0], np.cumsum(np.count_nonzero(active, axis=1))]).astype(np.int64)
        per_node = cnt[start[1:]] - cnt[start[:-1]]
        rows = np.where(g_node >= 0, per_node[np.maximum(g_node, 0)], 0)
        rows[1:] += kernel.N_NOISE
        return 6 + np.concatenate([[0], np.cumsum(rows)[:-1]]), rows, cnt

    def _draw_chunk(self, n: int, rng: np.random.Generator, xi: NDArray | None = None,
                    z0: NDArray | None = None) -> NDArray:
        """(J, 3, n) realisations (:meth:`draws`) from ``rng``; ``xi``: the standard normals
        to use instead, ``z0`` (n_z, n) a state added at the start
        (:func:`pospp.calib._null_kernel.forward_draws`)."""
        n_k, n_a = self.records[0].shape[0] - 1, self.lay[0]
        n_j, n_l = self.n_samples, len(self.leg_ids)
        dx = np.empty((n_k, n_a, n))
        eps_s, eb_s = np.empty((n_j, 3, n)), np.empty((n_j, 3, n))
        eps0 = np.empty((n_l, 12, n))
        kernel.forward_draws(self.grid, self.lay, self.inv_tau_a, self.inj, self.events,
                             self.records, n, rng, (dx, eps_s, eb_s, eps0),
                             np.zeros((0, n)) if xi is None else np.ascontiguousarray(xi),
                             np.zeros((0, n)) if z0 is None else np.ascontiguousarray(z0))
        ehat_s, ehat0 = np.zeros_like(eps_s), np.zeros_like(eps0)
        if self.smoother_gains is not None:
            kernel.smooth_draws(self.smoother_gains, dx, self.interp, self.lay[1], ehat_s,
                                ehat0)
        s0 = (eps0 - ehat0)[self.sample_leg]
        return eb_s + np.einsum("jab,jbr->jar", self.psi, s0) - (eps_s - ehat_s)

    def response(self, record_v: NDArray | None = None, accel_b_mps2: NDArray | None = None,
                 phi0_n_rad: NDArray | None = None) -> list[NDArray]:
        """B minus A's response to deterministic errors, legs in id order, each (M, 3, P) NED
        [m/s], for P columns of:

        - ``record_v`` (R, 3, P): per record (:attr:`record_t_s`'s order) the error ``v`` of
          its measurement (measured minus what A's model predicts from the true state; NED m
          for a position, m/s for a velocity): ``dx = K (H e_A - v)`` at each record;
        - ``accel_b_mps2`` (G, 3, P): an accelerometer error at each grid point
          (:attr:`grid_t_s`; body FRD, the sensor reading true plus it), in A's and B's input
          alike, trapezoid over each interval (as the draws' white noise enters);
        - ``phi0_n_rad`` (3, P): A's attitude error at its first node (NED).

        The same linear system as :meth:`draws` (A's gains held, its smoother, B from each
        leg start; module docstring) with these in place of the noise."""
        start, k_rec, h_rec, sig = self.records
        p = next(x.shape[-1] for x in (record_v, accel_b_mps2, phi0_n_rad) if x is not None)
        v = np.zeros((sig.shape[0], 3, p)) if record_v is None else np.asarray(record_v, float)
        if v.shape[:2] != (sig.shape[0], 3):
            raise ValueError(f"record_v: expected ({sig.shape[0]}, 3, P), got {v.shape}")
        on = ((sig > 0.0) | np.any(v != 0.0, axis=2)).astype(float)
        n_on = on.astype(np.int64)
        g_node = self.events[0]
        off, rows, cnt = self._normal_rows(on > 0.0)
        g_of_node = np.full(start.size - 1, -1, dtype=np.int64)
        g_of_node[g_node[g_node >= 0]] = np.flatnonzero(g_node >= 0)
        node = np.searchsorted(start, np.arange(sig.shape[0]), side="right") - 1
        g = g_of_node[node]
        if np.any(g < 0):
            raise ValueError("linear null: a record's node is not a grid point")
        first = off[g] + np.where(g > 0, kernel.N_NOISE, 0) + cnt[:-1] - cnt[start[node]]
        xi = np.zeros((6 + int(rows.sum()), p))
        i_rec, axis = np.nonzero(on)
        xi[first[i_rec] + np.cumsum(n_on, axis=1)[i_rec, axis] - 1] = v[i_rec, axis]
        inj = self.inj.copy()
        if accel_b_mps2 is not None:
            u = np.asarray(accel_b_mps2, dtype=float)
            dt = np.asarray(self.grid[3], dtype=float)[1:, None, None]
            # u dt / 2 at each end of the interval, over the sqrt(dt / 2) Gamma carries
            scale = dt / (2.0 * np.sqrt(0.5 * dt))
            a_rows = off[1:, None] + 3 + np.arange(3)  # the interval's start (a) normals ...
            xi[a_rows] = u[:-1] * scale
            xi[a_rows + kernel.N_IN] = u[1:] * scale  # ... and its end's (b)
            inj[5] = 1.0  # the accelerometer's white-noise scale: xi carries the input
        z0 = None
        if phi0_n_rad is not None:
            z0 = np.zeros((self.lay[0] + 18, p))
            z0[0:3] = np.asarray(phi0_n_rad, dtype=float)
        model = replace(self, records=(start, k_rec, h_rec, on), inj=inj)
        d = model._draw_chunk(p, np.random.default_rng(0), xi, z0)
        return np.split(d, np.cumsum(self.leg_sizes)[:-1])

    def fit_weights(self, leg_ids: Sequence[int], gain: NDArray) -> NDArray:
        """The weights (p, J, 3) of a fit's estimate ``x = gain @ z``, z per leg of
        ``leg_ids`` (in that order) [dv_N, dv_E] at its samples t > 0
        (:attr:`pospp.calib.solve.Calibration.gain`): ``covariance(fit_weights(...))`` is the
        estimate's covariance under this null."""
        g = np.asarray(gain, dtype=float)
        w = np.zeros((g.shape[0], self.n_samples, 3))
        first = np.concatenate([[0], np.cumsum(self.leg_sizes)])
        at = 0
        for lid in leg_ids:
            i = self.leg_ids.index(lid)
            m = self.leg_sizes[i] - 1
            w[:, first[i] + 1:first[i + 1], :2] = g[:, at:at + 2 * m].reshape(-1, m, 2)
            at += 2 * m
        if at != g.shape[1]:
            raise ValueError(f"gain: expected {at} columns for legs {tuple(leg_ids)}, got "
                             f"{g.shape[1]}")
        return w

    def calibration_covariance(self, cal: Calibration) -> NDArray:
        """The covariance of a least-squares calibration's estimate under this null,
        ``G Sigma G^T`` (G: :attr:`pospp.calib.solve.Calibration.gain`, the fit's linear map
        at its fitted variances: the estimator's sandwich), exactly."""
        if cal.gain is None:
            raise ValueError("calibration_covariance: the calibration has no gain")
        return self.covariance(self.fit_weights(cal.leg_ids, cal.gain))

    def _smoother_sources(self) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
        """Where the functionals' sources on the smoother's interpolated estimate land
        (:func:`pospp.calib._null_kernel.smoother_adjoint`'s ``sources``): each sample's and
        leg start's weight ``1 - alpha`` on e^_i^+ and ``alpha`` on e^_i+1^- (as A
        interpolates), sorted by node."""
        s_node, s_alpha, l_node, l_alpha = self.interp
        parts = []
        for kind, node, alpha in ((0, s_node, s_alpha), (1, l_node, l_alpha)):
            idx = np.arange(node.size)
            nxt = alpha > 0.0
            parts.append((node, np.ones(node.size, bool), 1.0 - alpha, kind, idx))
            parts.append((node[nxt] + 1, np.zeros(nxt.sum(), bool), alpha[nxt], kind, idx[nxt]))
        node = np.concatenate([q[0] for q in parts])
        order = np.argsort(node, kind="stable")
        return (node[order].astype(np.int64), np.concatenate([q[1] for q in parts])[order],
                np.concatenate([q[2] for q in parts])[order],
                np.concatenate([np.full(q[0].size, q[3], np.int64) for q in parts])[order],
                np.concatenate([q[4] for q in parts])[order].astype(np.int64))

    def covariance(self, weights: NDArray) -> NDArray:
        """Covariance (p, p) of the p functionals ``sum_j W[:, j, :] d_j`` of a realisation
        (``weights`` (p, J, 3), samples in :meth:`draws`' order, NED velocity), exactly:
        the adjoint of the linear system (module docstring)."""
        w = np.asarray(weights, dtype=float)
        p, n_j = w.shape[0], self.n_samples
        if w.shape[1:] != (n_j, 3):
            raise ValueError(f"weights: expected shape (p, {n_j}, 3), got {w.shape}")
        n_a, i_gm = self.lay[0], self.lay[1]
        n_k = self.records[0].shape[0] - 1
        wj = np.ascontiguousarray(np.transpose(w, (1, 0, 2)))  # (J, p, 3)
        u = np.zeros((len(self.leg_ids), p, 12))
        np.add.at(u, self.sample_leg, np.einsum("jpa,jab->jpb", wj, self.psi))
        u_a = np.zeros((u.shape[0], p, n_a))  # B's start on A's smoothed navigation error
        u_a[:, :, :9] = u[:, :, :9]
        u_a[:, :, I_BA:I_BA + 3] = u[:, :, 9:]
        if i_gm >= 0:
            u_a[:, :, i_gm + 3:i_gm + 6] = u[:, :, 9:]
        mu_dx = np.zeros((n_k, p, n_a))
        if self.smoother_gains is not None:
            kernel.smoother_adjoint(self.smoother_gains, self._smoother_sources(), wj, u_a,
                                    mu_dx)
        meat = np.zeros((p, p))
        kernel.filter_adjoint(self.grid, self.lay, self.inv_tau_a, self.inj, self.events,
                              self.records, wj, u_a, mu_dx, meat)
        return 0.5 * (meat + meat.T)


def linear_null(gains: GainReplay, trajectory: Trajectory, imu_t_s: NDArray, imu_w_b_radps: NDArray,
                imu_f_b_mps2: NDArray, replays: Sequence[LegReplay], noise: NullNoise, *,
                smoothed: bool = True, max_step_s: float = MAX_STEP_S) -> LinearNull:
    """The linear null of one flight (module docstring).

    Parameters
    ----------
    gains : GainReplay
        A's pass recorded with ``record_gains`` (its K, H, nodes, smoother gains, layout).
    trajectory : Trajectory
        A's solution (any epochs covering the pass): the states F is evaluated at.
    imu_t_s, imu_w_b_radps, imu_f_b_mps2 : ndarray, (N,), (N, 3), (N, 3)
        The IMU's epochs [s, A's time axis] and mean rate and specific force over the interval
        ending at each (body FRD).
    replays : sequence of LegReplay
        B's replays in leg-id order: the samples (``t0_s + t_s``) the realisations are made at.
    noise : NullNoise
    smoothed : bool
        B is referenced to A's smoothed solution (else its forward one; ``gains`` then need no
        smoother gains).
    max_step_s : float
        Longest grid interval [s].

    Raises
    ------
    ValueError
        Legs that overlap in time, samples outside A's pass, or smoother gains missing.
    """
    if smoothed and gains.smoother_gains is None:
        raise ValueError("linear null: B references A's smoothed solution, but the pass kept "
                         "no smoother gains")
    t_nodes = np.asarray(gains.t_s, dtype=float)[gains.node_k]
    reps = list(replays)
    t_samp = [r.t0_s + r.t_s for r in reps]
    if any(b[0] < a[-1] for a, b in zip(t_samp, t_samp[1:], strict=False)):
        raise ValueError("linear null: legs overlap in time")
    samples = np.concatenate(t_samp) if reps else np.zeros(0)
    if samples.size and (samples[0] < t_nodes[0] or samples[-1] > gains.t_s[-1]):
        raise ValueError("linear null: samples outside A's pass")
    grid_t, g_node, g_sample = event_grid(t_nodes, samples, max_step_s)
    sizes = [t.size for t in t_samp]
    first = np.concatenate([[0], np.cumsum(sizes)])[:-1].astype(np.int64)
    g_of_j = np.empty(samples.size, dtype=np.int64)
    g_of_j[g_sample[g_sample >= 0]] = np.flatnonzero(g_sample >= 0)
    g_leg = np.full(grid_t.size, -1, dtype=np.int64)
    g_leg[g_of_j[first]] = np.arange(len(reps))
    lay = gains.layout
    n_a = lay.n
    slot_g = lay.i_gm if lay.i_gm >= 0 else I_BG
    slot_a = lay.i_gm + 3 if lay.i_gm >= 0 else I_BA
    ev = interval_means(grid_t, trajectory, imu_t_s, imu_w_b_radps, imu_f_b_mps2)
    s_node, s_alpha = _bracket(t_nodes, samples)
    l_node, l_alpha = _bracket(t_nodes, samples[first])
    leg_end = g_of_j[first + np.asarray(sizes) - 1]
    lay_t = (n_a, lay.i_gm, lay.i_sf, slot_g, slot_a)
    inj = _injected(noise, gains.gm_inv_tau, lay.i_gm >= 0)
    sample_leg = np.repeat(np.arange(len(reps)), sizes).astype(np.int64)
    psi = np.zeros((samples.size, 3, 12))
    events = (g_node, g_leg, g_sample)
    kernel.psi_blocks(ev, lay_t, gains.gm_inv_tau, inj, g_leg, g_sample, leg_end, psi)
    return LinearNull(ev, lay_t, np.asarray(gains.gm_inv_tau, dtype=float), inj, events,
                      _records(gains, noise), gains.smoother_gains if smoothed else None,
                      (s_node, s_alpha, l_node, l_alpha), sample_leg,
                      tuple(r.leg.leg_id for r in reps), tuple(sizes),
                      g_of_j[first], psi, *_record_epochs(gains), grid_t)


def event_grid(t_nodes: NDArray, samples: NDArray, max_step_s: float
          ) -> tuple[NDArray, NDArray, NDArray]:
    """The grid's times (from A's first node) and the node and sample at each point (-1:
    none): A's nodes, the samples, and points filling every gap to at most ``max_step_s``."""
    pts = np.concatenate([t_nodes, samples])
    kind = np.concatenate([np.arange(t_nodes.size), -1 - np.arange(samples.size)])
    order = np.argsort(pts, kind="stable")
    pts, kind = pts[order], kind[order]
    new = np.concatenate([[True], np.diff(pts) > _SAME_S])
    idx = np.cumsum(new) - 1
    t = pts[new]
    g_node = np.full(t.size, -1, dtype=np.int64)
    g_sample = np.full(t.size, -1, dtype=np.int64)
    g_node[idx[kind >= 0]] = kind[kind >= 0]
    if np.any(np.bincount(idx[kind < 0], minlength=t.size) > 1):
        raise ValueError("linear null: two samples at one time (legs overlap)")
    g_sample[idx[kind < 0]] = -1 - kind[kind < 0]
    extra = np.ceil(np.diff(t) / max_step_s - 1e-9).astype(np.int64) - 1
    if np.any(extra > 0):
        fill = np.concatenate([t[i] + (t[i + 1] - t[i]) * np.arange(1, e + 1) / (e + 1)
                               for i, e in enumerate(extra) if e > 0])
        at = np.searchsorted(t, fill)
        t = np.insert(t, at, fill)
        g_node = np.insert(g_node, at, -1)
        g_sample = np.insert(g_sample, at, -1)
    return t, g_node, g_sample


def _bracket(t_nodes: NDArray, t: NDArray) -> tuple[NDArray, NDArray]:
    """Node i (last at or before t) and weight towards node i + 1, as A interpolates its
    smoothed error (:func:`pospp.nav.smoother.interpolation_weights`)."""
    i = np.clip(np.searchsorted(t_nodes, t + _SAME_S, side="right") - 1, 0, t_nodes.size - 1)
    nxt = np.minimum(i + 1, t_nodes.size - 1)
    span = t_nodes[nxt] - t_nodes[i]
    alpha = np.where(span > 0.0, (t - t_nodes[i]) / np.where(span > 0.0, span, 1.0), 0.0)
    return i.astype(np.int64), np.clip(alpha, 0.0, 1.0)


def interval_means(grid_t: NDArray, trajectory: Trajectory, t_s: NDArray, w: NDArray,
                    f: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """(kernel states at the grid points, mean specific force and rate over the interval
    ending at each (row 0: at its start), interval lengths): the IMU's rates integrated
    exactly (piecewise constant over their intervals)."""
    traj = interpolate_trajectory(trajectory, grid_t)
    xs = np.column_stack([traj.lat_rad, traj.lon_rad, traj.height_m, traj.v_n_mps,
                          traj.q_nb])
    t_s = np.asarray(t_s, dtype=float)
    means = []
    for rate in (f, w):
        at = _running_integrals(grid_t, t_s, np.asarray(rate))
        dt = np.diff(grid_t)
        m = np.empty((grid_t.size, 3))
        m[1:] = np.diff(at, axis=0) / dt[:, None]
        m[0] = m[1] if grid_t.size > 1 else 0.0
        means.append(np.ascontiguousarray(m))
    dts = np.concatenate([[0.0], np.diff(grid_t)])
    return np.ascontiguousarray(xs), means[0], means[1], dts


def _running_integrals(grid_t: NDArray, t_s: NDArray, rate: NDArray,
                       block: int = 65536) -> NDArray:
    """The integral (G, 3) of ``rate`` (N, 3), constant over each interval ending at its
    sample, from ``t_s[0]`` to each of ``grid_t`` (linear between the samples, held beyond
    them): the samples' running sum interpolated, ``block`` samples at a time (not the whole
    (N, 3) sum at once). Each block starts from the last one's end, so the sums are those of
    one running sum, bit for bit."""
    out = np.empty((grid_t.size, 3))
    n, g0, carry = t_s.size, 0, np.zeros(3)
    for s in range(0, n, block):
        e, a = min(s + block, n), max(s - 1, 0)  # new samples s .. e - 1 after sample a
        cum = np.empty((e - a, 3))
        cum[0] = carry
        np.multiply(rate[a + 1:e], np.diff(t_s[a:e])[:, None], out=cum[1:])
        np.cumsum(cum, axis=0, out=cum)
        g1 = grid_t.size if e == n else int(np.searchsorted(grid_t, t_s[e - 1], side="right"))
        for c in range(3):
            out[g0:g1, c] = np.interp(grid_t[g0:g1], t_s[a:e], cum[:, c])
        g0, carry = g1, cum[-1]
    return out


def _used(gains: GainReplay) -> NDArray:
    """Which of A's records the model holds: used (or used at a covariance reset) from its
    first node on."""
    st = np.asarray(gains.status)
    return ((st == STATUS_USED) | (st == STATUS_RESET)) & (gains.meas_k >= gains.node_k[0])


def _record_epochs(gains: GainReplay) -> tuple[NDArray, NDArray]:
    """(epoch [s], kind) of each record the model holds, in its order."""
    used = _used(gains)
    return (np.asarray(gains.t_s, dtype=float)[np.asarray(gains.meas_k)[used]],
            np.asarray(gains.meas_kind)[used])


def _records(gains: GainReplay, noise: NullNoise
             ) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """A's records used from its first node on: (first record of each node, K, H, the
    injected noise's sigma per NED axis: GNSS position, velocity; none for a ZUPT)."""
    used = _used(gains)
    k = np.asarray(gains.meas_k)[used]
    node = np.searchsorted(gains.node_k, k)
    if np.any(node >= gains.node_k.size) or np.any(gains.node_k[np.minimum(
            node, gains.node_k.size - 1)] != k):
        raise ValueError("linear null: a record's epoch is not a smoother node")
    kind = np.asarray(gains.meas_kind)[used]
    sig = np.zeros((k.size, 3))
    sig[kind == 0] = np.asarray(noise.pos_sigma_ned_m, dtype=float)
    sig[kind == 1] = np.asarray(noise.vel_sigma_ned_mps, dtype=float)
    start = np.searchsorted(node, np.arange(gains.node_k.size + 1)).astype(np.int64)
    return (start, np.ascontiguousarray(gains.gains[used]), np.ascontiguousarray(gains.h[used]),
            sig)


def _injected(noise: NullNoise, gm_inv_tau: NDArray, with_gm: bool) -> NDArray:
    """:mod:`pospp.calib._null_kernel`'s ``inj`` from the noise and A's model of its drifts."""
    out = np.zeros(10)
    for i, (sigma, tau) in enumerate(((noise.gyro_gm_sigma_radps, noise.gyro_gm_tau_s),
                                      (noise.accel_gm_sigma_mps2, noise.accel_gm_tau_s))):
        inv = 0.0 if not np.isfinite(tau) else 1.0 / float(tau)
        out[i] = inv
        out[2 + i] = -inv + (float(gm_inv_tau[i]) if with_gm else 0.0)
        out[6 + i] = float(np.sqrt(2.0 * sigma**2 * inv))
        out[8 + i] = float(sigma)
    out[4] = noise.gyro_arw_radpsqrts
    out[5] = noise.accel_vrw_mpspsqrts
    return out
