"""A's GNSS innovations' linear response to changes of its IMU input, all columns in one pass.

Frames NED (n) and FRD body (b), SI, errors computed minus unperturbed (the convention of
:mod:`pospp.nav.error_model`). A pass of A that replays its recorded gains
(:class:`pospp.nav.filter_state.GainReplay`: K fixed) is, to first order in a small change
``u(t)`` of its IMU samples, a linear time-varying system in u. Each column j of the
perturbation (a gyro change ``u_g,j(t)`` [rad/s] and an accelerometer change ``u_a,j(t)``
[m/s^2], body FRD, per SI coefficient) drives A's closed-loop error e (A's n_a states) as::

    between records:  e' = F_A(t) e + [-C_nb u_g,j ; C_nb u_a,j ; 0]     (rows phi, dv)
    at a record i:    dnu_i,j = H_i e^-,   e <- (I - K_i H_i) e^-

F_A A's own F (:func:`pospp.nav._filter_kernel.fill_extended_f`) along A's solution, K_i and
H_i the recorded gain and measurement matrix of every record A used (or reset with), in its
order within an epoch; dnu the change of the innovation (predicted minus measured, NED [m]
or [m/s]). The input enters as a sensor bias does (measured = true + bias: the gyro's into
the attitude error through -C_nb, the accelerometer's into the velocity error through C_nb;
the error's bias states hold minus the change of A's bias estimate, fed back as A does), so
the columns are exactly what re-running A with ``u`` added to its samples and the gains
replayed gives, less the unperturbed replay, to first order.

Start. e is zero at A's first epoch but for its attitude after a static alignment: A levels
and gyrocompasses with the mean rate and specific force over its static period, so a
column's mean over that period ``(du_g, du_a)`` gives ``phi_0 = J [du_g; du_a]``, J the
alignment's Jacobian (:func:`pospp.nav.alignment.static_attitude_jacobian`). An in-motion
alignment takes its attitude from GNSS alone: no response.

Discretisation. A grid holds A's record epochs, the caller's break points (the hinge knots)
and points at most ``max_step_s`` apart (:func:`pospp.calib.linear_null.event_grid`). Over
an interval [t0, t1] of length h, with F held at A's state at the interval's midpoint and
the mean specific force and rate over it (:func:`pospp.calib.linear_null.interval_means`)::

    e(t1) = expm(F h) e(t0) + D0 + F D1,  D0 = int b ds,  D1 = int (t1 - s) b ds

(b the input in the error's phi and dv rows; ``expm`` to fourth order), D0 and D1 by
Simpson's rule on b at t0, the midpoint and t1 (exact for an input and an attitude linear
over the interval: a hinge between knots). F at the midpoint is second order in h; held at
the interval's end, as the linear null holds it, it lags A's attitude in the turns by h / 2,
and the hinge columns were 1-8 % off the replays at h = 1 s.

Against the replays it stands for (A re-run with ``u`` added to its samples and its gains
replayed, less the unperturbed replay; tests/unit/test_innovation_response.py), each column
whitened by A's S^-1 over the records the diagnosis fits is within 0.1-1.2 % of its norm on
flight_accel_ramp_100hz (1 Hz GNSS, 50 Hz IMU, h = 1 s). What it leaves out, the sources of
that rest: the full filter before the replay's epoch ``k_from`` (the perturbed pass's own
gains there differ from the recorded ones at first order in u times the innovation: the
columns acting from the first knot carry most of it, 0.7-1.2 %), A's gate in the replay (a
record the base pass used and the perturbed pass gates: none at the catalogue's plausible
sizes), the static alignment's position through the lever arm, the lever-arm term of a gyro
change in a velocity record's prediction (``-C [l x] u_g``: 1 m x u against the attitude's
growing effect), and second-order terms (between one and a tenth of the catalogue's
plausible size the replays' columns move by 0.03 % of their norm for the hinges, up to
0.6 % for the gravity terms).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from pospp import rotation
from pospp.calib._null_kernel import expm4
from pospp.calib.linear_null import MAX_STEP_S, event_grid, interval_means
from pospp.nav._filter_kernel import STATUS_RESET, STATUS_USED, fill_extended_f
from pospp.nav.alignment import static_attitude_jacobian
from pospp.nav.filter_state import GainReplay
from pospp.nav.strapdown import Trajectory, interpolate_trajectory
from pospp.threads import map_in_threads

BodyInput = Callable[[NDArray, NDArray], NDArray]
"""``(t_s (T,), C_nb (T, 3, 3)) -> (T, 6, m)``: the m columns' gyro change (rows 0-2,
[rad/s]) and accelerometer change (rows 3-5, [m/s^2]), body FRD, per SI coefficient, at
times ``t_s`` [s, A's time axis] where A's attitude is ``C_nb``."""


@njit(cache=True, nogil=True)
def propagate_columns(grid, i_gm, i_sf, inv_tau, g_node, records, e0, d0, d1, dnu):
    """The forward pass of the m columns (module docstring). ``grid = (xs (G, 10), fm (G, 3),
    wm (G, 3), dt (G,))`` (:func:`pospp.calib.linear_null.interval_means`); ``g_node`` (G,)
    the record epoch at each grid point (-1 none); ``records = (rec_start (E + 1,), K (M,
    n_a, 3), H (M, 3, n_a), at (R,), row0, v (R or 0, 3, m))`` the R records of each epoch
    in order as indices ``at`` into A's M records' K and H, their rows ``at - row0`` in
    ``dnu``, and the change of what each measures (none: zero); ``e0``
    (n_a, m) the error at the first point; ``d0``, ``d1`` (G, 6, m) the input's integrals
    over the interval ending at each point (row 0 unused); ``dnu`` (., 3, m) receives each
    record's innovation change in its row. Returns the error after the last point's records
    (n_a, m): the next stretch of the grid continues from it."""
    xs, fms, wms, dts = grid
    rec_start, rec_k, rec_h, rec_at, row0, rec_v = records
    n_a = rec_k.shape[1]
    e = e0.copy()
    fa, ft, phi = np.empty((n_a, n_a)), np.empty((n_a, n_a)), np.empty((n_a, n_a))
    w1, w2 = np.empty((n_a, n_a)), np.empty((n_a, n_a))
    c_nb = np.empty((3, 3))
    for g in range(xs.shape[0]):
        if g > 0:
            fill_extended_f(xs[g], fms[g], wms[g], i_gm, i_sf, inv_tau, c_nb, fa)
            for a in range(n_a):
                for b in range(n_a):
                    ft[a, b] = fa[a, b] * dts[g]
            expm4(ft, phi, w1, w2)
            e = np.dot(phi, e) + np.dot(np.ascontiguousarray(fa[:, :6]), d1[g])
            e[:6] += d0[g]
        node = g_node[g]
        if node >= 0:
            for i in range(rec_start[node], rec_start[node + 1]):
                j = rec_at[i]
                nu = np.dot(rec_h[j], e)
                if rec_v.shape[0]:
                    nu -= rec_v[i]
                dnu[j - row0] = nu
                e -= np.dot(rec_k[j], nu)
    return e


def innovation_responses(gains: GainReplay, trajectory: Trajectory, imu_t_s: NDArray,
                         imu_w_b_radps: NDArray, imu_f_b_mps2: NDArray, body_input: BodyInput,
                         *, breaks_s: NDArray | None = None,
                         static_window_s: tuple[float, float] | None = None,
                         max_step_s: float = MAX_STEP_S,
                         record_v: NDArray | None = None) -> NDArray:
    """The change of each of A's innovations per unit of each input column (module
    docstring).

    Parameters
    ----------
    gains : GainReplay
        A's pass recorded with ``record_gains`` (its K, H, record status, layout).
    trajectory : Trajectory
        A's solution (any epochs covering the pass): where F and C_nb are evaluated.
    imu_t_s, imu_w_b_radps, imu_f_b_mps2 : ndarray, (N,), (N, 3), (N, 3)
        The IMU's epochs [s, A's time axis] and mean rate and specific force over the interval
        ending at each (body FRD): the pass's samples.
    body_input : BodyInput
        The m columns' body-frame gyro and accelerometer change at given times.
    breaks_s : ndarray, optional
        Times [s] where an input is not smooth (hinge knots): put on the grid.
    static_window_s : (float, float), optional
        The period (t0, t1] [s] whose mean rate and specific force A's static alignment
        levelled and gyrocompassed with (:func:`pospp.nav.alignment.align`): the columns'
        mean over it tilts and turns A's initial attitude
        (:func:`pospp.nav.alignment.static_attitude_jacobian`). None: an in-motion
        alignment, which the IMU does not move.
    max_step_s : float
        Longest grid interval [s].
    record_v : ndarray, (M, 3, m), optional
        Per record of ``gains``, the change of what it measures per SI coefficient of each
        column (measured minus A's prediction from the true state, NED [m] or [m/s]): its
        innovation moves by ``-v`` besides ``H e`` (a GNSS-side change: a time offset, a lever
        arm), and A's feedback carries it on.

    Returns
    -------
    ndarray, (M, 3, m)
        Per record of ``gains`` (its order), the innovation's change (NED [m] for a position
        record, [m/s] for a velocity one) per SI coefficient of each column; zero for the
        records A did not use.
    """
    return ResponseSystem.of(gains, trajectory, imu_t_s, imu_w_b_radps, imu_f_b_mps2,
                             breaks_s=breaks_s, max_step_s=max_step_s).responses(
        body_input, static_window_s=static_window_s, record_v=record_v)


@dataclass(frozen=True)
class ResponseSystem:
    """A's closed-loop error system along its pass on the event grid (:func:`innovation_
    responses`' arguments but the columns'): made once, it gives the responses to any
    columns on the same breaks (each family's, a GNSS-side column's)."""

    gains: GainReplay
    trajectory: Trajectory
    imu: tuple[NDArray, NDArray, NDArray]
    """The IMU's epochs [s], mean rate [rad/s] and specific force [m/s^2], body FRD."""
    breaks_s: NDArray
    max_step_s: float
    grid_t: NDArray
    g_node: NDArray
    means: tuple[NDArray, NDArray, NDArray, NDArray]
    """Per grid point A's kernel state at the interval's middle, the mean specific force and
    rate over it and its length (:func:`pospp.calib.linear_null.interval_means`)."""
    applied: NDArray
    """The records A used or reset with from its first epoch (indices into ``gains``)."""
    rec_start: NDArray

    @classmethod
    def of(cls, gains: GainReplay, trajectory: Trajectory, imu_t_s: NDArray,
           imu_w_b_radps: NDArray, imu_f_b_mps2: NDArray, *,
           breaks_s: NDArray | None = None, max_step_s: float = MAX_STEP_S
           ) -> ResponseSystem:
        st = np.asarray(gains.status)
        applied = np.flatnonzero(((st == STATUS_USED) | (st == STATUS_RESET))
                                 & (gains.meas_k >= gains.k_start))
        t0 = float(gains.t_s[gains.k_start])
        t_rec = np.asarray(gains.t_s)[gains.meas_k[applied]]
        t_nodes = np.unique(np.concatenate([[t0], t_rec]))
        breaks = np.zeros(0) if breaks_s is None else np.asarray(breaks_s, dtype=float)
        breaks = np.unique(breaks[(breaks > t0) & (breaks < t_nodes[-1])])
        grid_t, g_node, _ = event_grid(t_nodes, breaks, max_step_s)
        xs, fm, wm, dts = interval_means(grid_t, trajectory, imu_t_s, imu_w_b_radps,
                                         imu_f_b_mps2)
        xs[1:] = _kernel_states(trajectory, 0.5 * (grid_t[1:] + grid_t[:-1]))
        node_of_rec = np.searchsorted(t_nodes, t_rec)
        rec_start = np.searchsorted(node_of_rec, np.arange(t_nodes.size + 1)).astype(np.int64)
        return cls(gains, trajectory, (imu_t_s, imu_w_b_radps, imu_f_b_mps2), breaks,
                   max_step_s, grid_t, g_node, (xs, fm, wm, dts), applied, rec_start)

    def responses(self, body_input: BodyInput, *,
                  static_window_s: tuple[float, float] | None = None,
                  record_v: NDArray | None = None) -> NDArray:
        """:func:`innovation_responses` of the columns ``body_input`` (and ``record_v``)."""
        m = np.shape(body_input(self.grid_t[:1], np.eye(3)[None]))[2]
        out = np.zeros((np.size(self.gains.status), 3, m))  # zero for the records A did not use
        for row, dnu in self.blocks((body_input,), static_window_s=static_window_s,
                                    record_v=record_v):
            out[row:row + dnu.shape[0]] = dnu
        return out

    def blocks(self, body_inputs: Sequence[BodyInput], *,
               static_window_s: tuple[float, float] | None = None,
               record_v: NDArray | None = None, threads: int = 1
               ) -> Iterator[tuple[int, NDArray]]:
        """:func:`innovation_responses` of every input's columns side by side, a stretch of
        the grid at a time: per stretch ``(row, dnu)``, the changes (R, 3, m) of the records in
        rows ``row .. row + R`` of ``gains`` (zero for those A did not use; m the inputs'
        columns together, in their order). Each stretch's input integrals are made for it
        alone (the whole grid's are (G, 6, m) twice), and what a caller keeps of the changes
        is its choice (:func:`pospp.sensor_stage.innovation_design` keeps their Gram matrix).
        ``threads``: the inputs' passes over a stretch made at once (each its own columns;
        the result does not depend on it). ``record_v``: :func:`innovation_responses`', with
        one input."""
        gains, applied, grid_t = self.gains, self.applied, self.grid_t
        lay = gains.layout
        k_all, h_all = (np.ascontiguousarray(gains.gains, dtype=float),
                        np.ascontiguousarray(gains.h, dtype=float))
        v = (np.zeros((0, 3, 0)) if record_v is None
             else np.ascontiguousarray(np.asarray(record_v, dtype=float)[applied]))
        states = []
        for body_input in body_inputs:
            e = np.zeros((lay.n, np.shape(body_input(grid_t[:1], np.eye(3)[None]))[2]))
            if static_window_s is not None:
                e[:3] = _alignment_response(static_window_s, *self.imu, self.trajectory,
                                            body_input, self.breaks_s, self.max_step_s)
            states.append(e)
        xs, fm, wm, dts = self.means
        inv_tau = np.asarray(gains.gm_inv_tau, dtype=float)
        # a stretch starts at the last one's end point, whose records the last one applied
        for a in range(0, max(grid_t.size - 1, 1), _STRETCH):
            b = min(a + 1 + _STRETCH, grid_t.size)
            nodes = self.g_node[a:b].copy()
            nodes[0] = nodes[0] if a == 0 else -1
            at = nodes[nodes >= 0]
            first, last = ((self.rec_start[at[0]], self.rec_start[at[-1] + 1]) if at.size
                           else (0, 0))
            row = int(applied[first]) if last > first else 0
            n_rows = int(applied[last - 1]) + 1 - row if last > first else 0
            records = (self.rec_start, k_all, h_all, applied, row, v)

            def stretch(j: int, a: int = a, b: int = b, nodes: NDArray = nodes,
                        records: tuple = records, n_rows: int = n_rows) -> NDArray:
                d0, d1 = _input_integrals(grid_t[a:b], self.trajectory, body_inputs[j])
                dnu = np.zeros((n_rows, 3, states[j].shape[1]))
                states[j] = propagate_columns((xs[a:b], fm[a:b], wm[a:b], dts[a:b]),
                                              lay.i_gm, lay.i_sf, inv_tau, nodes, records,
                                              states[j], d0, d1, dnu)
                return dnu

            parts = map_in_threads(stretch, range(len(body_inputs)), threads)
            yield row, parts[0] if len(parts) == 1 else np.concatenate(parts, axis=2)


def _alignment_response(window_s: tuple[float, float], imu_t_s: NDArray, imu_w: NDArray,
                        imu_f: NDArray, trajectory: Trajectory, body_input: BodyInput,
                        breaks_s: NDArray, max_step_s: float) -> NDArray:
    """A's initial attitude error per column (3, m) [rad NED]: the static alignment's
    Jacobian at the window's mean rate and specific force times the columns' mean over the
    window (trapezoid over points at most ``max_step_s`` apart and the breaks in it)."""
    t0, t1 = window_s
    sel = (imu_t_s > t0) & (imu_t_s <= t1)
    jac = static_attitude_jacobian(np.asarray(imu_w)[sel].mean(axis=0),
                                   np.asarray(imu_f)[sel].mean(axis=0))
    n = int(np.ceil((t1 - t0) / max_step_s)) + 1
    pts = np.union1d(np.linspace(t0, t1, n), breaks_s[(breaks_s > t0) & (breaks_s < t1)])
    u = np.asarray(body_input(pts, rotation.dcm_from_quat(
        interpolate_trajectory(trajectory, pts).q_nb)), dtype=float)
    return jac @ (np.trapezoid(u, pts, axis=0) / (t1 - t0))


def _kernel_states(trajectory: Trajectory, t_s: NDArray) -> NDArray:
    """A's kernel states (T, 10) (:mod:`pospp.nav._kernels` layout) at ``t_s``."""
    tr = interpolate_trajectory(trajectory, t_s)
    return np.column_stack([tr.lat_rad, tr.lon_rad, tr.height_m, tr.v_n_mps, tr.q_nb])


_STRETCH = 128
"""Grid intervals propagated at once, their input integrals in memory (128 x 6 x m doubles
twice, and the inputs at three points per interval while they are made: 1.2 and 3.7 MiB per
family at m = 198, a 1.5 h flight's hinges on two axes; a family per thread)."""
_CHUNK = 512
"""Grid intervals whose input integrals are made at once (their inputs at three points each:
512 x 3 x 6 x m doubles, 10 MB at m = 140)."""
_INSIDE_S = 1e-6
"""How far inside its interval an end is evaluated [s] (a hinge moves by its slope times
this: 3e-10 of an hour)."""


def _input_integrals(grid_t: NDArray, trajectory: Trajectory, body_input: BodyInput
                     ) -> tuple[NDArray, NDArray]:
    """``D0 = int b ds``, ``D1 = int (t1 - s) b ds`` (G, 6, m) over the interval ending at
    each grid point (row 0 zero), b = [-C_nb u_g; C_nb u_a] the input in the error's phi and
    dv rows, by Simpson's rule (module docstring), :data:`_CHUNK` intervals at a time (the
    input at three points per interval is the largest array). Each interval's ends are
    evaluated just inside it (:data:`_INSIDE_S`), so that an input with a jump at a grid point
    (a step) is integrated exactly, its value before the jump in the interval that ends
    there."""
    g = grid_t.size
    d0 = d1 = np.zeros((g, 6, 0))
    for a in range(0, g - 1, _CHUNK):
        t0, t1 = grid_t[a:a + _CHUNK], grid_t[a + 1:a + 1 + _CHUNK]
        t0 = t0[:t1.size]
        t_all = np.concatenate([t0 + _INSIDE_S, t1 - _INSIDE_S, 0.5 * (t0 + t1)])
        c_nb = rotation.dcm_from_quat(interpolate_trajectory(trajectory, t_all).q_nb)
        u = np.asarray(body_input(t_all, c_nb), dtype=float)
        b = np.empty((t_all.size, 6, u.shape[2]))  # in place: each temporary is as large as u
        np.einsum("tij,tjm->tim", c_nb, u[:, 0:3], out=b[:, 0:3])
        np.negative(b[:, 0:3], out=b[:, 0:3])
        np.einsum("tij,tjm->tim", c_nb, u[:, 3:6], out=b[:, 3:6])
        del u
        if not d0.shape[2]:
            d0 = np.zeros((g, 6, np.shape(b)[2]))
            d1 = np.zeros_like(d0)
        k = t1.size
        h = (t1 - t0)[:, None, None]
        b0, b1, bm = b[:k], b[k:2 * k], b[2 * k:]
        s0, s1 = d0[a + 1:a + 1 + k], d1[a + 1:a + 1 + k]
        np.multiply(bm, 4.0, out=s0)  # h / 6 (b0 + 4 bm + b1)
        s0 += b0
        s0 += b1
        s0 *= h / 6.0
        np.multiply(bm, 2.0, out=s1)  # h^2 / 6 (b0 + 2 bm)
        s1 += b0
        s1 *= h * h / 6.0
    return d0, d1
