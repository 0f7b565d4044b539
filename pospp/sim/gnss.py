"""Simulated GNSS antenna fixes and velocities from a true motion.

Frames and units: lever arm ``lever_b`` in body FRD [m] from the IMU to the antenna phase
centre; positions geodetic WGS-84 (rad, m); velocities NED [m/s]; covariances NED.

What the receiver sees (exact rigid-body kinematics, nothing dropped):

    r_a = r + C_nb lever_b                      (applied as a small NED offset:
                                                 dlat = dN / (R_M + h), dlon = dE / ((R_N + h)
                                                 cos lat), dh = -dD; < 1 mm for lever < 10 m)
    v_a = v_n + C_nb (w_eb_b x lever_b),        w_eb_b = w_nb_b + C_bn w_en_n

(velocity relative to the Earth of a point fixed in the body). Time offset: the fix stamped
t is the antenna state at true time t - ``time_offset_s`` (a positive offset means the
receiver stamps late). Noise is white, Gaussian, independent per epoch: horizontal and
vertical standard deviations for position and velocity; the reported covariance is the
diagonal of those variances (not below a 1 mm, 1 mm/s floor), or of the ``reported_*``
sigmas when given. Epochs fall on multiples of
1 / ``rate_hz`` from the mission start, except inside outages [start_s, end_s).

Coloured position error (optional, off by default): a first-order Gauss-Markov error per NED
axis, stationary, horizontal / vertical sigma ``pos_gm_sigma_m`` and correlation time
``pos_gm_tau_s``, stepped at the epochs: e_k+1 = a e_k + sigma sqrt(1 - a^2) w_k,
a = exp(-dt_k / tau). It is added to the white noise; the reported covariance is unchanged
(a receiver does not report its multipath). The velocity may have one too
(``vel_gm_sigma_mps``, ``vel_gm_tau_s``), drawn after the position's. Drawn after the white
noise from the same stream, and only when a sigma is non-zero: a model without it draws the
same bits as if the error did not exist.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pospp import earth
from pospp.sim.imu import Motion, dcm_nb_from_euler
from pospp.sim.trajectory import MotionSample
from pospp.types import GnssFixes, GnssVelocities

__all__ = ["GnssModel", "antenna_state", "gnss_model_file", "simulate_gnss"]

_POS_FLOOR_M = 1e-3
_VEL_FLOOR_MPS = 1e-3


@dataclass(frozen=True)
class GnssModel:
    """GNSS simulation settings (units in the names).

    Attributes
    ----------
    rate_hz : float
    pos_noise_m : (horizontal, vertical) 1-sigma [m]
    vel_noise_mps : (horizontal, vertical) 1-sigma [m/s]
    lever_arm_b_m : (3,) IMU -> antenna in body FRD [m]
    time_offset_s : float
        Receiver stamp minus true time of the measured state [s].
    outages_s : tuple of (start_s, end_s)
        Windows (seconds from the mission start) with no GNSS output.
    pos_gm_sigma_m : (horizontal, vertical) sigma of the coloured position error [m]
    pos_gm_tau_s : float
        Its correlation time [s] (module docstring).
    vel_gm_sigma_mps : (horizontal, vertical) sigma of the coloured velocity error [m/s]
    vel_gm_tau_s : float
        Its correlation time [s] (a filtered receiver's velocity is correlated too).
    reported_pos_sigma_m, reported_vel_sigma_mps : (horizontal, vertical), optional
        The sigmas the receiver reports in the covariances, when they differ from the noise
        (default: the noise sigmas; real receivers often report nominal values).
    """

    rate_hz: float = 1.0
    pos_noise_m: tuple[float, float] = (0.05, 0.1)
    vel_noise_mps: tuple[float, float] = (0.02, 0.03)
    lever_arm_b_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    time_offset_s: float = 0.0
    outages_s: tuple[tuple[float, float], ...] = field(default_factory=tuple)
    pos_gm_sigma_m: tuple[float, float] = (0.0, 0.0)
    pos_gm_tau_s: float = 60.0
    reported_pos_sigma_m: tuple[float, float] | None = None
    reported_vel_sigma_mps: tuple[float, float] | None = None
    vel_gm_sigma_mps: tuple[float, float] = (0.0, 0.0)
    vel_gm_tau_s: float = 60.0

    def __post_init__(self) -> None:
        if not self.rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {self.rate_hz!r}")
        for name, n in (("pos_noise_m", 2), ("vel_noise_mps", 2), ("lever_arm_b_m", 3),
                        ("pos_gm_sigma_m", 2), ("vel_gm_sigma_mps", 2)):
            v = tuple(float(x) for x in getattr(self, name))
            if len(v) != n or not np.isfinite(v).all():
                raise ValueError(f"{name}: expected {n} finite numbers, got {v!r}")
            if ("noise" in name or "sigma" in name) and min(v) < 0:
                raise ValueError(f"{name} must be >= 0, got {v!r}")
            object.__setattr__(self, name, v)
        out = tuple((float(a), float(b)) for a, b in self.outages_s)
        for a, b in out:
            if not b > a:
                raise ValueError(f"outage ({a}, {b}): end must be after start")
        object.__setattr__(self, "outages_s", out)
        object.__setattr__(self, "rate_hz", float(self.rate_hz))
        object.__setattr__(self, "time_offset_s", float(self.time_offset_s))
        for name in ("reported_pos_sigma_m", "reported_vel_sigma_mps"):
            v = getattr(self, name)
            if v is not None:
                v = tuple(float(x) for x in v)
                if len(v) != 2 or not (np.isfinite(v).all() and min(v) >= 0):
                    raise ValueError(f"{name}: expected 2 finite numbers >= 0, got {v!r}")
                object.__setattr__(self, name, v)
        for name in ("pos_gm_tau_s", "vel_gm_tau_s"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")
            object.__setattr__(self, name, float(getattr(self, name)))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> GnssModel:
        return cls(**d)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dict; the coloured-error keys only when that error is on."""
        d = asdict(self)
        if not any(self.pos_gm_sigma_m):
            d.pop("pos_gm_sigma_m")
            d.pop("pos_gm_tau_s")
        if not any(self.vel_gm_sigma_mps):
            d.pop("vel_gm_sigma_mps")
            d.pop("vel_gm_tau_s")
        for k in ("reported_pos_sigma_m", "reported_vel_sigma_mps"):
            if d[k] is None:
                d.pop(k)
        return {k: ([list(x) for x in v] if k == "outages_s" else
                    (list(v) if isinstance(v, tuple) else v)) for k, v in d.items()}


def gnss_model_file(path: str) -> GnssModel | None:
    """The ``[gnss]`` table of a model TOML file (keys: the :class:`GnssModel` fields), None
    when the file has none.

    Written by ``pospp compare-sim`` (sim_model.toml, docs/compare_sim.md); its ``[imu]``
    table is read by :func:`pospp.sim.sensors.imu_model_file`.
    """
    import tomllib

    from pospp.io.files import open_regular

    with open_regular(path) as fh:
        data = tomllib.load(fh)
    if "gnss" not in data:
        return None
    known = set(GnssModel.__dataclass_fields__)
    unknown = sorted(set(data["gnss"]) - known)
    if unknown:
        raise ValueError(f"{path}: unknown [gnss] keys {unknown}; known: {sorted(known)}")
    return GnssModel.from_dict(data["gnss"])


def antenna_state(m: MotionSample, lever_b_m: ArrayLike) -> tuple[NDArray, NDArray, NDArray,
                                                                NDArray]:
    """True antenna (lat_rad, lon_rad, height_m, v_n_mps) of a motion sample (module doc)."""
    lever = np.asarray(lever_b_m, dtype=float)
    c_nb = dcm_nb_from_euler(m.rpy_rad)
    d_n = c_nb @ lever
    r_m, r_n = earth.principal_radii_m(m.lat_rad)
    lat = m.lat_rad + d_n[:, 0] / (r_m + m.height_m)
    lon = m.lon_rad + d_n[:, 1] / ((r_n + m.height_m) * np.cos(m.lat_rad))
    h = m.height_m - d_n[:, 2]
    roll, pitch = m.rpy_rad[:, 0], m.rpy_rad[:, 1]
    d = m.rpy_rate_radps
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    w_nb_b = np.stack([d[:, 0] - d[:, 2] * sp, d[:, 1] * cr + d[:, 2] * sr * cp,
                       -d[:, 1] * sr + d[:, 2] * cr * cp], axis=-1)
    w_en = earth.transport_rate_n_radps(m.lat_rad, m.height_m, m.v_n_mps)
    w_eb_b = w_nb_b + np.einsum("nji,nj->ni", c_nb, w_en)
    v = m.v_n_mps + np.einsum("nij,nj->ni", c_nb, np.cross(w_eb_b, lever))
    return lat, lon, h, v


def simulate_gnss(
    motion: Motion,
    duration_s: float,
    model: GnssModel,
    *,
    start_time_ns: int,
    seed: int | np.random.SeedSequence,
) -> tuple[GnssFixes, GnssVelocities]:
    """GNSS fixes and velocities over [0, duration_s] (module docstring).

    Returns
    -------
    fix : GnssFixes
    vel : GnssVelocities
        Same epochs as ``fix``.
    """
    step_ns = round(1e9 / model.rate_hz)
    k = np.arange(int(np.floor(duration_s * 1e9 / step_ns)) + 1, dtype=np.int64)
    t_rel_ns = k * step_ns
    t_s = t_rel_ns * 1e-9
    keep = np.ones(t_s.shape, bool)
    for a, b in model.outages_s:
        keep &= ~((t_s >= a) & (t_s < b))
    # the true state at t - offset must lie inside the mission
    t_true = t_s - model.time_offset_s
    keep &= (t_true >= 0.0) & (t_true <= duration_s)
    t_rel_ns, t_true = t_rel_ns[keep], t_true[keep]
    m = motion.evaluate(t_true)
    lat, lon, h, v = antenna_state(m, model.lever_arm_b_m)
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    rng = np.random.default_rng(ss)
    n = lat.size
    sp = np.array([model.pos_noise_m[0], model.pos_noise_m[0], model.pos_noise_m[1]])
    sv = np.array([model.vel_noise_mps[0], model.vel_noise_mps[0], model.vel_noise_mps[1]])
    e_p = rng.standard_normal((n, 3)) * sp
    e_v = rng.standard_normal((n, 3)) * sv
    if any(model.pos_gm_sigma_m):
        e_p += _gauss_markov_epochs(rng, t_true, model.pos_gm_sigma_m, model.pos_gm_tau_s)
    if any(model.vel_gm_sigma_mps):
        e_v += _gauss_markov_epochs(rng, t_true, model.vel_gm_sigma_mps, model.vel_gm_tau_s)
    r_m, r_n = earth.principal_radii_m(lat)
    lat = lat + e_p[:, 0] / (r_m + h)
    lon = lon + e_p[:, 1] / ((r_n + h) * np.cos(lat))
    h = h - e_p[:, 2]
    time_ns = np.int64(start_time_ns) + t_rel_ns
    pos_cov = np.zeros((n, 3, 3))
    if model.reported_pos_sigma_m is not None:
        h_, v_ = model.reported_pos_sigma_m
        sp = np.array([h_, h_, v_])
    if model.reported_vel_sigma_mps is not None:
        h_, v_ = model.reported_vel_sigma_mps
        sv = np.array([h_, h_, v_])
    pos_cov[:, [0, 1, 2], [0, 1, 2]] = np.maximum(sp, _POS_FLOOR_M) ** 2
    vel_cov = np.zeros((n, 3, 3))
    vel_cov[:, [0, 1, 2], [0, 1, 2]] = np.maximum(sv, _VEL_FLOOR_MPS) ** 2
    fix = GnssFixes(time_ns, lat, lon, h, pos_cov, np.zeros(n, dtype=np.int8))
    vel = GnssVelocities(time_ns.copy(), v + e_v, vel_cov)
    return fix, vel


def _gauss_markov_epochs(rng: np.random.Generator, t_s: NDArray, sigma_hv_m: tuple[float, float],
                         tau_s: float) -> NDArray:
    """Stationary first-order Gauss-Markov error at the (possibly gapped) epochs, (n, 3) NED."""
    sig = np.array([sigma_hv_m[0], sigma_hv_m[0], sigma_hv_m[1]])
    w = rng.standard_normal((t_s.size, 3))
    e = np.empty_like(w)
    if t_s.size == 0:
        return e
    e[0] = w[0] * sig
    a = np.exp(-np.diff(t_s) / tau_s)
    for k in range(1, t_s.size):
        e[k] = a[k - 1] * e[k - 1] + sig * np.sqrt(1.0 - a[k - 1] ** 2) * w[k]
    return e
