"""Synthetic survey flights whose truth is the one strapdown kernel's own solution.

Frames and units: body FRD (b), navigation NED (n), SI (rad, m, s). Test scaffolding for the
model-discrepancy workflow's tests and benchmarks (moved out of the package, issue 17 item 6;
the mission simulator :mod:`pospp.sim` is the package's own flight generator).

Method: a nominal level flight (speed profile, heading profile with constant-rate turns, and an
optional small heading / pitch wander) is turned into error-free IMU increments with the
navigation equations read backwards at each interval's midpoint::

    w_ib_b = C_bn (w_ie_n + w_en_n) + w_nb_b
    f_b    = C_bn (dv_n/dt + (2 w_ie_n + w_en_n) x v_n - g_n)

and the truth is *defined* as :func:`pospp.nav.strapdown.integrate` of those increments from
the nominal initial state. The truth therefore obeys the mechanization exactly (B replayed from
the truth on clean increments has zero error, whatever the small mismatch between the nominal
and the integrated path), and any effect injected into the increments is the only source of
B's error.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pospp import earth, rotation
from pospp.calib.replay import (
    ImuIncrements,
    LegReplay,
    SolutionA,
    replay_leg,
    solution_a_from_trajectory,
)
from pospp.calib.segment import Leg
from pospp.nav import strapdown


@dataclass(frozen=True)
class SyntheticFlight:
    """Clean increments, their strapdown truth and the true legs.

    Attributes
    ----------
    imu : ImuIncrements
        Error-free increments (body FRD).
    truth : Trajectory
        The strapdown solution of ``imu`` (same epochs).
    legs : tuple of Leg
        Straight legs (times in ``t_s``).
    """

    imu: ImuIncrements
    truth: strapdown.Trajectory
    legs: tuple[Leg, ...]

    def solution_a(self, v_sigma_mps: float = 0.01) -> SolutionA:
        """The truth as algorithm A (no accelerometer-bias estimate)."""
        return solution_a_from_trajectory(self.truth, v_sigma_n_mps=np.full(3, v_sigma_mps))


def _smooth_turn(t: NDArray, t0: float, duration: float, angle: float) -> NDArray:
    """Heading change of a turn: C2 smoothstep from 0 to ``angle`` over [t0, t0 + duration]."""
    u = np.clip((t - t0) / duration, 0.0, 1.0)
    return angle * u**3 * (10.0 - 15.0 * u + 6.0 * u**2)


def survey_flight(
    *,
    headings_deg: tuple[float, ...] = (0.0, 180.0, 0.0, 180.0),
    speeds_mps: tuple[float, ...] | float = 60.0,
    leg_duration_s: float = 300.0,
    turn_duration_s: float = 60.0,
    lead_in_s: float = 20.0,
    rate_hz: float = 100.0,
    lat_deg: float = 40.0,
    lon_deg: float = 116.0,
    height_m: float = 1000.0,
    wander_heading_deg: float = 0.0,
    wander_pitch_deg: float = 0.0,
    wander_period_s: float = 40.0,
) -> SyntheticFlight:
    """Back-and-forth straight legs joined by smooth turns (and speed changes), level.

    Parameters
    ----------
    headings_deg : tuple of float
        Heading of each leg (clockwise from north).
    speeds_mps : float or tuple of float
        Speed of each leg; speed changes happen during the turns.
    leg_duration_s, turn_duration_s, lead_in_s : float
        Durations [s]; the flight starts with a straight lead-in on the first heading.
    rate_hz : float
        IMU rate [Hz].
    lat_deg, lon_deg, height_m : float
        Start position.
    wander_heading_deg, wander_pitch_deg, wander_period_s : float
        Amplitude of a sinusoidal heading / pitch oscillation (the legs are then not ideal; a
        pitch oscillation also makes the vertical speed oscillate) and its period.

    Returns
    -------
    SyntheticFlight
    """
    n_legs = len(headings_deg)
    speeds = np.broadcast_to(np.asarray(speeds_mps, dtype=float), (n_legs,))
    hdg = np.radians(np.asarray(headings_deg, dtype=float))
    leg_starts = lead_in_s + np.arange(n_legs) * (leg_duration_s + turn_duration_s)
    total = float(leg_starts[-1] + leg_duration_s + 5.0)
    t = np.arange(0.0, total + 0.5 / rate_hz, 1.0 / rate_hz)

    def profiles(tt: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        psi = np.full_like(tt, hdg[0])
        spd = np.full_like(tt, speeds[0])
        for i in range(1, n_legs):
            t_turn = leg_starts[i] - turn_duration_s
            dpsi = (hdg[i] - hdg[i - 1] + np.pi) % (2 * np.pi) - np.pi
            if abs(abs(dpsi) - np.pi) < 1e-9:
                dpsi = np.pi  # 180 deg: turn right
            psi = psi + _smooth_turn(tt, t_turn, turn_duration_s, dpsi)
            spd = spd + _smooth_turn(tt, t_turn, turn_duration_s, speeds[i] - speeds[i - 1])
        w = 2 * np.pi / wander_period_s
        psi = psi + np.radians(wander_heading_deg) * np.sin(w * tt)
        pitch = np.radians(wander_pitch_deg) * np.sin(w * tt)
        return psi, spd, pitch

    # nominal path on a fine grid (midpoints), position by trapezoidal integration
    tm = 0.5 * (t[1:] + t[:-1])
    dt = np.diff(t)
    h_eps = 1e-3
    psi_m, spd_m, th_m = profiles(tm)
    psi_d = (profiles(tm + h_eps)[0] - profiles(tm - h_eps)[0]) / (2 * h_eps)
    th_d = (profiles(tm + h_eps)[2] - profiles(tm - h_eps)[2]) / (2 * h_eps)

    def vel(tt: NDArray) -> NDArray:
        psi, spd, th = profiles(tt)
        return np.stack([spd * np.cos(th) * np.cos(psi), spd * np.cos(th) * np.sin(psi),
                         -spd * np.sin(th)], axis=1)

    v_m = vel(tm)
    a_m = (vel(tm + h_eps) - vel(tm - h_eps)) / (2 * h_eps)
    lat0, lon0 = np.radians(lat_deg), np.radians(lon_deg)
    v_nodes = vel(t)
    # geodetic position at the nodes (explicit integration of the rates; nominal only)
    lat = np.empty_like(t)
    hgt = np.empty_like(t)
    lat[0], hgt[0] = lat0, height_m
    r_m0, _ = earth.principal_radii_m(lat0)
    dn = np.concatenate([[0.0], np.cumsum(0.5 * (v_nodes[1:, 0] + v_nodes[:-1, 0]) * dt)])
    dd = np.concatenate([[0.0], np.cumsum(0.5 * (v_nodes[1:, 2] + v_nodes[:-1, 2]) * dt)])
    lat = lat0 + dn / (r_m0 + height_m)
    hgt = height_m - dd
    lat_m = 0.5 * (lat[1:] + lat[:-1])
    h_m = 0.5 * (hgt[1:] + hgt[:-1])
    c_nb = rotation.dcm_from_euler(np.stack([np.zeros_like(tm), th_m, psi_m], axis=1))
    w_ie = earth.earth_rate_n_radps(lat_m)
    w_en = earth.transport_rate_n_radps(lat_m, h_m, v_m)
    g_n = earth.gravity_n_mps2(lat_m, h_m)
    f_n = a_m + np.cross(2 * w_ie + w_en, v_m) - g_n
    c_bn = np.swapaxes(c_nb, 1, 2)
    # body rate of a yaw-then-pitch attitude (roll 0): w_nb_b = [-sin(th) psi', th', cos(th) psi']
    w_nb_b = np.stack([-np.sin(th_m) * psi_d, th_d, np.cos(th_m) * psi_d], axis=1)
    w_ib_b = np.einsum("kij,kj->ki", c_bn, w_ie + w_en) + w_nb_b
    f_b = np.einsum("kij,kj->ki", c_bn, f_n)
    dth = w_ib_b * dt[:, None]
    dv = f_b * dt[:, None]
    psi0, _, th0 = profiles(t[:1])
    x0 = strapdown.NavState.from_euler(lat0, lon0, height_m, v_nodes[0],
                                       [0.0, float(th0[0]), float(psi0[0])])
    truth = strapdown.integrate(t, dth, dv, x0)
    legs = tuple(
        Leg(leg_id=i, start_s=float(leg_starts[i]), end_s=float(leg_starts[i] + leg_duration_s),
            heading_rad=float(hdg[i] % (2 * np.pi)), speed_mps=float(speeds[i]),
            height_m=float(height_m), heading_spread_rad=0.0, speed_std_mps=0.0,
            vertical_speed_mps=0.0, heading_rate_max_radps=0.0)
        for i in range(n_legs)
    )
    return SyntheticFlight(ImuIncrements(t, dth, dv), truth, legs)


def noisy_replays(
    flight: SyntheticFlight,
    imu: ImuIncrements,
    *,
    sigma_mps: float,
    rng: np.random.Generator,
    solution_a: SolutionA | None = None,
) -> list[LegReplay]:
    """Replay B on (possibly perturbed) increments over every leg, with white noise on B - A.

    The noise stands for A's velocity error (standard deviation ``sigma_mps`` per axis, also
    the replays' ``sigma_v_n_mps``); the first sample stays zero (B starts on A).
    """
    ref = flight.solution_a(sigma_mps) if solution_a is None else solution_a
    out = []
    for leg in flight.legs:
        r = replay_leg(imu, ref, leg, sigma_floor_mps=min(0.005, sigma_mps))
        dv = r.dv_n_mps + rng.normal(0.0, sigma_mps, r.dv_n_mps.shape)
        dv[0] = 0.0
        out.append(dataclasses.replace(r, dv_n_mps=dv))
    return out
