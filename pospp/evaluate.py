"""Errors of a navigation solution against a reference trajectory (``pospp evaluate``).

A reference that does not share an epoch with the solution, or lies kilometres away from it,
is refused (:class:`TruthMismatchError`): it is not this flight's. Errors are computed minus
reference (docs/method.md): position in local NED metres about the
reference point (exact llh difference, pospp.earth.llh_difference_ned_m), velocity NED m/s,
attitude as the rotation vector phi (NED, rad) with C_nb_est = (I - [phi x]) C_nb_ref, split
into tilt (north, east) and heading (down) components; attitudes are compared as rotations,
never element-wise Euler. The reference is interpolated to the solution's times (linear in
position and velocity, spherical-linear in attitude); solution epochs outside the reference's
span are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from pospp import earth, rotation
from pospp.units import ARCSEC_RAD

MAX_TRUTH_DISTANCE_M = 1000.0
"""A reference whose median horizontal distance from the solution exceeds this [m] is not of
this flight (another flight's truth, another site): refused, not evaluated. GNSS-aided
solutions of any grade pospp handles lie within metres of their truth."""


class TruthMismatchError(ValueError):
    """The reference is not of this flight: no epoch in common, or kilometres away."""


@dataclass(frozen=True)
class SolutionErrors:
    """Errors of one solution at the common epochs (time-major, SI, NED)."""

    time_ns: NDArray
    pos_ned_m: NDArray
    vel_ned_mps: NDArray
    att_ned_rad: NDArray

    def rms(self, *, skip_s: float = 0.0) -> dict[str, float]:
        """RMS figures (SI) over the epochs later than ``skip_s`` after the first."""
        m = self.time_ns >= self.time_ns[0] + int(skip_s * 1e9)

        def r(x: NDArray) -> float:
            return float(np.sqrt(np.mean(x[m] ** 2))) if m.any() else float("nan")

        return {
            "north_rms_m": r(self.pos_ned_m[:, 0]),
            "east_rms_m": r(self.pos_ned_m[:, 1]),
            "down_rms_m": r(self.pos_ned_m[:, 2]),
            "horizontal_rms_m": r(np.hypot(self.pos_ned_m[:, 0], self.pos_ned_m[:, 1])),
            "vel_horizontal_rms_mps": r(np.hypot(self.vel_ned_mps[:, 0],
                                                 self.vel_ned_mps[:, 1])),
            "vd_rms_mps": r(self.vel_ned_mps[:, 2]),
            "roll_pitch_rms_rad": r(np.hypot(self.att_ned_rad[:, 0], self.att_ned_rad[:, 1])
                                    / np.sqrt(2.0)),
            "heading_rms_rad": r(self.att_ned_rad[:, 2]),
        }


def solution_errors(
    time_ns: NDArray,
    lat_rad: NDArray,
    lon_rad: NDArray,
    height_m: NDArray,
    v_n_mps: NDArray,
    rpy_rad: NDArray,
    *,
    ref_time_ns: NDArray,
    ref_lat_rad: NDArray,
    ref_lon_rad: NDArray,
    ref_height_m: NDArray,
    ref_v_n_mps: NDArray,
    ref_rpy_rad: NDArray,
) -> SolutionErrors:
    """Errors (solution minus reference) at the solution epochs inside the reference span.

    Parameters
    ----------
    time_ns, lat_rad, lon_rad, height_m, v_n_mps, rpy_rad : arrays
        The solution: (N,) int64 stamps, geodetic position (rad, rad, m), NED velocity (N, 3)
        [m/s], [roll, pitch, yaw] (N, 3) [rad] of FRD w.r.t. NED.
    ref_* : arrays
        The reference, same meaning, its own epochs (strictly increasing).
    """
    t = np.asarray(time_ns, dtype=np.int64)
    rt = np.asarray(ref_time_ns, dtype=np.int64)
    m = (t >= rt[0]) & (t <= rt[-1])
    if not m.any():
        raise TruthMismatchError(
            f"the solution [{t[0]}, {t[-1]}] ns and the reference [{rt[0]}, {rt[-1]}] ns do "
            "not overlap in time: not this flight's reference (or another time base)")
    t = t[m]
    x = (t - rt[0]).astype(float)
    xr = (rt - rt[0]).astype(float)

    def lin(a: NDArray) -> NDArray:
        a = np.asarray(a, dtype=float)
        if a.ndim == 1:
            return np.interp(x, xr, a)
        return np.column_stack([np.interp(x, xr, a[:, i]) for i in range(a.shape[1])])

    lon_ref = np.unwrap(np.asarray(ref_lon_rad, dtype=float))
    lat_r, lon_r, h_r, v_r = lin(ref_lat_rad), lin(lon_ref), lin(ref_height_m), lin(ref_v_n_mps)
    slerp = Slerp(xr, Rotation.from_matrix(rotation.dcm_from_euler(ref_rpy_rad)))
    c_ref = slerp(x).as_matrix()
    c_est = rotation.dcm_from_euler(np.asarray(rpy_rad, dtype=float)[m])
    pos = earth.llh_difference_ned_m(np.asarray(lat_rad)[m], np.asarray(lon_rad)[m],
                                     np.asarray(height_m)[m], lat_r, lon_r, h_r)
    vel = np.asarray(v_n_mps, dtype=float)[m] - v_r
    att = rotation.attitude_error_n_rad(c_est, c_ref)
    distance_m = float(np.median(np.hypot(pos[:, 0], pos[:, 1])))
    if not distance_m <= MAX_TRUTH_DISTANCE_M:
        raise TruthMismatchError(
            f"the reference lies {distance_m / 1e3:.3g} km from the solution (median over "
            f"{len(t)} common epochs; at most {MAX_TRUTH_DISTANCE_M / 1e3:g} km is taken as "
            "the same flight): not this flight's reference")
    return SolutionErrors(t, pos, vel, att)


_METRIC_UNITS = {
    "north_rms_m": ("north_rms", "m", 1.0),
    "east_rms_m": ("east_rms", "m", 1.0),
    "down_rms_m": ("down_rms", "m", 1.0),
    "horizontal_rms_m": ("horizontal_rms", "m", 1.0),
    "vel_horizontal_rms_mps": ("vel_horizontal_rms", "m/s", 1.0),
    "vd_rms_mps": ("vd_rms", "m/s", 1.0),
    "roll_pitch_rms_rad": ("roll_pitch_rms", "arcsec", 1.0 / ARCSEC_RAD),
    "heading_rms_rad": ("heading_rms", "arcsec", 1.0 / ARCSEC_RAD),
}


def evaluation_rows(errors: dict[str, SolutionErrors], *, skip_s: float = 0.0) -> dict[str, list]:
    """Columns of the long-form ``evaluation`` table (solution, metric, value, unit, ...).

    Parameters
    ----------
    errors : dict
        Solution name -> its :class:`SolutionErrors`.
    skip_s : float
        Leave out the epochs within this time of each solution's first (alignment, take-off).
    """
    cols: dict[str, list] = {k: [] for k in ("solution", "metric", "value", "unit", "skip_s",
                                             "n_epochs")}
    for name, err in errors.items():
        rms = err.rms(skip_s=skip_s)
        n = int(np.sum(err.time_ns >= err.time_ns[0] + int(skip_s * 1e9)))
        for key, (metric, unit, scale) in _METRIC_UNITS.items():
            cols["solution"].append(name)
            cols["metric"].append(metric)
            cols["value"].append(rms[key] * scale)
            cols["unit"].append(unit)
            cols["skip_s"].append(float(skip_s))
            cols["n_epochs"].append(n)
    return cols
