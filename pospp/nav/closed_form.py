"""Closed-form horizontal (Schuler) error channels of a constant-velocity leg (paper Eq. 3-14).

Liu & Fang (2012) model algorithm B's horizontal velocity error over a straight, uniform leg by
a simplified error model whose transition matrix has closed-form rows (paper Eq. 10 and 13).
This module re-derives those rows in pospp's conventions FROM ONE simplified F
(:func:`simplified_f_matrix`) and provides that F, so that every closed form is checked against
``scipy.linalg.expm(F t)`` (tests/unit/test_closed_form.py) instead of against the paper's print.

Conventions (pospp, docs/method.md "Error definitions")
-------------------------------------------------------
Frames NED (n) and FRD (b). Errors are computed minus true: ``dv_n = v_hat - v``,
``dr_n`` = computed minus true position in local NED metres; the misalignment phi (NED, rad)
satisfies ``C_nb_hat = (I - [phi x]) C_nb``; the gyro reads true + bias, and the
navigation-frame drift is ``eps_n = C_nb b_g`` (rad/s).

Simplified state and F (constant velocity v_n, latitude L, height h)
--------------------------------------------------------------------
State order (:data:`STATES`)::

    x = [dv_N, dv_E, phi_N, phi_E, phi_D, eps_N, eps_E, eps_D, dr_N, dr_E]

With R_N' = R_M + h (north channel), R_E' = R_N + h (east channel), g the normal gravity,
w_N = Omega cos L + v_E / R_E' and w_E = -v_N / R_N' (components of w_in = w_ie + w_en)::

    dv_N'  =  g phi_E                          dv_E'  = -g phi_N
    phi_E' = -dv_N / R_N' + w_N phi_D - eps_E   phi_N' =  dv_E / R_E' - w_E phi_D - eps_N
    phi_D' = -eps_D                             eps'   =  0
    dr_N'  =  dv_N                              dr_E'  =  dv_E

These are the horizontal rows of the 15-state model of :mod:`pospp.nav.error_model`
(``phi' = -w_in x phi + dw_in(dv) - C_nb b_g``, ``dv' = f_n x phi + ...``) with f_n = [0, 0, -g]
(level, unaccelerated), keeping the Schuler loop, the heading-to-tilt coupling through the
horizontal w_in, and dropping: the tilt cross-coupling through w_in,D (Foucault, period
2 pi / (Omega sin L), about 37 h at 40 deg), Coriolis and transport terms in the velocity rows,
the heading dynamics driven by the tilts and by dv_E tan L / R, the position-error terms, and
the vertical channel. Over an ideal 300 s leg at 60 m/s these change the velocity error by
about 2 % in the tilt and horizontal-drift columns and up to 6-9 % in the heading and vertical
drift columns (mostly the Coriolis-compensating horizontal specific force times phi_D);
on a leg that wanders the closed forms degrade much more (36 % for heading on a +-10 deg
weave). :func:`pospp.nav.error_model.transition_matrices` keeps every term along the actual
trajectory (tests/unit/test_closed_form.py, test_error_model.py).

Closed forms (the two channels are independent)
-----------------------------------------------
With omega_N = sqrt(g / R_N'), omega_E = sqrt(g / R_E') (Schuler frequencies; 84.4 min period)
and, for a channel of frequency omega and radius R = g / omega^2,
``S = sin(omega t)``, ``C1 = 1 - cos(omega t)``, ``S2 = t - sin(omega t) / omega``,
``C2 = t^2 / 2 - (1 - cos(omega t)) / omega^2``::

    dv_N(t) =  omega R S phi_E + R w_N C1 phi_D - R C1 eps_E - R w_N S2 eps_D
    dv_E(t) = -omega R S phi_N + R w_E C1 phi_D + R C1 eps_N - R w_E S2 eps_D
    dr_N(t) =  R C1 phi_E + R w_N S2 phi_D - R S2 eps_E - R w_N C2 eps_D
    dr_E(t) = -R C1 phi_N + R w_E S2 phi_D + R S2 eps_N - R w_E C2 eps_D

(each channel with its own omega and R: omega_N, R_M + h for dv_N, dr_N; omega_E, R_N + h
for dv_E, dr_E).

Derivation: differentiate the velocity row once, ``dv_N'' + omega^2 dv_N = g u(t)`` with the
forcing ``u = w_N phi_D(t) - eps_E``, ``phi_D(t) = phi_D0 - eps_D t``, and initial conditions
dv_N(0) = 0, dv_N'(0) = g phi_E0. A constant forcing u gives R u (1 - cos omega t), a ramp
c t gives R c (t - sin(omega t) / omega), the initial slope gives (g / omega) sin(omega t) =
omega R sin(omega t). The east channel is the same with phi_N -> -phi_N (dv_E' = -g phi_N)
and u = w_E phi_D - eps_N entering phi_N' with a minus sign: dv_E'' + omega^2 dv_E =
g (w_E phi_D + eps_N). Position rows are the time integrals of the velocity rows.

Sign note: the paper prints Phi rows (Eq. 10, 13) whose phi, eps and eps_U columns have the
opposite sign of what its own F (Eq. 6 and the north-channel analogue) gives: e.g. expm(F t)'s
east-velocity row has -omega_s R sin(omega_s t) in the phi_y (north tilt) column where the paper
prints +omega_s R sin(omega_s t). The forms above follow F (and the strapdown mechanization:
tests/unit/test_strapdown.py checks a 1 arcmin tilt gives dv_E = -omega R sin(omega t) phi_N).

Paper symbols <-> pospp (paper: ENU navigation frame, right-front-up body; the same
misalignment definition C_b^n' = (I - [phi x]) C_b^n and computed-minus-true errors)
-------------------------------------------------------------------------------------
==============  ====================  ============================================
paper           pospp (NED)           relation
==============  ====================  ============================================
phi_x (E)       phi_E                 phi_x = phi_E
phi_y (N)       phi_N                 phi_y = phi_N
phi_z (U)       phi_D                 phi_z = -phi_D
eps_E, eps_N    eps_E, eps_N          equal
eps_U           eps_D                 eps_U = -eps_D
dV_E, dV_N      dv_E, dv_N            equal
dV_U            dv_D                  dV_U = -dv_D
omega_s, R      omega_N/E, R_M/N + h  one Schuler frequency and radius in the paper
X_p             [phi_x, phi_y, phi_z, eps_E, eps_N] = PAPER_FROM_NED @ x_ned
==============  ====================  ============================================

with ``x_ned = [phi_N, phi_E, phi_D, eps_N, eps_E]`` (the column order of
:func:`velocity_error_rows`).

References
----------
Liu, Fang, "Online calibration of POS error based on double strapdown algorithm", Acta
Aeronautica et Astronautica Sinica, 2012, Eq. 3-14. Titterton & Weston (2004) Sec. 12.3
(Schuler loop).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp.earth import EARTH_RATE_RADPS, normal_gravity_mps2, principal_radii_m

STATES = ("dv_n", "dv_e", "phi_n", "phi_e", "phi_d", "eps_n", "eps_e", "eps_d", "dr_n", "dr_e")
"""Order of the simplified state vector (SI: m/s, rad, rad/s, m)."""
DV_N, DV_E, PHI_N, PHI_E, PHI_D, EPS_N, EPS_E, EPS_D, DR_N, DR_E = range(10)

XP_NED_NAMES = ("phi_n", "phi_e", "phi_d", "eps_n", "eps_e")
"""Column order of :func:`velocity_error_rows` (pospp NED names)."""
XP_PAPER_NAMES = ("phi_x", "phi_y", "phi_z", "eps_e", "eps_n")
"""The paper's X_p (ENU / right-front-up), :data:`PAPER_FROM_NED` maps NED -> paper."""

PAPER_FROM_NED = np.array(
    [
        [0.0, 1.0, 0.0, 0.0, 0.0],  # phi_x (E) = phi_E
        [1.0, 0.0, 0.0, 0.0, 0.0],  # phi_y (N) = phi_N
        [0.0, 0.0, -1.0, 0.0, 0.0],  # phi_z (U) = -phi_D
        [0.0, 0.0, 0.0, 0.0, 1.0],  # eps_E
        [0.0, 0.0, 0.0, 1.0, 0.0],  # eps_N
    ]
)
"""X_p(paper) = PAPER_FROM_NED @ [phi_N, phi_E, phi_D, eps_N, eps_E]; orthogonal, so its
transpose maps back."""
PAPER_FROM_NED.setflags(write=False)


def xp_paper_from_ned(x_ned: ArrayLike) -> NDArray:
    """[phi_N, phi_E, phi_D, eps_N, eps_E] (..., 5) -> paper X_p [phi_x, phi_y, phi_z, eps_E,
    eps_N] (..., 5); units unchanged."""
    return np.asarray(x_ned, dtype=float) @ PAPER_FROM_NED.T


def xp_ned_from_paper(x_paper: ArrayLike) -> NDArray:
    """Inverse of :func:`xp_paper_from_ned`."""
    return np.asarray(x_paper, dtype=float) @ PAPER_FROM_NED


def _channel_constants(lat_rad: float, height_m: float, v_n_mps: ArrayLike):
    v = np.asarray(v_n_mps, dtype=float).reshape(-1)
    if v.shape[0] not in (2, 3) or not np.all(np.isfinite(v)):
        raise ValueError(f"v_n_mps: expected 2 or 3 finite NED components, got {v_n_mps!r}")
    lat = float(lat_rad)
    h = float(height_m)
    if not (np.isfinite(lat) and abs(lat) < np.pi / 2 and np.isfinite(h)):
        raise ValueError(f"lat_rad, height_m: expected |lat| < pi/2 and finite, got {lat}, {h}")
    r_m, r_n = principal_radii_m(lat)
    r_north = float(r_m) + h  # north channel: dlat = dr_N / (R_M + h)
    r_east = float(r_n) + h  # east channel
    g = float(normal_gravity_mps2(lat, h))
    w_n = EARTH_RATE_RADPS * np.cos(lat) + v[1] / r_east
    w_e = -v[0] / r_north
    return g, r_north, r_east, w_n, w_e


def schuler_frequencies_radps(lat_rad: float, height_m: float) -> tuple[float, float]:
    """(omega_N, omega_E) = sqrt(g / (R_M + h)), sqrt(g / (R_N + h)) [rad/s]."""
    g, r_north, r_east, _, _ = _channel_constants(lat_rad, height_m, [0.0, 0.0])
    return float(np.sqrt(g / r_north)), float(np.sqrt(g / r_east))


def simplified_f_matrix(*, lat_rad: float, height_m: float, v_n_mps: ArrayLike) -> NDArray:
    """The simplified horizontal error dynamics F (10x10) of the module docstring (NED).

    Parameters
    ----------
    lat_rad, height_m : float
        Latitude [rad] and ellipsoidal height [m] of the leg.
    v_n_mps : array_like, shape (2,) or (3,)
        Constant leg velocity, NED [m/s] (only north and east enter).

    Returns
    -------
    ndarray, shape (10, 10)
        ``x' = F x`` for the state order :data:`STATES`.
    """
    g, r_north, r_east, w_n, w_e = _channel_constants(lat_rad, height_m, v_n_mps)
    f = np.zeros((10, 10))
    f[DV_N, PHI_E] = g
    f[DV_E, PHI_N] = -g
    f[PHI_N, DV_E] = 1.0 / r_east
    f[PHI_N, PHI_D] = -w_e
    f[PHI_N, EPS_N] = -1.0
    f[PHI_E, DV_N] = -1.0 / r_north
    f[PHI_E, PHI_D] = w_n
    f[PHI_E, EPS_E] = -1.0
    f[PHI_D, EPS_D] = -1.0
    f[DR_N, DV_N] = 1.0
    f[DR_E, DV_E] = 1.0
    return f


def _sin_terms(x: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """sin x, 1 - cos x, x - sin x, x^2/2 - (1 - cos x), without cancellation for small x."""
    s = np.sin(x)
    c1 = 2.0 * np.sin(0.5 * x) ** 2
    small = np.abs(x) < 0.5
    x2 = x * x
    # x - sin x = x^3/6 - x^5/120 + ... ; x^2/2 - 1 + cos x = x^4/24 - x^6/720 + ...
    s2_series = np.zeros_like(x)
    c2_series = np.zeros_like(x)
    term_s = x * x2 / 6.0
    term_c = x2 * x2 / 24.0
    for k in range(8):  # truncation below 1e-16 relative for |x| < 0.5
        s2_series += term_s
        c2_series += term_c
        term_s = -term_s * x2 / ((2 * k + 4) * (2 * k + 5))
        term_c = -term_c * x2 / ((2 * k + 5) * (2 * k + 6))
    s2 = np.where(small, s2_series, x - s)
    c2 = np.where(small, c2_series, 0.5 * x2 - c1)
    return s, c1, s2, c2


def horizontal_error_rows(
    t_s: ArrayLike, *, lat_rad: float, height_m: float, v_n_mps: ArrayLike
) -> NDArray:
    """Closed-form rows of Phi(t) = expm(F t) for the horizontal velocity and position errors.

    Parameters
    ----------
    t_s : array_like, shape (M,)
        Times since the leg start [s].
    lat_rad, height_m : float
        Latitude [rad] and ellipsoidal height [m] of the leg.
    v_n_mps : array_like, shape (2,) or (3,)
        Constant leg velocity, NED [m/s].

    Returns
    -------
    ndarray, shape (M, 4, 6)
        Rows [dv_N, dv_E, dr_N, dr_E] (m/s, m), columns [phi_N, phi_E, phi_D, eps_N, eps_E,
        eps_D] (rad, rad/s): the error at t caused by a unit misalignment at the leg start or a
        unit constant navigation-frame drift (module docstring; equal to the corresponding
        block of ``expm(simplified_f_matrix(...) * t)``).
    """
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    if t.ndim != 1 or not np.all(np.isfinite(t)):
        raise ValueError(f"t_s: expected a finite 1-D array, got shape {t.shape}")
    g, r_north, r_east, w_n, w_e = _channel_constants(lat_rad, height_m, v_n_mps)
    om_n = np.sqrt(g / r_north)
    om_e = np.sqrt(g / r_east)
    sn, c1n, s2n, c2n = _sin_terms(om_n * t)
    se, c1e, s2e, c2e = _sin_terms(om_e * t)
    # in units of t: (1 - cos)/omega^0, (t - sin(wt)/w) = s2/w, (t^2/2 - (1-cos)/w^2) = c2/w^2
    out = np.zeros((t.shape[0], 4, 6))
    # north velocity: dv_N'' + om^2 dv_N = g (w_N phi_D(t) - eps_E), dv_N'(0) = g phi_E0
    out[:, 0, 1] = om_n * r_north * sn
    out[:, 0, 2] = r_north * w_n * c1n
    out[:, 0, 4] = -r_north * c1n
    out[:, 0, 5] = -r_north * w_n * s2n / om_n
    # east velocity: dv_E'' + om^2 dv_E = g (w_E phi_D(t) + eps_N), dv_E'(0) = -g phi_N0
    out[:, 1, 0] = -om_e * r_east * se
    out[:, 1, 2] = r_east * w_e * c1e
    out[:, 1, 3] = r_east * c1e
    out[:, 1, 5] = -r_east * w_e * s2e / om_e
    # positions: time integrals of the velocity rows
    out[:, 2, 1] = r_north * c1n
    out[:, 2, 2] = r_north * w_n * s2n / om_n
    out[:, 2, 4] = -r_north * s2n / om_n
    out[:, 2, 5] = -r_north * w_n * c2n / om_n**2
    out[:, 3, 0] = -r_east * c1e
    out[:, 3, 2] = r_east * w_e * s2e / om_e
    out[:, 3, 3] = r_east * s2e / om_e
    out[:, 3, 5] = -r_east * w_e * c2e / om_e**2
    return out


def velocity_error_rows(
    t_s: ArrayLike, *, lat_rad: float, height_m: float, v_n_mps: ArrayLike
) -> NDArray:
    """Paper Eq. 10 / 13 in pospp's conventions: horizontal velocity error per unit of X_p.

    ``[dv_N(t), dv_E(t)] = rows[t] @ [phi_N, phi_E, phi_D, eps_N, eps_E]`` for a leg starting
    with zero velocity error, misalignment phi (NED, rad, C_nb_hat = (I - [phi x]) C_nb) and a
    constant navigation-frame gyro drift eps_n = C_nb b_g (rad/s); errors computed minus true.

    Parameters
    ----------
    t_s : array_like, shape (M,)
        Times since the leg start [s].
    lat_rad, height_m : float
        Latitude [rad] and ellipsoidal height [m] of the leg.
    v_n_mps : array_like, shape (2,) or (3,)
        Constant leg velocity, NED [m/s].

    Returns
    -------
    ndarray, shape (M, 2, 5)
        Rows [dv_N, dv_E] [m/s]; columns [phi_N, phi_E, phi_D] [per rad] and [eps_N, eps_E]
        [per rad/s]. Map to the paper's X_p with :data:`PAPER_FROM_NED`:
        ``rows_paper = rows @ PAPER_FROM_NED.T``.
    """
    return horizontal_error_rows(t_s, lat_rad=lat_rad, height_m=height_m, v_n_mps=v_n_mps)[
        :, 0:2, 0:5
    ]
