"""A's navigation solution at its output epochs: states and their covariance.

:class:`NavSolution` is what :func:`pospp.nav.filter.run_integrated_navigation` returns for
its forward and smoothed passes. Its covariance blocks are stored packed (upper triangles,
:func:`pospp.nav.smoother.pack_symmetric`): P is exactly symmetric, so the full blocks and
the sigmas are made from them, when asked, without loss.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pospp import rotation
from pospp.nav.error_model import rpy_covariance
from pospp.nav.smoother import unpack_symmetric
from pospp.nav.strapdown import Trajectory

_DIAGONAL3 = np.array([0, 3, 5])
"""Where the diagonal of a packed symmetric 3 x 3 matrix sits (:class:`NavSolution`)."""


@dataclass(frozen=True)
class NavSolution:
    """Navigation solution with its uncertainty at N output epochs (time-major arrays).

    Position and attitude are those of the IMU. The covariances are the filter's P blocks of
    the position (NED, m^2), velocity (NED, m^2/s^2) and misalignment phi (NED, rad^2)
    errors, each stored as its upper triangle row by row, (N, 6): [xx, xy, xz, yy, yz, zz]
    (:func:`pospp.nav.smoother.pack_symmetric`; P is exactly symmetric). The full (N, 3, 3)
    blocks and the sigmas (square roots of their diagonals) are made from them when asked.
    Attitude sigmas: ``att_sigma_ned_rad`` of phi, and ``rpy_sigma_rad`` of [roll, pitch,
    yaw] mapped by d(rpy) = -E^-1 phi, where E maps Euler angle rates to the NED rotation rate
    (z-y-x, :func:`pospp.nav.error_model.rpy_covariance`).
    """

    time_ns: NDArray
    t_s: NDArray
    lat_rad: NDArray
    lon_rad: NDArray
    height_m: NDArray
    v_n_mps: NDArray
    q_nb: NDArray
    pos_cov_packed_ned_m2: NDArray
    vel_cov_packed_ned_m2ps2: NDArray
    att_cov_packed_ned_rad2: NDArray

    def __len__(self) -> int:
        return self.t_s.shape[0]

    @property
    def pos_cov_ned_m2(self) -> NDArray:
        """(N, 3, 3) position covariance, NED [m^2]."""
        return unpack_symmetric(self.pos_cov_packed_ned_m2, 3)

    @property
    def vel_cov_ned_m2ps2(self) -> NDArray:
        """(N, 3, 3) velocity covariance, NED [m^2/s^2]."""
        return unpack_symmetric(self.vel_cov_packed_ned_m2ps2, 3)

    @property
    def att_cov_ned_rad2(self) -> NDArray:
        """(N, 3, 3) misalignment phi covariance, NED [rad^2]."""
        return unpack_symmetric(self.att_cov_packed_ned_rad2, 3)

    @property
    def pos_sigma_ned_m(self) -> NDArray:
        """(N, 3) position sigmas, NED [m]."""
        return np.sqrt(self.pos_cov_packed_ned_m2[:, _DIAGONAL3])

    @property
    def vel_sigma_ned_mps(self) -> NDArray:
        """(N, 3) velocity sigmas, NED [m/s]."""
        return np.sqrt(self.vel_cov_packed_ned_m2ps2[:, _DIAGONAL3])

    @property
    def att_sigma_ned_rad(self) -> NDArray:
        """(N, 3) misalignment phi sigmas, NED [rad]."""
        return np.sqrt(self.att_cov_packed_ned_rad2[:, _DIAGONAL3])

    @property
    def rpy_sigma_rad(self) -> NDArray:
        """(N, 3) [roll, pitch, yaw] sigmas [rad]: sqrt(diag(E^-1 P_phiphi E^-T))."""
        rpy_cov = rpy_covariance(self.q_nb, self.att_cov_ned_rad2)
        return np.sqrt(np.clip(np.diagonal(rpy_cov, axis1=1, axis2=2), 0.0, None))

    @property
    def rpy_rad(self) -> NDArray:
        """[roll, pitch, yaw] (rad), yaw in [0, 2 pi)."""
        return rotation.euler_from_quat(self.q_nb)

    @property
    def trajectory(self) -> Trajectory:
        """The states as a :class:`pospp.nav.strapdown.Trajectory`."""
        return Trajectory(self.t_s, self.lat_rad, self.lon_rad, self.height_m, self.v_n_mps,
                          self.q_nb)
