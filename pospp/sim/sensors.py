"""IMU error models applied to exact increments (sensors read true + error).

Frames and units: every per-axis parameter is on body FRD axes. Boundary names carry their
unit (``_dph`` deg/h, ``_dpsh`` deg/sqrt(h), ``_ug`` micro-g with g = 9.80665 m/s^2,
``_ugph`` ug per hour, ``_mpsph`` m/s/sqrt(h), ``_ppm``, ``_arcsec``, ``_s``); the arrays
returned are SI (rad, m/s).

Model, per IMU interval k of length dt (t_mid its midpoint, t from the mission start)::

    dtheta_meas = (I + M_g) dtheta_true + (b_g + r_g t_mid + x_g,k) dt + n_g,k
    dv_meas     = (I + M_a) dv_true     + (b_a + r_a t_mid + x_a,k) dt + n_a,k

- b: constant bias (``gyro_bias_dph``, ``accel_bias_ug``);
- r: bias drift in time, a ramp (``gyro_bias_drift_dphph``, ``accel_bias_drift_ugph``);
- x: first-order Gauss-Markov drift, stationary, sigma and correlation time tau
  (``gyro_gm_sigma_dph`` / ``gyro_gm_tau_s``; accel likewise): x_k+1 = e^(-dt/tau) x_k +
  sigma sqrt(1 - e^(-2 dt/tau)) w_k, x_0 ~ N(0, sigma^2). The paper's "random drift" is this
  sigma (docs/simulator.md);
- n: white noise on the increments, angle / velocity random walk: std = N sqrt(dt) with
  N = ``gyro_arw_dpsh`` (deg/sqrt(h)) or ``accel_vrw_mpsph`` (m/s/sqrt(h));
- M = diag(scale factor [ppm]) + misalignment (off-diagonal, [xy, xz, yx, yz, zx, zy] arcsec;
  M_ij = sensitivity of axis i to the input about/along axis j);
- vibration, a SENSOR error (the IMU case vibrates, the navigation point does not): per axis
  j a sinusoid v_j(t) = sqrt(2) rms_j sin(2 pi f t + phi_j) of frequency f
  (``vibration_freq_hz``, shared by all axes) with a seeded uniform random phase phi_j, RMS
  ``accel_vibration_rms_mps2`` / ``gyro_vibration_rms_dps``. It is integrated exactly over
  each interval, so the increments stay the exact interval means:

      int_t0^t1 v dt = 2 sqrt(2) rms / w * sin(w t_mid + phi) sin(w dt / 2),  w = 2 pi f.

  The sample (interval-mean) RMS is therefore rms |sinc(f dt)| (sinc(x) = sin(pi x)/(pi x)),
  and a frequency above the Nyquist rate aliases exactly as a real sampled IMU's does. The
  vibration's mean over any whole number of periods is zero. With ``vibration_bandwidth_hz``
  B > 0 the vibration is band-limited noise instead: per axis a sum of
  ``VIBRATION_TONES`` sinusoids of RMS rms / sqrt(n) each, frequencies uniform in
  [f - B/2, f + B/2] and phases uniform, all seeded, each integrated exactly as above (the
  total RMS is rms; the increments stay exact interval means).

Random streams are seeded per sensor (gyro, accel) from one ``numpy.random.SeedSequence``, so
the same seed gives bit-identical output. The vibration phases come from a third child of that
SeedSequence (spawn key index 2), drawn only when a vibration RMS is non-zero: a model without
vibration draws the same gyro and accelerometer bits as if vibration did not exist.
"""

from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass, field, fields
from importlib import resources
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from pospp.units import (
    ARCSEC_RAD,
    DEG_PER_H_RADPS,
    DEG_PER_SQRT_H_RAD_PER_SQRT_S,
    MPS_PER_SQRT_H_MPS_PER_SQRT_S,
    UG_MPS2,
)

__all__ = ["ImuErrorModel", "RealisedImuErrors", "apply_imu_errors", "imu_grade", "grade_names",
           "imu_model_file",
           "vibration_increments", "VIBRATION_TONES"]

def _zeros3() -> tuple[float, float, float]:
    return (0.0, 0.0, 0.0)


def _zeros6() -> tuple[float, ...]:
    return (0.0,) * 6


@dataclass(frozen=True)
class ImuErrorModel:
    """IMU error parameters (body FRD axes; units in the names). All default to zero, except
    the correlation times (300 s) and ``vibration_freq_hz`` (50 Hz, used only when a
    vibration RMS is non-zero)."""

    gyro_bias_dph: tuple[float, float, float] = field(default_factory=_zeros3)
    gyro_bias_drift_dphph: tuple[float, float, float] = field(default_factory=_zeros3)
    gyro_arw_dpsh: tuple[float, float, float] = field(default_factory=_zeros3)
    gyro_gm_sigma_dph: tuple[float, float, float] = field(default_factory=_zeros3)
    gyro_gm_tau_s: float = 300.0
    gyro_sf_ppm: tuple[float, float, float] = field(default_factory=_zeros3)
    gyro_misalign_arcsec: tuple[float, ...] = field(default_factory=_zeros6)
    accel_bias_ug: tuple[float, float, float] = field(default_factory=_zeros3)
    accel_bias_drift_ugph: tuple[float, float, float] = field(default_factory=_zeros3)
    accel_vrw_mpsph: tuple[float, float, float] = field(default_factory=_zeros3)
    accel_gm_sigma_ug: tuple[float, float, float] = field(default_factory=_zeros3)
    accel_gm_tau_s: float = 300.0
    accel_sf_ppm: tuple[float, float, float] = field(default_factory=_zeros3)
    accel_misalign_arcsec: tuple[float, ...] = field(default_factory=_zeros6)
    accel_vibration_rms_mps2: tuple[float, float, float] = field(default_factory=_zeros3)
    gyro_vibration_rms_dps: tuple[float, float, float] = field(default_factory=_zeros3)
    vibration_freq_hz: float = 50.0
    vibration_bandwidth_hz: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "vibration_bandwidth_hz":
                bw = float(v)
                if not 0.0 <= bw < 2.0 * float(self.vibration_freq_hz):
                    raise ValueError(f"vibration_bandwidth_hz must be in [0, 2 x "
                                     f"vibration_freq_hz), got {v!r}")
                object.__setattr__(self, f.name, bw)
                continue
            if f.name in _SCALAR_FIELDS:
                if not float(v) > 0.0:
                    raise ValueError(f"{f.name} must be > 0, got {v!r}")
                object.__setattr__(self, f.name, float(v))
                continue
            n = 6 if "misalign" in f.name else 3
            arr = np.broadcast_to(np.asarray(v, dtype=float), (n,))
            if not np.isfinite(arr).all():
                raise ValueError(f"{f.name}: non-finite value {v!r}")
            if any(k in f.name for k in ("arw", "vrw", "sigma", "rms")) and (arr < 0).any():
                raise ValueError(f"{f.name} must be >= 0, got {v!r}")
            object.__setattr__(self, f.name, tuple(float(x) for x in arr))

    @classmethod
    def from_dict(cls, d: dict[str, Any], *, source: str = "<dict>") -> ImuErrorModel:
        """From a dict with the field names (unknown keys are an error)."""
        names = {f.name for f in fields(cls)}
        bad = set(d) - names
        if bad:
            raise ValueError(f"{source}: unknown IMU error parameter(s) {sorted(bad)}; "
                             f"known: {sorted(names)}")
        return cls(**d)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dict (lists), field names as keys; the vibration keys only when a
        vibration RMS is non-zero."""
        d = {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}
        if not self.has_vibration():
            for k in _VIBRATION_FIELDS:
                d.pop(k)
        return d

    def has_vibration(self) -> bool:
        """True when an accelerometer or gyro vibration RMS is non-zero."""
        return bool(any(self.accel_vibration_rms_mps2) or any(self.gyro_vibration_rms_dps))

    def is_error_free(self) -> bool:
        return all(
            (v == 0.0 if isinstance(v, float) else not any(v))
            for k, v in asdict(self).items()
            if k not in _SCALAR_FIELDS and k != "vibration_bandwidth_hz"
        )

    def gyro_matrix(self) -> NDArray:
        """I + M_g (scale factor and misalignment), (3, 3)."""
        return _sf_misalign(self.gyro_sf_ppm, self.gyro_misalign_arcsec)

    def accel_matrix(self) -> NDArray:
        """I + M_a, (3, 3)."""
        return _sf_misalign(self.accel_sf_ppm, self.accel_misalign_arcsec)


_SCALAR_FIELDS = frozenset({"gyro_gm_tau_s", "accel_gm_tau_s", "vibration_freq_hz"})
"""Scalar, strictly positive fields (the rest are per-axis vectors)."""
_VIBRATION_FIELDS = ("accel_vibration_rms_mps2", "gyro_vibration_rms_dps", "vibration_freq_hz",
                     "vibration_bandwidth_hz")
VIBRATION_TONES = 16
"""Sinusoids per axis of band-limited vibration (``vibration_bandwidth_hz`` > 0)."""


def vibration_increments(t_s: NDArray, rms: NDArray, freq_hz: float | NDArray,
                         phase_rad: NDArray) -> NDArray:
    """Exact integrals of per-axis sinusoidal vibration over each interval.

    Integrates v_j(t) = sqrt(2) rms_j sin(2 pi f t + phi_j) from t_k to t_k+1 in closed form:
    2 sqrt(2) rms_j / w sin(w t_mid + phi_j) sin(w dt / 2), w = 2 pi f (module docstring).

    Parameters
    ----------
    t_s : (N + 1,) epochs [s].
    rms : (3,) vibration RMS per axis (any unit u; the result is in u s).
    freq_hz : float or (3,) array, > 0 (one frequency, or one per axis).
    phase_rad : (3,) phases phi_j [rad].

    Returns
    -------
    (N, 3) increments [u s].
    """
    t_s = np.asarray(t_s, dtype=float)
    dt = np.diff(t_s)
    f = np.broadcast_to(np.asarray(freq_hz, dtype=float), (3,))
    w = 2.0 * np.pi * f
    # phase of the midpoint reduced with the cycle count first (t f ~ 1e5 cycles)
    t_mid = 0.5 * (t_s[1:] + t_s[:-1])
    cyc = np.mod(t_mid[:, None] * f[None, :], 1.0)
    amp = 2.0 * np.sqrt(2.0) * np.asarray(rms, dtype=float) / w
    return (amp * np.sin(2.0 * np.pi * cyc + np.asarray(phase_rad)[None, :])
            * np.sin(0.5 * dt[:, None] * w[None, :]))


def _sf_misalign(sf_ppm, mis_arcsec) -> NDArray:
    m = np.eye(3) + np.diag(np.asarray(sf_ppm) * 1e-6)
    for (i, j), v in zip(((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)), mis_arcsec, strict=True):
        m[i, j] = v * ARCSEC_RAD
    return m


def grade_names() -> list[str]:
    """Names of the IMU grades in ``pospp/presets/imu.toml``."""
    text = resources.files("pospp").joinpath("presets", "imu.toml").read_text()
    return sorted(tomllib.loads(text))


def imu_grade(name: str) -> ImuErrorModel:
    """An IMU grade from ``pospp/presets/imu.toml``: ``errorfree``, ``paper_vehicle``
    (FOG: 0.1 deg/h constant, 0.05 deg/h random drift, 5 ug), ``paper_flight`` (flexure gyro:
    1 deg/h constant, 0.5 deg/h random drift, 5 ug), ``tactical``, ``mems`` (consumer MEMS
    with the measured ArduPilot plane's band-limited vibration, docs/simulator.md). A name
    ending in ``.toml`` is a model file (:func:`imu_model_file`), e.g. the one ``pospp
    compare-sim`` writes."""
    if name.endswith(".toml"):
        return imu_model_file(name)
    grades = tomllib.loads(resources.files("pospp").joinpath("presets", "imu.toml").read_text())
    if name not in grades:
        raise ValueError(f"unknown IMU grade {name!r}; grades: {sorted(grades)}")
    return ImuErrorModel.from_dict(grades[name], source=f"IMU grade {name}")


def imu_model_file(path: str) -> ImuErrorModel:
    """The ``[imu]`` table of a model TOML file (keys: the :class:`ImuErrorModel` fields).

    Written by ``pospp compare-sim`` (sim_model.toml, docs/compare_sim.md); its ``[gnss]``
    table holds :class:`pospp.sim.gnss.GnssModel` fields.
    """
    from pospp.io.files import open_regular

    with open_regular(path) as fh:
        data = tomllib.load(fh)
    return ImuErrorModel.from_dict(data.get("imu", {}), source=str(path))


@dataclass(frozen=True)
class RealisedImuErrors:
    """The error realisation of one run (SI, body FRD), per IMU interval.

    Attributes
    ----------
    gyro_bias_radps, accel_bias_mps2 : (N, 3)
        Total bias (constant + ramp + Gauss-Markov) over each interval; noise excluded.
    gyro_matrix, accel_matrix : (3, 3)
        I + M (scale factor and misalignment).
    """

    gyro_bias_radps: NDArray
    accel_bias_mps2: NDArray
    gyro_matrix: NDArray
    accel_matrix: NDArray


def _gauss_markov(rng: np.random.Generator, n: int, dt: float, sigma: NDArray,
                  tau: float) -> NDArray:
    """Stationary first-order Gauss-Markov sequence, shape (n, 3)."""
    if not np.any(sigma):
        return np.zeros((n, 3))
    a = np.exp(-dt / tau)
    w = rng.standard_normal((n, 3))
    w[0] = w[0] / np.sqrt(1.0 - a * a)  # x_0 ~ N(0, sigma^2) after scaling below
    x = lfilter([1.0], [1.0, -a], w, axis=0)
    return x * (sigma * np.sqrt(1.0 - a * a))


def apply_imu_errors(
    t_s: NDArray,
    dtheta_b_rad: NDArray,
    dv_b_mps: NDArray,
    model: ImuErrorModel,
    seed: int | np.random.SeedSequence,
) -> tuple[NDArray, NDArray, RealisedImuErrors]:
    """Corrupt exact increments per the model (module docstring).

    Parameters
    ----------
    t_s : (N + 1,) epochs [s]; uniform spacing is assumed for the Gauss-Markov step.
    dtheta_b_rad, dv_b_mps : (N, 3) exact increments.
    model : ImuErrorModel
    seed : int or SeedSequence
        Gyro and accelerometer streams are spawned from it.

    Returns
    -------
    dtheta_meas_rad, dv_meas_mps : (N, 3)
    realised : RealisedImuErrors
    """
    n = dtheta_b_rad.shape[0]
    dt = np.diff(t_s)
    dt_nom = float(np.median(dt)) if n else 0.0
    t_mid = 0.5 * (t_s[1:] + t_s[:-1])
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    rng_g, rng_a = (np.random.default_rng(s) for s in ss.spawn(2))
    mg, ma = model.gyro_matrix(), model.accel_matrix()

    def total_bias(const, ramp_ph, rng, gm_sigma, tau):
        # (const + ramp t) + Gauss-Markov, built in place (one (N, 3) array alive)
        b = np.empty((n, 3))
        b[:] = const
        if np.any(ramp_ph):
            b += np.outer(t_mid / 3600.0, ramp_ph)
        if np.any(gm_sigma):
            b += _gauss_markov(rng, n, dt_nom, gm_sigma, tau)
        return b

    bg = total_bias(np.asarray(model.gyro_bias_dph) * DEG_PER_H_RADPS,
                    np.asarray(model.gyro_bias_drift_dphph) * DEG_PER_H_RADPS, rng_g,
                    np.asarray(model.gyro_gm_sigma_dph) * DEG_PER_H_RADPS, model.gyro_gm_tau_s)
    ba = total_bias(np.asarray(model.accel_bias_ug) * UG_MPS2,
                    np.asarray(model.accel_bias_drift_ugph) * UG_MPS2, rng_a,
                    np.asarray(model.accel_gm_sigma_ug) * UG_MPS2, model.accel_gm_tau_s)
    sq = np.sqrt(dt)[:, None]
    arw = np.asarray(model.gyro_arw_dpsh) * DEG_PER_SQRT_H_RAD_PER_SQRT_S
    vrw = np.asarray(model.accel_vrw_mpsph) * MPS_PER_SQRT_H_MPS_PER_SQRT_S
    dth = dtheta_b_rad @ mg.T if not np.array_equal(mg, np.eye(3)) else dtheta_b_rad.copy()
    dvm = dv_b_mps @ ma.T if not np.array_equal(ma, np.eye(3)) else dv_b_mps.copy()
    dth += bg * dt[:, None]
    dvm += ba * dt[:, None]
    if np.any(arw):
        dth += rng_g.standard_normal((n, 3)) * arw * sq
    if np.any(vrw):
        dvm += rng_a.standard_normal((n, 3)) * vrw * sq
    if model.has_vibration():
        # a third child of the seed (as ss.spawn would give next), without mutating ss
        ss_v = np.random.SeedSequence(ss.entropy, spawn_key=(*ss.spawn_key, 2),
                                      pool_size=ss.pool_size)
        rng_v = np.random.default_rng(ss_v)
        ph = rng_v.uniform(0.0, 2.0 * np.pi, (2, 3))
        f0, bw = model.vibration_freq_hz, model.vibration_bandwidth_hz
        rms = (np.deg2rad(model.gyro_vibration_rms_dps),
               np.asarray(model.accel_vibration_rms_mps2))
        if bw == 0.0:
            tones = [(ph[i][None], np.full((1, 3), f0), rms[i]) for i in range(2)]
        else:  # band-limited: VIBRATION_TONES sinusoids per axis (module docstring)
            nt = VIBRATION_TONES
            fr = rng_v.uniform(f0 - 0.5 * bw, f0 + 0.5 * bw, (2, nt, 3))
            pt = rng_v.uniform(0.0, 2.0 * np.pi, (2, nt, 3))
            tones = [(pt[i], fr[i], rms[i] / np.sqrt(nt)) for i in range(2)]
        for out, (phases, freqs, amp) in zip((dth, dvm), tones, strict=True):
            if np.any(amp):
                for p_k, f_k in zip(phases, freqs, strict=True):
                    out += vibration_increments(t_s, amp, f_k, p_k)
    return dth, dvm, RealisedImuErrors(bg, ba, mg, ma)
