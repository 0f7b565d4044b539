"""The antenna lever arm and the GNSS time offset estimated jointly (arrays in, a frozen
:class:`LeverTime` out; no I/O).

Frames and units: body FRD lever arms [m]; ``tau_s`` is the GNSS stamp minus the true time of
the record [s] (positive: the GNSS records are stamped late, the GNSS lags the IMU); the
catalogue's ``time_offset`` (:mod:`pospp.effects_catalog`, IMU time tag minus GNSS time) is
``-tau_s``.

Why jointly. A record stamped tau late shows the antenna where it was tau earlier:
``r_a(t - tau) = r_a(t) - v tau`` and ``v_a(t - tau) = v_a(t) - a tau``. A forward lever arm
l_x puts the antenna at ``r + C_nb l`` with velocity ``v + C_nb (w x l)``. At a constant speed
v along the body x axis (straight legs, coordinated turns, steady climbs) both are the same
error with ``l_x = -v tau``: the flight determines only the *apparent* forward lever arm
``l_x - v tau`` (= forward lever arm + v x time offset, in the catalogue's sign). What tells
them apart is what changes the speed and not the attitude, or the reverse: the take-off roll,
the landing, legs flown at other speeds, static periods (a lever arm stays, a time offset
vanishes at rest).

How. Algorithm A's forward pass with lever-arm states (the QC stage's,
:func:`pospp.flight_stages.lever_arm_passes`, a wide gate) is run on the log with the GNSS
records re-stamped by ``t - s`` for trial offsets s on the IMU grid, each pass started where
the lever arm is expected at s (:func:`pospp.lever_time_stage.lever_time_pass`); each pass's
lever arm is l(s), its fit to the GNSS records J(s) = sum of their NIS (each record's
innovation against the pass's own covariance, capped at the gate; the records all passes
processed). J is -2 log L of the offset with the lever arm profiled out: its minimum is
walked to in steps of ``LEVER_TIME_STEP_S``, and the least-squares parabola through the
lowest and two steps either side gives tau and its sigma (Delta J = 1, scaled by the reduced
chi-square at the minimum when above 1: a receiver noisier than it reports; and by the
long-run variance ratio of the pass's whitened innovations: a coloured, time-correlated,
GNSS error; the parabola's own fit error added). The lever arm at tau is l interpolated at
tau; its sigma at a known offset is the pass's own (times the same sqrt of the reduced
chi-square when above 1 and of the long-run variance ratio; the apparent lever arm's
likewise, with the ratio of the pass nearest tau: at 0 an offset left out colours the
innovations itself), and with tau's uncertainty
``var l_i = sigma_l,i^2 + (dl_i / d tau)^2 sigma_tau^2``,
``corr(l_i, tau) = (dl_i / d tau) sigma_tau / sd(l_i)``.

Why the long-run variance ratio. A's passes take the records as independent; the reduced
chi-square corrects their level, not their independence. A Gauss-Markov GNSS position error
(0.342 m over 60 s in the Monte Carlo, docs/compare_sim.md) leaves A's innovations
correlated over tens of seconds, so the records carry fewer independent looks at the lever
arm and the offset than their number: both estimates sum the innovations with weights that
change only in the turns and speed changes, and their variance is the white formula's times
the innovations' long-run variance ratio (:func:`pospp.distributions.long_run_ratio`, over
``LEVER_TIME_COLOUR_WINDOW_S``; 1 for white innovations). A draw of a coloured error then
reads as a lever arm of a few of its widened sigmas, not of 7-15 of the passes' own.

Two readings are tested against the joint estimate: *all lever arm* (tau = 0) and *all time
offset* (the lever arm as configured, tau_b where l_x(tau_b) is the configured x). Both lie on
the line l(tau), where the joint estimate's chi-square is ((tau - tau_hat) / sigma_tau)^2: a
reading is rejected beyond ``SEPARATION_SIGMAS``. Neither rejected while the apparent lever
arm differs from the configured one: the flight cannot separate them, and the combination it
determines is stated with both readings.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pospp.distributions import long_run_ratio
from pospp.nav.filter import STATUS_GATED, STATUS_RESET, STATUS_USED, FilterResult

__all__ = ["LEVER_TIME_COLOUR_WINDOW_S", "LEVER_TIME_STEP_S", "LeverPass", "LeverTime",
           "innovation_lrv_ratio", "lever_pass", "lever_time_joint", "lever_time_verdict"]

LEVER_TIME_STEP_S = 0.01
"""Step of the trial offsets [s] (rounded to whole IMU intervals): 0.6 m along the track at
60 m/s, which moves J by about 100 near its minimum on a 45 min flight (flight_time_offset_200hz),
far above the passes' rounding."""
LEVER_TIME_COLOUR_WINDOW_S = 60.0
"""The window of the innovations' long-run variance ratio [s]
(:func:`pospp.distributions.long_run_ratio` with the Gauss-Markov + white model's
autocorrelation): the scale over which the lever arm's response changes (a 180 deg turn at
3 deg/s takes 60 s) and the offset's (a take-off roll, 40 s). Measured ratios: docs/decisions.md
"The joint lever-arm estimate's sigmas widened by its innovations' colour"."""
LEVER_TIME_START_PASSES = 2
LEVER_TIME_START_STEP_M = 0.1
"""The pass at offset 0 is made again from its own estimate, at most
``LEVER_TIME_START_PASSES`` times, while that moves more than this from where it started
(a 3 m lever-arm error read 1.78 m after one pass: docs/diagnose.md, "Power")."""
LEVER_TIME_MAX_PASSES = 12
"""Passes of A the joint estimate makes at most (each about a third of A's time)."""
SEPARATION_SIGMAS = 3.0
"""A reading (all lever arm, all time offset) is rejected when the joint estimate lies more than
this many of tau's sigmas from it."""
TIME_OFFSET_FLOOR_S = 0.002
"""The practical floor of a GNSS time offset [s]: below 2 ms (12 cm at 60 m/s, under the
noise of most receivers' positions) an offset is not worth a word."""
LEVER_ARM_FLOOR_M = 0.2
"""The practical floor of a lever-arm error [m] (the ``lever_arm`` check's: with one 180 deg
turn, A's lever-arm sigma is optimistic by about 3, docs/qc.md)."""


@dataclass(frozen=True)
class LeverPass:
    """One pass of A with lever-arm states on the log with its GNSS re-stamped ``t - shift_s``.

    Attributes
    ----------
    shift_s : float
        The trial offset (GNSS stamp minus true time) [s].
    lever_b_m, sigma_b_m : (3,) the pass's lever-arm estimate and 1-sigma, body FRD [m]
    record_key : (M,) int64
        Each processed GNSS record's identity: its kind (0 position, 1 velocity) x 2^62 plus
        its *unshifted* stamp [ms], so that the passes' records can be matched.
    nis : (M,) float
        Each record's NIS against the pass's covariance (3 dof), capped at the pass's gate.
    lrv_ratio : float
        The long-run variance ratio of the pass's whitened innovations (module docstring;
        at least 1).
    """

    shift_s: float
    lever_b_m: NDArray
    sigma_b_m: NDArray
    record_key: NDArray
    nis: NDArray
    lrv_ratio: float = 1.0


@dataclass(frozen=True)
class LeverTime:
    """The joint estimate (module docstring).

    Attributes
    ----------
    tau_s, sigma_tau_s : GNSS stamp minus true time and its 1-sigma [s] (sigma inf: the
        flight does not determine it)
    lever_b_m : (3,) lever arm at tau [m]; ``sigma_lever_b_m`` its 1-sigma with tau's
        uncertainty; ``sigma_lever_given_tau_b_m`` at a known offset
    apparent_lever_b_m : (3,) the lever arm at tau = 0 (what A reads when the offset is not
        modelled: forward lever arm + v x time offset) and ``sigma_apparent_b_m``
    dlever_dtau_mps : (3,) d l / d tau [m/s] (about the speed, along x)
    correlation : (3,) corr(l_i, tau)
    configured_b_m : (3,) the configured lever arm
    tau_lever_only_s : float
        tau_b: the offset that alone explains the apparent forward lever arm (the lever arm
        as configured).
    chi2_reduced : float
        J / (3 n) at the minimum (1 when the records' sigmas are right; where the offset is
        not determined, the pass at 0's).
    n_records : int
    lrv_ratio : float
        The innovations' long-run variance ratio that widened the sigmas (the pass nearest
        tau's; 1 when they are white).
    """

    tau_s: float
    sigma_tau_s: float
    lever_b_m: NDArray
    sigma_lever_b_m: NDArray
    sigma_lever_given_tau_b_m: NDArray
    apparent_lever_b_m: NDArray
    sigma_apparent_b_m: NDArray
    dlever_dtau_mps: NDArray
    correlation: NDArray
    configured_b_m: NDArray
    tau_lever_only_s: float
    chi2_reduced: float
    n_records: int
    lrv_ratio: float = 1.0

    @property
    def speed_mps(self) -> float:
        """The speed that converts the offset into a forward lever arm: dl_x / d tau."""
        return float(self.dlever_dtau_mps[0])

    def z_lever_only(self) -> float:
        """How many of tau's sigmas the *all lever arm* reading (tau = 0) lies from tau."""
        return abs(self.tau_s) / self.sigma_tau_s if self.sigma_tau_s > 0 else math.inf

    def z_time_only(self) -> float:
        """How many of tau's sigmas the *all time offset* reading lies from tau."""
        if not math.isfinite(self.tau_lever_only_s):
            return math.inf
        return (abs(self.tau_lever_only_s - self.tau_s) / self.sigma_tau_s
                if self.sigma_tau_s > 0 else math.inf)


def lever_pass(nav: FilterResult, shift_s: float) -> LeverPass:
    """The :class:`LeverPass` of A's pass ``nav`` with lever-arm states on the log re-stamped
    by ``shift_s``: its lever-arm estimate and each GNSS position and velocity record it
    processed (used, gated or used after a reset) with its NIS capped at the gate, keyed by
    its unshifted stamp; the long-run variance ratio of its innovations
    (:func:`innovation_lrv_ratio`). ValueError when the pass recorded no innovations."""
    rec = nav.innovations
    if rec is None:
        raise ValueError("the lever-arm pass recorded no GNSS innovations")
    m = (rec.kind <= 1) & np.isin(rec.status, (STATUS_USED, STATUS_GATED, STATUS_RESET)) \
        & np.isfinite(rec.nis)
    key = rec.kind[m].astype(np.int64) * 2 ** 62 + np.round(
        (rec.t_s[m] + shift_s) * 1e3).astype(np.int64)
    return LeverPass(float(shift_s), np.asarray(nav.lever_arm.lever_b_m, dtype=float),
                     np.asarray(nav.lever_arm.sigma_b_m, dtype=float), key,
                     np.minimum(rec.nis[m], nav.gate_nis), innovation_lrv_ratio(nav))


def innovation_lrv_ratio(nav: FilterResult, window_s: float = LEVER_TIME_COLOUR_WINDOW_S
                         ) -> float:
    """The largest long-run variance ratio (:func:`pospp.distributions.long_run_ratio` over
    ``window_s``) of the innovations of the GNSS positions and of the velocities that ``nav``
    used, each whitened by its innovation covariance (``L^T dz`` with ``S^-1 = L L^T``: unit
    white noise where A's model holds) when the pass kept it (``record_gains``: its
    ``gain_replay``), else as they are [m, m/s]; 1 with fewer than 20 records of a kind."""
    rec, gains = nav.innovations, nav.gain_replay
    if rec is None:
        return 1.0
    used = np.isin(rec.status, (STATUS_USED, STATUS_RESET)) & np.all(np.isfinite(rec.dz_ned),
                                                                      axis=1)
    ratio = 1.0
    for kind in (0, 1):
        m = used & (rec.kind == kind)
        if np.count_nonzero(m) < 20:
            continue
        dz = rec.dz_ned[m]
        if gains is not None:
            try:
                low = np.linalg.cholesky(gains.s_inv[m])
            except np.linalg.LinAlgError:
                low = None
            if low is not None:
                dz = np.einsum("mji,mj->mi", low, dz)
        ratio = max(ratio, long_run_ratio(dz, rec.t_s[m], window_s, gauss_markov=True))
    return ratio


def _common(passes: list[LeverPass]) -> list[NDArray]:
    """Each pass's NIS on the records every pass processed (same order)."""
    keys = passes[0].record_key
    for p in passes[1:]:
        keys = np.intersect1d(keys, p.record_key)
    out = []
    for p in passes:
        order = np.argsort(p.record_key, kind="stable")
        idx = order[np.searchsorted(p.record_key[order], keys)]
        out.append(p.nis[idx])
    return out


def _profile(passes: list[LeverPass]) -> tuple[float, float, float, int, float] | None:
    """(tau, curvature c of J = c (s - tau)^2 + J_min, J_min, n, sigma of tau from the fit)
    of the least-squares parabola through the passes' J (None when it is not convex). With
    more than three passes, J's scatter about the parabola (A's passes do not lie on one:
    its lever-arm states jump by tens of cm on a short flight whose antenna height it cannot
    see, and J with them) gives tau a second sigma, by the delta method on the fit's
    covariance."""
    nis = _common(passes)
    s = np.array([p.shift_s for p in passes])
    j = np.array([float(np.sum(x)) for x in nis])
    x = np.column_stack([s * s, s, np.ones_like(s)])
    coef, *_ = np.linalg.lstsq(x, j, rcond=None)
    c2, c1, c0 = coef
    if not c2 > 0:
        return None
    tau = -c1 / (2.0 * c2)
    sig_fit = 0.0
    if s.size > 3:
        rss = float(np.sum((j - x @ coef) ** 2))
        cov = rss / (s.size - 3) * np.linalg.inv(x.T @ x)
        grad = np.array([c1 / (2.0 * c2 * c2), -1.0 / (2.0 * c2), 0.0])  # d tau / d coef
        sig_fit = float(np.sqrt(max(grad @ cov @ grad, 0.0)))
    return float(tau), float(c2), float(c0 - c1 * c1 / (4.0 * c2)), int(nis[0].size), sig_fit


RunPass = Callable[[float, NDArray], LeverPass]
"""run_pass(shift_s, start_b_m): A's lever-arm pass on the log re-stamped by ``shift_s``, its
lever-arm states started at ``start_b_m``."""


class _Profile:
    """The passes made so far, by trial offset in whole steps; each new one started where the
    nearest made one puts the lever arm (moved by the slope dl/ds): A is not linear in a
    lever-arm error of a metre (its gate; its attitude Jacobian at the wrong lever arm), so a
    pass started far from its answer stops short of it and J is then not A's likelihood."""

    def __init__(self, run_pass: RunPass, step_s: float, p0: LeverPass) -> None:
        self.run_pass, self.step_s = run_pass, step_s
        self.made: dict[int, LeverPass] = {0: p0}
        self.slope = np.zeros(3)

    def at(self, k: int) -> LeverPass:
        if k not in self.made:
            near = min(self.made, key=lambda j: abs(j - k))
            start = self.made[near].lever_b_m + self.slope * (k - near) * self.step_s
            self.made[k] = self.run_pass(k * self.step_s, start)
            if len(self.made) >= 2:
                ks = sorted(self.made)
                self.slope = np.polyfit([j * self.step_s for j in ks],
                                        [self.made[j].lever_b_m for j in ks], 1)[0]
        return self.made[k]

    def j(self, k: int) -> float:
        return float(np.sum(_common([self.at(k), self.at(0)])[0]))


def lever_time_joint(run_pass: RunPass, configured_b_m: NDArray, start_b_m: NDArray, *,
                     grid_s: float, step_s: float = LEVER_TIME_STEP_S,
                     max_passes: int = LEVER_TIME_MAX_PASSES) -> LeverTime | None:
    """The joint estimate of the lever arm and the GNSS time offset (module docstring).

    Parameters
    ----------
    run_pass : callable(shift_s, start_b_m) -> LeverPass
        A's lever-arm pass on the log re-stamped by the trial offset, from a start; may raise
        ValueError (A failed: the estimate is then None).
    configured_b_m : (3,) the configured lever arm, body FRD [m]
    start_b_m : (3,) where the first pass (offset 0) starts: A's lever-arm estimate.
    grid_s : float
        The IMU interval [s]: every trial offset is a whole number of them. A takes a GNSS
        velocity at its nearest IMU epoch (the position is moved by v dt to the record's
        time), so an offset between two grid points moves the velocity records' timing error
        by up to half an interval: J then jumps by tens between offsets 2.5 ms apart (the
        sample flight, 100 Hz), and its parabola is noise.

    The minimum of J is walked to in steps (``step_s`` on the grid): from 0 and +-1 step,
    the profile moves towards the lower end, doubling its stride, until the lowest J is
    inside (``max_passes`` passes at most; else None); then the least-squares parabola
    through the lowest and two steps either side gives tau (:func:`_profile`).
    """
    cfg = np.asarray(configured_b_m, dtype=float)
    h = max(round(step_s / grid_s), 1) * grid_s if grid_s > 0 else step_s
    try:
        start = np.asarray(start_b_m, dtype=float)
        p0 = run_pass(0.0, start)
        for _ in range(LEVER_TIME_START_PASSES):  # A is not linear in a lever-arm error
            if not np.max(np.abs(p0.lever_b_m - start)) > LEVER_TIME_START_STEP_M:
                break
            start = p0.lever_b_m
            p0 = run_pass(0.0, start)
        prof = _Profile(run_pass, h, p0)
        stride, best, way = 1, 0, 0
        for _ in range(2 * max_passes):
            if len(prof.made) > max_passes:
                return None
            jl, jb, jh = prof.j(best - 1), prof.j(best), prof.j(best + 1)
            if jb <= jl and jb <= jh:
                break
            step = -1 if jl < jh else 1
            stride = stride * 2 if step == way else 1  # double while going one way
            way = step
            best += step * min(stride, 8)
        else:
            return None
    except ValueError:
        return None
    try:  # five passes about the lowest: J's scatter about the parabola is seen
        passes = [prof.at(best + k) for k in (-2, -1, 0, 1, 2)]
    except ValueError:
        return None
    return _joint(passes, _profile(passes), cfg, prof.at(0))


def _joint(passes: list[LeverPass], prof: tuple[float, float, float, int, float] | None,
           cfg: NDArray, p0: LeverPass) -> LeverTime:
    """:class:`LeverTime` of the passes about the profile's minimum; ``p0``: the pass at 0."""
    s = np.array([p.shift_s for p in passes])
    lev = np.array([p.lever_b_m for p in passes])
    slope = np.polyfit(s, lev, 1)[0]
    near = min(passes, key=lambda p: abs(p.shift_s - (prof[0] if prof else 0.0)))
    sig_given = np.asarray(near.sigma_b_m, dtype=float)
    colour = max(1.0, near.lrv_ratio)  # correlated innovations: fewer independent records
    if prof is None:  # J flat or concave: the offset is not determined; the level: J(0)'s
        n = int(_common(passes)[0].size)
        tau, sig_tau, red = 0.0, math.inf, float(np.mean(p0.nis)) / 3.0 if n else math.nan
    else:
        tau, c2, j_min, n, sig_fit = prof
        red = j_min / (3.0 * n) if n else math.nan
        sig_tau = math.sqrt(max(1.0, red if math.isfinite(red) else 1.0) * colour / c2
                            + sig_fit ** 2)
    # a receiver noisier than it reports widens the lever arm's sigmas as it does tau's
    level = max(1.0, red) if math.isfinite(red) else 1.0
    sig_given = sig_given * math.sqrt(level * colour)
    fit2 = [np.polyfit(s, lev[:, i], 2) for i in range(3)]
    lever_tau = np.array([np.polyval(f, tau) for f in fit2])
    # the apparent lever arm: the pass at 0 (its own sigma), else the profile's at 0
    apparent = (np.asarray(p0.lever_b_m, dtype=float) if np.any(np.abs(s) < 1e-12)
                else lever_tau - slope * tau)
    var = sig_given ** 2 + (slope * sig_tau) ** 2 if math.isfinite(sig_tau) else \
        np.full(3, math.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.where(np.isfinite(var), slope * sig_tau / np.sqrt(var), np.sign(slope))
    tau_b = (tau + (cfg[0] - lever_tau[0]) / slope[0]) if abs(slope[0]) > 1e-3 else math.inf
    return LeverTime(float(tau), float(sig_tau), lever_tau, np.sqrt(var), sig_given, apparent,
                     np.asarray(p0.sigma_b_m, dtype=float) * math.sqrt(level * colour),
                     slope, corr, cfg,
                     float(tau_b), float(red), n, colour)


@dataclass(frozen=True)
class Verdict:
    """What the joint estimate says (:func:`lever_time_verdict`).

    ``kind``: "none" (the apparent lever arm agrees with the configured one), "lever_arm",
    "time_offset", "both" or "confounded" (the flight cannot tell them apart); ``text``: the
    suggestion, with both readings and their numbers.
    """

    kind: str
    text: str


def _vec(x: NDArray) -> str:
    return "[" + ", ".join(f"{v if abs(v) >= 0.005 else 0.0:.2f}" for v in x) + "]"


def _late(tau_s: float, sigma_s: float) -> str:
    word = "lags" if tau_s > 0 else "leads"
    sig = f" +- {1e3 * sigma_s:.1f}" if math.isfinite(sigma_s) else ""
    return (f"GNSS {word} the IMU by {1e3 * abs(tau_s):.1f}{sig} ms (records stamped "
            f"{'late' if tau_s > 0 else 'early'}; time_offset, IMU minus GNSS time, "
            f"{-1e3 * tau_s:+.1f} ms)")


def lever_time_verdict(est: LeverTime, *, sigmas: float = 5.0) -> Verdict:
    """The joint estimate's reading: which of the lever arm and the time offset the flight
    shows (each beyond ``sigmas`` of its own sigma and its practical floor), or that it
    cannot tell them apart (module docstring), with a suggestion naming both readings."""
    cfg = est.configured_b_m
    d_app = est.apparent_lever_b_m - cfg
    app_seen = (np.abs(d_app) > sigmas * est.sigma_apparent_b_m) & \
        (np.abs(d_app) > LEVER_ARM_FLOOR_M)
    if not app_seen.any():
        return Verdict("none", "")
    d_lev = est.lever_b_m - cfg
    lev_seen = bool(np.any((np.abs(d_lev) > sigmas * est.sigma_lever_b_m)
                           & (np.abs(d_lev) > LEVER_ARM_FLOOR_M)))
    tau_seen = (abs(est.tau_s) > sigmas * est.sigma_tau_s
                and abs(est.tau_s) > TIME_OFFSET_FLOOR_S)
    z_l, z_t = est.z_lever_only(), est.z_time_only()
    speed = est.speed_mps
    lever_reading = (f"a lever arm of {_vec(est.apparent_lever_b_m)} m (body FRD; "
                     f"{_vec(cfg)} m configured: set [gnss] lever_arm_m)")
    time_reading = (_late(est.tau_lever_only_s,
                          float(est.sigma_apparent_b_m[0] / abs(est.dlever_dtau_mps[0])))
                    if math.isfinite(est.tau_lever_only_s) else "")
    if tau_seen and not lev_seen and z_l > SEPARATION_SIGMAS:
        return Verdict("time_offset", (
            f"{_late(est.tau_s, est.sigma_tau_s)}: fix the GNSS stamps (receiver latency, "
            f"clock); the lever arm at that offset is {_vec(est.lever_b_m)} m, as configured "
            f"within its sigma. Read as {lever_reading}, the flight's speed changes reject it "
            f"({z_l:.0f} sigma)"))
    # a difference off the forward axis is no offset's (v tau lies along the track)
    if lev_seen and not tau_seen and (z_t > SEPARATION_SIGMAS or not app_seen[0]):
        alt = (f"; read as a GNSS time offset ({time_reading}), the flight's speed changes "
               f"reject it ({z_t:.0f} sigma)") if time_reading and app_seen[0] else ""
        return Verdict("lever_arm", (
            f"the data suggest a lever arm of {_vec(est.lever_b_m)} m (body FRD, sigma "
            f"{', '.join(f'{x:.2f}' for x in est.sigma_lever_b_m)}) where {_vec(cfg)} m is "
            f"configured: set [gnss] lever_arm_m{alt}"))
    if lev_seen and tau_seen:
        return Verdict("both", (
            f"both: {_late(est.tau_s, est.sigma_tau_s)} and a lever arm of "
            f"{_vec(est.lever_b_m)} m (body FRD; {_vec(cfg)} m configured), told apart by the "
            "flight's speed changes: fix the GNSS stamps, then set [gnss] lever_arm_m"))
    i = int(np.argmax(np.abs(d_app) / np.maximum(est.sigma_apparent_b_m, 1e-9)))
    comb = (f"forward lever arm + v x time offset = {est.apparent_lever_b_m[0]:.2f} +- "
            f"{est.sigma_apparent_b_m[0]:.2f} m at {speed:.0f} m/s" if i == 0 and speed > 1.0
            else f"the apparent lever arm is {_vec(est.apparent_lever_b_m)} m")
    alt = f" or {time_reading}" if time_reading and i == 0 else ""
    return Verdict("confounded", (
        f"{comb} ({_vec(cfg)} m configured): either {lever_reading}{alt}; this flight cannot "
        "tell them apart (its speed hardly changes while the GNSS is received): fly a leg at "
        "another speed, or a take-off roll, to separate them"))
