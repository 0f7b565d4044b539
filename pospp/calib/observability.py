"""Observability study: condition number of the stacked pair matrix (paper Fig. 4 and 5).

Two ideal legs (straight, level, constant speed, 300 s) at headings H and H + dH and speeds
V and V + dV; their sensitivity rows come from the same error model and solver as the
calibration (:mod:`pospp.calib.solve`), so the study describes exactly what the calibration
solves. Unit weights; the condition numbers are reported raw (SI units) and column-scaled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pospp import earth, rotation
from pospp.calib.design import condition_numbers, design_matrix
from pospp.calib.replay import LegReplay
from pospp.calib.segment import Leg
from pospp.nav.error_model import transition_matrices
from pospp.nav.strapdown import Trajectory


@dataclass(frozen=True)
class ObservabilityGrid:
    """Condition numbers over heading and speed differences.

    ``cond_scaled[i, j]`` belongs to ``dheading_deg[i]`` and ``dspeed_mps[j]``.
    """

    formulation: str
    dheading_deg: NDArray
    dspeed_mps: NDArray
    cond_raw: NDArray
    cond_scaled: NDArray


def ideal_leg(
    leg_id: int,
    heading_rad: float,
    speed_mps: float,
    *,
    duration_s: float = 300.0,
    lat_rad: float = np.radians(40.0),
    height_m: float = 2600.0,
    rate_hz: float = 1.0,
    transition_rate_hz: float = 10.0,
    numerical: bool = True,
) -> LegReplay:
    """A synthetic ideal leg carrying only what the solver needs (zero errors, unit sigma).

    ``numerical=False`` skips the numerical transition matrices (identity placeholders) for
    the closed-form path, which does not use them.
    """
    n = int(duration_s * transition_rate_hz) + 1
    t = np.arange(n) / transition_rate_hz
    v_n = np.array([speed_mps * np.cos(heading_rad), speed_mps * np.sin(heading_rad), 0.0])
    r_m, r_n = earth.principal_radii_m(lat_rad)
    lat = lat_rad + v_n[0] * t / (r_m + height_m)
    lon = v_n[1] * t / ((r_n + height_m) * np.cos(lat_rad))
    q = np.tile(rotation.quat_from_euler([0.0, 0.0, heading_rad]), (n, 1))
    traj = Trajectory(t, lat, lon, np.full(n, height_m), np.tile(v_n, (n, 1)), q)
    g = earth.normal_gravity_mps2(lat_rad, height_m)
    c_bn = rotation.dcm_from_euler([0.0, 0.0, heading_rad]).T
    f_b = np.tile(c_bn @ np.array([0.0, 0.0, -g]), (n - 1, 1))
    step = int(round(transition_rate_hz / rate_hz))
    idx = np.arange(0, n, step)
    if numerical:
        phi = transition_matrices(traj, f_b, step=1)
    else:
        phi = np.broadcast_to(np.eye(15), (n, 15, 15))
    m = idx.size
    leg = Leg(leg_id, 0.0, duration_s, heading_rad % (2 * np.pi), speed_mps, height_m,
              0.0, 0.0, 0.0, 0.0)
    return LegReplay(
        leg=leg, t0_s=0.0, t_s=t[idx], dv_n_mps=np.zeros((m, 3)), dr_n_m=np.zeros((m, 3)),
        sigma_v_n_mps=np.ones((m, 3)), phi=phi[idx],
        c_nb0=c_bn.T, c_nb=np.tile(c_bn.T, (m, 1, 1)), lat_rad=float(lat_rad),
        height_m=float(height_m), v_n0_mps=v_n,
    )


def condition_grid(
    dheading_deg: NDArray,
    dspeed_mps: NDArray,
    *,
    formulation: str = "paper",
    heading_deg: float = 0.0,
    speed_mps: float = 60.0,
    duration_s: float = 300.0,
    lat_rad: float = np.radians(40.0),
    transition: str = "numerical",
) -> ObservabilityGrid:
    """Condition numbers of the pair matrix over dH x dV (paper Fig. 4: dV = 0; Fig. 5).

    Parameters
    ----------
    dheading_deg : array_like, shape (I,)
        Heading changes from leg a to leg b [deg].
    dspeed_mps : array_like, shape (J,)
        Speed of leg b minus speed of leg a [m/s].
    formulation : {"paper", "body"}
        Matrix whose conditioning is computed (paper Eq. 17 is ``"paper"``).
    heading_deg, speed_mps, duration_s, lat_rad : float
        Leg a's heading [deg], speed [m/s], both legs' duration [s], latitude [rad].
    transition : {"numerical", "closed_form"}
        Sensitivity rows (the two agree on these ideal legs).
    """
    dh = np.asarray(dheading_deg, dtype=float)
    dv = np.asarray(dspeed_mps, dtype=float)
    raw = np.empty((dh.size, dv.size))
    scaled = np.empty_like(raw)
    num = transition == "numerical"
    leg_a = ideal_leg(0, np.radians(heading_deg), speed_mps, duration_s=duration_s,
                      lat_rad=lat_rad, numerical=num)
    for i, h in enumerate(dh):
        for j, s in enumerate(dv):
            leg_b = ideal_leg(1, np.radians(heading_deg + h), speed_mps + s,
                              duration_s=duration_s, lat_rad=lat_rad, numerical=num)
            hm, _, sig, _ = design_matrix((leg_a, leg_b), formulation, transition=transition)
            raw[i, j], scaled[i, j] = condition_numbers(hm / sig[:, None])
    return ObservabilityGrid(formulation, dh, dv, raw, scaled)


def observability_table(
    dheading_deg: NDArray | None = None,
    dspeed_mps: NDArray | None = None,
    *,
    formulations: tuple[str, ...] = ("paper", "body"),
    speed_mps: float = 60.0,
    duration_s: float = 300.0,
    lat_rad: float = np.radians(40.0),
    transition: str = "closed_form",
) -> dict[str, NDArray | list[str]]:
    """Long-form table of paper Fig. 4 (cond vs dH at dV = 0) and Fig. 5 (cond vs dV per dH).

    The ``pospp observability`` command calls this; pospp.report draws the figures from it.
    Defaults: dH 0..180 deg every 5 deg, dV in {0, 5, 10, 20, 30, 40} m/s, the paper's
    flight case (60 m/s, 300 s legs, 40 deg N), closed-form rows (they agree with the
    numerical ones on ideal legs to < 1 %, and cost nothing).

    Returns
    -------
    dict
        Columns formulation (str), dheading_deg, dspeed_mps, cond_raw, cond_scaled (float).
    """
    dh = np.arange(0.0, 181.0, 5.0) if dheading_deg is None else np.asarray(dheading_deg, float)
    dv = (np.array([0.0, 5.0, 10.0, 20.0, 30.0, 40.0]) if dspeed_mps is None
          else np.asarray(dspeed_mps, float))
    cols: dict[str, list] = {k: [] for k in ("formulation", "dheading_deg", "dspeed_mps",
                                             "cond_raw", "cond_scaled")}
    for f in formulations:
        g = condition_grid(dh, dv, formulation=f, speed_mps=speed_mps, duration_s=duration_s,
                           lat_rad=lat_rad, transition=transition)
        hh, vv = np.meshgrid(dh, dv, indexing="ij")
        cols["formulation"] += [f] * hh.size
        cols["dheading_deg"] += list(hh.ravel())
        cols["dspeed_mps"] += list(vv.ravel())
        cols["cond_raw"] += list(g.cond_raw.ravel())
        cols["cond_scaled"] += list(g.cond_scaled.ravel())
    out: dict[str, NDArray | list[str]] = {"formulation": cols["formulation"]}
    for k in ("dheading_deg", "dspeed_mps", "cond_raw", "cond_scaled"):
        out[k] = np.asarray(cols[k], dtype=float)
    return out
