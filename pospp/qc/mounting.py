"""QC check of the IMU's mounting yaw: A's heading against the GNSS course.

Arrays in, a frozen :class:`pospp.qc.check_record.Check` out (no I/O). Frames: NED, body FRD as
declared (the configured ``[input] mounting_rpy_deg`` applied); angles rad inside, deg in the
check; times ``t_s`` from the run epoch.

A mounting yaw declared wrong by psi rotates the body A navigates (b') about down: its attitude
converges to C_nb' = C_nb R_z(psi)^T, so A's heading is the vehicle's minus psi, and every
attitude it outputs is off by psi. No gravity check sees a rotation about down, and the
lever-arm pass reads the antenna in b' as the configured lever arm rotated by psi (the sample
flight with ``mounting_rpy_deg = [0, 0, 90]``: "degraded" with the advice to set the lever arm
to [-0.10, 0.30, -1.52] m; following it gave "ok" with an 89 deg heading error).

In straight, level flight at speed the course over ground chi = atan2(v_E, v_N) is the heading
plus the crab (the drift of the wind: at most about 20 deg for an aircraft at cruise, a few deg
for a car), and the crab changes sign with the heading relative to the wind, so on back and
forth lines it averages out. The statistic is the circular mean of psi_A - chi over such
epochs. Where the course does not follow the heading through the turns (a multirotor that flies
sideways) the comparison says nothing and the check is not applicable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp import rotation
from pospp.qc.check_record import Check, skip
from pospp.qc.checks import LEVER_ARM_MAX_M, LEVER_ARM_SIGMAS

__all__ = ["MOUNTING_YAW_MAX_DEG", "HeadingOffset", "heading_offset", "lever_arm_naming_mounting",
           "mounting_yaw"]

MOUNTING_YAW_MAX_DEG = 45.0
"""Largest |mean(A's heading - GNSS course)| in straight, level flight at speed [deg]: beyond
any crab of an aircraft at cruise or a car (the clean logs of docs/qc.md: 0.0-5 deg), and half
of the quarter turn an IMU mounted on the wrong face is off by."""
MIN_SPEED_MPS = 5.0
"""Epochs compared: horizontal GNSS speed above this [m/s] (a car on the reference case
drives at 9 m/s)..."""
MAX_COURSE_RATE_DPS = 1.0
"""... the course turning slower than this [deg/s] ..."""
MAX_FLIGHT_PATH_DEG = 5.0
"""... and climbing or descending at most this steeply [deg]."""
MIN_EPOCHS = 30
"""At least this many such GNSS epochs (else not applicable)."""
MIN_EXPLAINED = 0.5
"""The course changes between GNSS epochs at speed must follow A's heading changes at least
this well (R^2) for the comparison to mean anything (as for the time-offset check)."""
MIN_TURN_DEG = 30.0
"""... over turns adding up to at least this much course change [deg]; the changes are taken
over intervals of at least COURSE_INTERVAL_S, so that a 10 Hz receiver's course noise does not
drown them."""
COURSE_INTERVAL_S = 1.0


@dataclass(frozen=True)
class HeadingOffset:
    """A's heading minus the GNSS course in straight, level flight at speed."""

    offset_rad: float
    """Circular mean of psi_A - chi, wrapped to (-pi, pi] [rad]."""
    spread_rad: float
    """Circular standard deviation of psi_A - chi [rad]."""
    n_epochs: int
    explained: float
    """Share of the course changes' variance A's heading changes explain (R^2; NaN: no turn)."""


def _wrap(a: NDArray) -> NDArray:
    return np.angle(np.exp(1j * a))


def heading_offset(vel_t_s: ArrayLike, v_n_mps: ArrayLike, sol_t_s: ArrayLike,
                   q_nb: ArrayLike) -> HeadingOffset | None:
    """:class:`HeadingOffset` from GNSS velocities (NED [m/s] at ``vel_t_s``) and A's attitude
    (quaternions ``q_nb`` at ``sol_t_s``, yaw interpolated unwrapped to the GNSS epochs);
    None without GNSS velocities at speed."""
    tv = np.asarray(vel_t_s, dtype=float)
    v = np.asarray(v_n_mps, dtype=float)
    ts = np.asarray(sol_t_s, dtype=float)
    inside = (tv >= ts[0]) & (tv <= ts[-1]) if ts.size else np.zeros(tv.shape, bool)
    tv, v = tv[inside], v[inside]
    vh = np.hypot(v[:, 0], v[:, 1]) if v.size else np.zeros(0)
    fast = vh > MIN_SPEED_MPS
    if np.count_nonzero(fast) < MIN_EPOCHS:
        return None
    yaw = np.interp(tv, ts, np.unwrap(rotation.euler_from_quat(q_nb)[:, 2]))
    course = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    rate = np.gradient(course, tv) if tv.size > 1 else np.zeros(tv.shape)
    steady = fast & (np.abs(rate) < math.radians(MAX_COURSE_RATE_DPS)) & (
        np.abs(v[:, 2]) < vh * math.tan(math.radians(MAX_FLIGHT_PATH_DEG)))
    if np.count_nonzero(steady) < MIN_EPOCHS:
        return None
    z = np.exp(1j * _wrap(yaw[steady] - course[steady])).mean()
    k = max(1, int(round(COURSE_INTERVAL_S / float(np.median(np.diff(tv))))))
    both = fast[k::k] & fast[:-k:k]
    dc, dy = np.diff(course[::k])[both], np.diff(yaw[::k])[both]
    turned = float(np.sum(np.abs(dc)))
    explained = (1.0 - float(np.sum((dc - dy) ** 2)) / float(np.sum(dc**2))
                 if turned >= math.radians(MIN_TURN_DEG) else math.nan)
    return HeadingOffset(float(np.angle(z)), math.sqrt(-2.0 * math.log(max(abs(z), 1e-12))),
                         int(np.count_nonzero(steady)), explained)


def mounting_yaw(est: HeadingOffset | None, mounting_rpy_deg: ArrayLike) -> Check:
    """|A's heading - GNSS course| in straight, level flight at speed against
    :data:`MOUNTING_YAW_MAX_DEG` (severity failed: every attitude of the run is off by it).

    The suggestion gives the mounting yaw that removes it: the configured yaw plus the offset
    (A's heading is the vehicle's minus the yaw error)."""
    if est is None:
        return skip("mounting_yaw", "navigate", f"fewer than {MIN_EPOCHS} GNSS epochs in "
                    "straight, level flight at speed", "deg", MOUNTING_YAW_MAX_DEG)
    if not est.explained >= MIN_EXPLAINED:
        why = ("no turn to tell a crab from the mounting" if math.isnan(est.explained) else
               f"the course does not follow the heading through the turns (R^2 "
               f"{est.explained:.2f}: a vehicle that moves sideways)")
        return skip("mounting_yaw", "navigate", why, "deg", MOUNTING_YAW_MAX_DEG)
    off = math.degrees(est.offset_rad)
    passed = abs(off) <= MOUNTING_YAW_MAX_DEG
    rpy = [float(x) for x in np.asarray(mounting_rpy_deg, dtype=float)]
    new_yaw = (int(round(rpy[2] + off)) + 180) % 360 - 180  # whole degrees, no "-0"
    sug = "" if passed else (
        f"A's heading is {off:+.1f} deg off the GNSS course in straight, level flight "
        f"({est.n_epochs} epochs at speed): the IMU's mounting yaw looks wrong; set [input] "
        f"mounting_rpy_deg = [{rpy[0]:g}, {rpy[1]:g}, {new_yaw}] (configured yaw "
        f"{rpy[2]:g} deg)")
    return Check("mounting_yaw", "navigate",
                 "|mean A heading - GNSS course| in straight, level flight at speed "
                 f"(circular spread {math.degrees(est.spread_rad):.1f} deg, R^2 "
                 f"{est.explained:.2f})", abs(off), MOUNTING_YAW_MAX_DEG, "deg", passed,
                 "failed", sug)


_QUARTER_TURNS = tuple((axis, k) for axis in range(3) for k in (1, 2, 3))


def _rotation(axis: int, angle_rad: float) -> NDArray:
    vec = np.zeros(3)
    vec[axis] = angle_rad
    return rotation.dcm_from_rotvec(vec)


def lever_arm_naming_mounting(check: Check, configured_b_m: ArrayLike,
                              estimated_b_m: ArrayLike, sigma_b_m: ArrayLike,
                              observable: ArrayLike, mounting: Check,
                              offset_rad: float | None) -> Check:
    """The lever-arm check with a suggestion that names the mounting when the estimate is the
    configured lever arm rotated: by the heading offset about down, or by a quarter turn about
    a body axis (an IMU mounted on another face), within max(5 sigma, 0.2 m) on the axes the
    flight reveals. A lever arm "fixed" that way hides a wrong attitude."""
    if check.passed:
        return check
    cfg = np.asarray(configured_b_m, dtype=float)
    est = np.asarray(estimated_b_m, dtype=float)
    tol = np.maximum(LEVER_ARM_SIGMAS * np.asarray(sigma_b_m, dtype=float), LEVER_ARM_MAX_M)
    seen = np.asarray(observable, dtype=bool)
    candidates = [(2, -offset_rad)] if offset_rad is not None else []
    candidates += [(axis, k * math.pi / 2) for axis, k in _QUARTER_TURNS]
    for axis, angle in candidates:
        rotated = _rotation(axis, angle) @ cfg
        if np.linalg.norm((rotated - cfg)[seen]) > LEVER_ARM_MAX_M and \
                np.all(np.abs(rotated - est)[seen] <= tol[seen]):
            what = (f"the configured lever arm rotated by {math.degrees(angle):+.0f} deg about "
                    f"body {'xyz'[axis]}")
            tail = ("see mounting_yaw" if not mounting.passed else
                    "check [input] sensor_frame and mounting_rpy_deg")
            return replace(check, suggestion=(
                f"the estimate [{', '.join(f'{x:.2f}' for x in est)}] m is {what}: the IMU "
                f"mounting is wrong, not the lever arm ({tail}); keep [gnss] lever_arm_m and "
                "fix the mounting first"))
    if not mounting.passed:
        return replace(check, suggestion="fix the IMU mounting first (mounting_yaw), the "
                       "lever-arm estimate is made in the wrong body axes; " + check.suggestion)
    return check
