"""Step 0 of the comparison: the base model fitted to the log (docs/compare_sim.md).

The configured grade is only the prior. Before any effect is looked for, the levels a
simulation must have to be the same kind of flight are measured on the log itself, each with
a 1-sigma, and the flight is simulated with them:

* **IMU white noise** (gyro ARW, accelerometer VRW, per axis): the level of the Welch power
  spectrum of the samples (4 s segments, linear detrend) over [``WHITE_F_LO_HZ``,
  f_Nyquist], its lines (bins above ``LINE_FACTOR`` x the median) left out, on the static
  parts when they last ``STATIC_MIN_S`` (else the whole flight: the statistics it must
  match, ``imu_hf_*``, ``imu_band_*``, are the whole flight's, and the steady parts of a car
  or a drone shake less than the rest): a white rate noise of
  variance s^2 per sample at f_s has the one-sided spectrum 2 s^2 / f_s, and ARW =
  s sqrt(dt). The trajectory's own power there (the error-free simulated IMU on the same
  parts, :class:`pospp.sim.api.Kinematics`) is subtracted. Sigma: batch means over up to
  ``N_PIECES`` pieces of the parts used.
* **Gyro bias instability** (Gauss-Markov sigma at the grade's correlation time T, one for
  the three axes): the Allan variance at ``GM_TAU_S`` on the static parts, less the white noise's
  N^2 / tau and the trajectory's (the error-free simulation's, same parts), divided by the
  Gauss-Markov Allan variance per unit variance (:func:`gm_allan_per_variance`). Fitted as
  a variance q >= 0 (its sigma from the Allan products), reported as sqrt(q) with the upper
  1-sigma distance sqrt(q + sigma_q) - sqrt(q): never negative. Without ``STATIC_MIN_S`` of
  static data the grade's value is kept and said so.
* **GNSS white noise** (position and velocity, horizontal and vertical): from the residuals
  about A's smoothed solution (antenna lever arm included), half the mean square of their
  differences L = 1, 2, 3 records apart, extrapolated along a straight line to L = 0
  (:func:`gnss_white_noise`): the white variance without what A's slow error or a slow
  coloured GNSS error change in a few records. Sigma: batch means. The whiteness is the
  residuals' lag-1 autocorrelation (sigma 1 / sqrt(n)), reported only: a coloured error is
  the library's ``coloured_gnss``.

The vibration is none: a platform's, not the sensor's (the ``mems`` preset's, the ArduPilot
plane's propeller, put comma2k19's high-frequency accelerometer variance 25 sigma above the
measured): it is the library's ``vibration``. The constant
biases, the accelerometer's Gauss-Markov part and the correlation times stay the grade's (A
estimates the biases on both flights; A's own estimate would carry the effects into the base
model, docs/compare_sim.md). A parameter whose fit differs
from the prior by more than ``DIFFERS_SIGMAS`` sigma and ``DIFFERS_FRACTION`` of the prior
is reported as such ("gyro ARW x 0.0020 +- 0.0001 deg/sqrt(h) fitted, grade 0.01"), never as
an effect.

Frames and units: body FRD, NED, SI inside; the parameters are reported in the units of the
sensor model's fields (:class:`pospp.sim.sensors.ImuErrorModel`,
:class:`pospp.sim.gnss.GnssModel`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from pospp import earth
from pospp.sim.gnss import GnssModel
from pospp.sim.sensors import ImuErrorModel
from pospp.simcompare.stats import allan_products
from pospp.units import (
    DEG_PER_H_RADPS,
    DEG_PER_SQRT_H_RAD_PER_SQRT_S,
    MPS_PER_SQRT_H_MPS_PER_SQRT_S,
)

__all__ = ["BaseFit", "BaseParameter", "ImuParts", "fit_base_model", "gm_allan_per_variance",
           "gnss_white_noise", "gyrocompass_resolves", "imu_white_noise", "has_drift"]

WHITE_F_LO_HZ = 2.0
"""Lowest frequency of the white-noise band [Hz] (the trajectory's power is below it)."""
SEGMENT_S = 4.0
"""Welch segment [s]."""
LINE_FACTOR = 5.0
"""Spectrum bins above this times the band's median are lines (vibration), left out."""
N_PIECES = 10
"""Pieces of the parts used, for the batch-means sigma of a level."""
STATIC_MIN_S = 60.0
"""Static parts shorter than this in all: the steady parts give the white noise, and the bias
instability is not fitted (the grade's kept)."""
GM_TAU_S = 10.0
"""Allan cluster time of the bias-instability fit [s]."""
KEEP_PRIOR_SIGMAS = 2.0
"""A variance-type level whose fit lies within this many sigmas of the prior (on the variance)
is simulated at the prior: the grade is the prior, the log overrides it where it differs."""
DIFFERS_SIGMAS = 3.0
DIFFERS_FRACTION = 0.1
"""A fitted level is reported as differing from its prior beyond both."""


@dataclass(frozen=True)
class BaseParameter:
    """One fitted level of the base model.

    Attributes
    ----------
    name : str
        ``gyro_arw_x``, ``gnss_pos_noise_h``, ... (axis or channel in the suffix).
    value, sigma : float
        Fitted value and 1-sigma (for a level at its bound 0: the upper 1-sigma distance),
        in ``unit``.
    prior : float
        The grade's (or the receiver's reported) value, in ``unit``; NaN when none.
    unit : str
    source : str
        What it was measured on (or why the prior is kept).
    fitted : bool
        False: the flight does not determine it and the prior is kept.
    """

    name: str
    value: float
    sigma: float
    prior: float
    unit: str
    source: str
    fitted: bool = True
    z_zero: float = float("nan")
    """For a variance-type level: how many of its sigmas the fitted variance lies above 0."""
    model: float = float("nan")
    """The level simulated, in ``unit``: the fit, or the prior where the fit does not differ
    from it (``KEEP_PRIOR_SIGMAS``); NaN: ``value``."""

    @property
    def simulated(self) -> float:
        """The level the base model simulates (``model``, else ``value``)."""
        return self.value if math.isnan(self.model) else self.model

    @property
    def differs(self) -> bool:
        """The fit differs from the prior beyond DIFFERS_SIGMAS sigma and DIFFERS_FRACTION."""
        d = abs(self.value - self.prior)
        return bool(self.fitted and math.isfinite(self.prior) and self.sigma >= 0
                    and d > DIFFERS_SIGMAS * self.sigma and d > DIFFERS_FRACTION
                    * abs(self.prior))

    def text(self) -> str:
        """"gyro_arw_x 0.00201 +- 0.00007 deg_per_sqrt_h fitted, prior 0.01 (differs)"."""
        if not self.fitted:
            return f"{self.name} {self.prior:.4g} {self.unit} kept ({self.source})"
        prior = f", prior {self.prior:.4g}" if math.isfinite(self.prior) else ""
        kept = (" (consistent with the prior: simulated at it)"
                if self.simulated != self.value else "")
        return (f"{self.name} {self.value:.4g} +- {self.sigma:.2g} {self.unit} fitted"
                f"{prior}{' (differs)' if self.differs else kept}")


@dataclass(frozen=True)
class BaseFit:
    """The base model: its parameters and the simulation models made from them."""

    parameters: tuple[BaseParameter, ...]
    imu: ImuErrorModel
    gnss: GnssModel


@dataclass(frozen=True)
class ImuParts:
    """An IMU series and the parts of it to fit on.

    ``t_s`` (N,) stamps [s]; ``w_radps``, ``f_mps2`` (N, 3) body FRD; ``static``, ``steady``
    (N,) bool: at rest; steady (static included)."""

    t_s: NDArray
    w_radps: NDArray
    f_mps2: NDArray
    static: NDArray
    steady: NDArray


def _pieces(t: NDArray, mask: NDArray, dt: float) -> list[NDArray]:
    """Index arrays of the pieces of the stretches where ``mask`` holds (no gap above 1.5
    intervals), each at least one Welch segment, about a ``N_PIECES``-th of the total."""
    brk = np.flatnonzero(~mask[1:] | ~mask[:-1] | (np.diff(t) > 1.5 * dt)) + 1
    starts, ends = np.concatenate([[0], brk]), np.concatenate([brk, [t.size]])
    seg = round(SEGMENT_S / dt)
    runs = [(a, b) for a, b in zip(starts, ends, strict=True) if mask[a] and b - a >= seg]
    total = sum(b - a for a, b in runs)
    size = max(seg, total // N_PIECES)
    out = []
    for a, b in runs:
        k = max((b - a) // size, 1)
        edges = np.linspace(a, b, k + 1).astype(int)
        out += [np.arange(edges[i], edges[i + 1]) for i in range(k)]
    return out


def _spectrum(x: NDArray, dt: float) -> tuple[NDArray, NDArray]:
    """One piece's Welch spectrum (frequencies [Hz], (F, 3) one-sided PSD), segments of
    ``SEGMENT_S``, linear detrend."""
    from scipy.signal import welch

    return welch(x, fs=1.0 / dt, nperseg=round(SEGMENT_S / dt), detrend="linear", axis=0)


def imu_white_noise(t_s: NDArray, x: NDArray, mask: NDArray
                    ) -> tuple[NDArray, NDArray, float]:
    """Per-axis white variance per sample [unit^2] of ``x`` (N, 3) on ``mask``, its sigma
    (batch means over the pieces) and the seconds used; NaN with no piece.

    Each piece's level is the mean of its spectrum over the band's bins that are not lines;
    the lines are found on the spectrum averaged over all pieces (many segments, so a bin of
    noise is never 5 x the median there; on one piece of one or two segments 3 % of the bins
    are, and leaving them out read a white level 20 % low on 34 s of steady parts)."""
    dt = float(np.median(np.diff(t_s)))
    pieces = _pieces(t_s, mask, dt)
    if not pieces:
        return np.full(3, np.nan), np.full(3, np.nan), 0.0
    specs = [_spectrum(x[i], dt) for i in pieces]
    f = specs[0][0]
    n = np.array([i.size for i in pieces], dtype=float)
    band = f >= WHITE_F_LO_HZ
    if not band.any():
        return np.full(3, np.nan), np.full(3, np.nan), 0.0
    p = np.array([sp[1][band] for sp in specs])  # (pieces, bins, 3)
    avg = np.average(p, axis=0, weights=n)
    noise = avg <= LINE_FACTOR * np.median(avg, axis=0)
    lv = np.array([[pk[noise[:, i], i].mean() for i in range(p.shape[2])] for pk in p])
    lv = lv / (2.0 * dt)  # one-sided PSD 2 s^2 dt of a white series -> s^2
    mean = np.average(lv, axis=0, weights=n)
    sig = (np.sqrt(np.average((lv - mean) ** 2, axis=0, weights=n) / (len(pieces) - 1))
           if len(pieces) > 1 else np.abs(mean))
    return mean, sig, float(n.sum() * dt)


def gm_allan_per_variance(tau_s: float, corr_time_s: float) -> float:
    """Allan variance at ``tau_s`` of a first-order Gauss-Markov process of unit variance and
    correlation time T: (T / tau)^2 [2 (tau / T - 1 + e^(-tau/T)) - (1 - e^(-tau/T))^2]
    (from Var of the cluster integral 2 q T^2 (tau/T - 1 + e^(-tau/T)) and the neighbouring
    clusters' covariance q T^2 (1 - e^(-tau/T))^2; about 2 tau / (3 T) for tau << T)."""
    r = tau_s / corr_time_s
    e = math.exp(-r)
    return (2.0 * (r - 1.0 + e) - (1.0 - e) ** 2) / (r * r)


def _allan_per_axis(t: NDArray, x: NDArray, mask: NDArray, tau: float
                    ) -> tuple[NDArray, NDArray, int]:
    """Per-axis Allan variance at ``tau`` on ``mask`` with its sigma (std of the products /
    sqrt(n) x sqrt(1.5), as ``imu_avar_gyro_static``) and the number of products."""
    vals, sigs, n = np.full(3, np.nan), np.full(3, np.nan), 0
    for i in range(3):
        _, d = allan_products(t, x[:, i:i + 1], mask, tau)
        n = d.size
        if n >= 2:
            vals[i] = d.mean()
            sigs[i] = np.std(d, ddof=1) / math.sqrt(n) * math.sqrt(1.5)
    return vals, sigs, n


def _level_rows(name: str, unit: str, var: NDArray, sig_var: NDArray, per_unit: float,
                prior: NDArray, source: str) -> list[BaseParameter]:
    """Rows of a variance-type level fitted per axis (``name_x``, ...): sqrt of max(var, 0)
    in ``unit`` (SI / ``per_unit``), the upper 1-sigma distance sqrt(var + sigma_var) -
    sqrt(var) as its sigma (never negative, also at the bound 0). The grade is the prior: a
    fit within ``KEEP_PRIOR_SIGMAS`` of it (on the variance) keeps it (``model`` = prior), so
    a drift the flight cannot tell from 0 is still simulated (docs/compare_sim.md)."""
    out = []
    for i, a in zip(range(len(var)), "xyz", strict=False):
        v = max(float(var[i]), 0.0)
        s = math.sqrt(v + float(sig_var[i])) - math.sqrt(v)
        z = float(var[i]) / float(sig_var[i]) if sig_var[i] > 0 else math.inf
        q0 = (float(prior[i]) * per_unit) ** 2
        keep = abs(float(var[i]) - q0) <= KEEP_PRIOR_SIGMAS * float(sig_var[i])
        out.append(BaseParameter(f"{name}_{a}", math.sqrt(v) / per_unit, s / per_unit,
                                 float(prior[i]), unit, source, z_zero=z,
                                 model=float(prior[i]) if keep else math.sqrt(v) / per_unit))
    return out


def _imu_rows(meas: ImuParts, kin: ImuParts, grade: ImuErrorModel) -> list[BaseParameter]:
    """White noise and bias instability rows (module docstring)."""
    dt = float(np.median(np.diff(meas.t_s)))
    static_s = float(np.count_nonzero(meas.static)) * dt
    use_static = static_s >= STATIC_MIN_S
    where = "static parts" if use_static else "the whole flight (no static part of 60 s)"
    rows: list[BaseParameter] = []
    white = {}
    for kind, xm, xk, per, unit, prior in (
            ("gyro_arw", meas.w_radps, kin.w_radps, DEG_PER_SQRT_H_RAD_PER_SQRT_S,
             "deg_per_sqrt_h", grade.gyro_arw_dpsh),
            ("accel_vrw", meas.f_mps2, kin.f_mps2, MPS_PER_SQRT_H_MPS_PER_SQRT_S,
             "m_per_s_per_sqrt_h", grade.accel_vrw_mpsph)):
        mask_m, mask_k = ((meas.static, kin.static) if use_static else
                          (np.ones_like(meas.static), np.ones_like(kin.static)))
        vm, sm, used = imu_white_noise(meas.t_s, xm, mask_m)
        vk = imu_white_noise(kin.t_s, xk, mask_k)[0] if mask_k.any() else np.zeros(3)
        var = (vm - np.nan_to_num(vk)) * dt  # N^2 = s^2 dt [unit^2 s]
        src = f"Welch spectrum >= {WHITE_F_LO_HZ:.0f} Hz on {used:.0f} s of {where}"
        if not np.all(np.isfinite(var)):
            rows += [BaseParameter(f"{kind}_{a}", float(prior[i]), math.nan, float(prior[i]),
                                   unit, "no steady part of 4 s: the grade's", False)
                     for i, a in enumerate("xyz")]
            continue
        white[kind] = np.maximum(var, 0.0)
        rows += _level_rows(kind, unit, var, sm * dt, per, np.asarray(prior), src)
    rows += _gm_rows(meas, kin, grade, white.get("gyro_arw"), use_static)
    return rows


def _gm_rows(meas: ImuParts, kin: ImuParts, grade: ImuErrorModel, n2: NDArray | None,
             use_static: bool) -> list[BaseParameter]:
    """The gyro Gauss-Markov sigma from the static Allan variance (module docstring), one
    level for the three axes (their variances averaged: a per-axis fit on 300 s at rest read
    0, 1.75 and 1.88 deg/h of a 1.5 deg/h drift, and the axis fitted at 0 then drew none in
    the simulation while its real drift moved A's bias trend)."""
    prior = float(np.mean(grade.gyro_gm_sigma_dph))
    if not use_static or n2 is None:
        return [BaseParameter("gyro_gm_sigma", prior, math.nan, prior, "deg_per_h",
                              "no static part of 60 s: the grade's", False)]
    am, sm, n = _allan_per_axis(meas.t_s, meas.w_radps, meas.static, GM_TAU_S)
    ak = (_allan_per_axis(kin.t_s, kin.w_radps, kin.static, GM_TAU_S)[0]
          if kin.static.any() else np.zeros(3))
    g = gm_allan_per_variance(GM_TAU_S, grade.gyro_gm_tau_s)
    q = float(np.mean((am - np.nan_to_num(ak) - n2 / GM_TAU_S) / g))
    sq = float(np.sqrt(np.sum((sm / g) ** 2)) / 3.0)
    row = _level_rows("gyro_gm_sigma", "deg_per_h", np.array([q]), np.array([sq]),
                      DEG_PER_H_RADPS, np.array([prior]),
                      f"Allan variance at {GM_TAU_S:.0f} s on the static parts ({n} products "
                      f"per axis; the axes pooled), at the grade's {grade.gyro_gm_tau_s:.0f} "
                      "s")[0]
    return [replace(row, name="gyro_gm_sigma")]


GNSS_LAGS = (1, 2, 3)
"""Record lags of the GNSS residuals' structure function (:func:`gnss_white_noise`)."""


def _structure(t_s: NDArray, resid: NDArray, lag: int) -> tuple[NDArray, NDArray]:
    """Half the squared differences of the residuals ``lag`` records apart (consecutive in
    time: no gap), horizontal (mean of N and E) and vertical, each beyond 5 MAD of its
    differences left out (turns, jumps)."""
    dt = t_s[lag:] - t_s[:-lag]
    d = (resid[lag:] - resid[:-lag])[dt < (lag + 0.5) * np.median(np.diff(t_s))]
    mad = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    d = d[np.all(np.abs(d) <= 5.0 * np.maximum(mad, 1e-12), axis=1)]
    return 0.5 * np.mean(d[:, :2] ** 2, axis=1), 0.5 * d[:, 2] ** 2


def gnss_white_noise(t_s: NDArray, resid: NDArray) -> tuple[NDArray, NDArray, NDArray, int]:
    """GNSS white noise from the residuals ``resid`` (M, 3) NED about A's smoothed solution
    at the record times ``t_s``: (sigma horizontal and vertical (2,), their 1-sigma (2,),
    the residuals' lag-1 autocorrelation and its sigma (2,), records used).

    Half the mean square difference of residuals L records apart is the white variance plus
    what the slow errors (a coloured GNSS error, A's own) change in L records, which grows
    with L (for a Gauss-Markov error of sigma s and time T, s^2 (1 - exp(-L dt / T)), about
    s^2 L dt / T): the white variance is its straight line through L = 1, 2, 3 taken at
    L = 0 (a 0.3 m error of 60 s on 0.05 m white noise: 0.063 m from L = 1 alone, 0.05 m
    so). Sigma: the same on 10 blocks of the records (batch means)."""
    if t_s.size < 40:
        return np.full(2, np.nan), np.full(2, np.nan), np.full(2, np.nan), 0
    lags = np.asarray(GNSS_LAGS, dtype=float)
    design = np.column_stack([np.ones_like(lags), lags])

    def intercept(t: NDArray, r: NDArray) -> NDArray:
        parts = [_structure(t, r, int(lag)) for lag in lags]
        if any(x[0].size == 0 for x in parts):  # no records that far apart without a gap
            return np.full(2, np.nan)
        v = np.array([[x.mean() for x in part] for part in parts])
        return np.linalg.lstsq(design, v, rcond=None)[0][0]  # (2,): h, v at L = 0

    var = intercept(t_s, resid)
    blocks = np.array_split(np.arange(t_s.size), N_PIECES)
    per = np.array([intercept(t_s[b], resid[b]) for b in blocks])
    per = per[np.all(np.isfinite(per), axis=1)]
    if not np.all(np.isfinite(var)) or per.shape[0] < 2:
        return np.full(2, np.nan), np.full(2, np.nan), np.full(2, np.nan), 0
    sv = np.std(per, axis=0, ddof=1) / math.sqrt(per.shape[0])
    val = np.sqrt(np.clip(var, 0.0, None))
    sig = np.sqrt(np.clip(var, 0.0, None) + sv) - val
    e = resid - resid.mean(axis=0)
    lag1 = float(np.mean(e[1:, :2] * e[:-1, :2]) / np.mean(e[:, :2] ** 2))
    return val, sig, np.array([lag1, 1.0 / math.sqrt(t_s.size)]), int(t_s.size)


def _gnss_rows(kind: str, unit: str, t_s: NDArray, resid: NDArray, reported: tuple[float, float]
               ) -> tuple[list[BaseParameter], tuple[float, float] | None]:
    val, sig, lag, n = gnss_white_noise(t_s, resid)
    if not n:
        return [BaseParameter(f"gnss_{kind}_noise_{c}", reported[i], math.nan, reported[i],
                              unit, "fewer than 20 records: the reported sigma", False)
                for i, c in enumerate("hv")], None
    src = f"differences of consecutive residuals about A's smoothed solution ({n} records)"
    rows = [BaseParameter(f"gnss_{kind}_noise_{c}", float(val[i]), float(sig[i]),
                          float(reported[i]), unit, src) for i, c in enumerate("hv")]
    rows.append(BaseParameter(f"gnss_{kind}_lag1", lag[0], lag[1], 0.0, "-",
                              "lag-1 autocorrelation of the horizontal residuals (reported "
                              "only)"))
    return rows, (float(val[0]), float(val[1]))


def fit_base_model(meas: ImuParts, kin: ImuParts, grade: ImuErrorModel, gnss: GnssModel, *,
                   fix: tuple[NDArray, NDArray], vel: tuple[NDArray, NDArray]) -> BaseFit:
    """Step 0 (module docstring).

    Parameters
    ----------
    meas, kin : the log's IMU and the error-free simulation's, with their static and steady
        parts (the same parts of the same trajectory).
    grade : the configured grade's simulation model (the priors)
    gnss : the simulation's GNSS model from the log (rates, outages, reported sigmas, lever
        arm); its noise is replaced by the fit.
    fix, vel : (record times [s], (M, 3) residuals NED [m], [m/s]) about A's smoothed solution.
    """
    rows = _imu_rows(meas, kin, grade)
    pos_rows, pos = _gnss_rows("pos", "m", *fix, gnss.reported_pos_sigma_m or gnss.pos_noise_m)
    vel_rows, vel_n = _gnss_rows("vel", "m_per_s", *vel,
                                 gnss.reported_vel_sigma_mps or gnss.vel_noise_mps)
    rows += pos_rows + vel_rows
    by = {r.name: r for r in rows}

    def axes(name: str) -> tuple[float, float, float]:
        return tuple(float(by[f"{name}_{a}"].simulated)  # type: ignore[return-value]
                     for a in "xyz")

    gm = float(by["gyro_gm_sigma"].simulated)
    imu = replace(grade, gyro_arw_dpsh=axes("gyro_arw"), accel_vrw_mpsph=axes("accel_vrw"),
                  gyro_gm_sigma_dph=(gm, gm, gm), accel_vibration_rms_mps2=(0.0, 0.0, 0.0),
                  gyro_vibration_rms_dps=(0.0, 0.0, 0.0))
    g = replace(gnss, pos_noise_m=pos or gnss.pos_noise_m,
                vel_noise_mps=vel_n or gnss.vel_noise_mps)
    return BaseFit(tuple(rows), imu, g)


def has_drift(fit: BaseFit) -> bool:
    """The base model simulates a gyro Gauss-Markov drift (a level above 0 on some axis,
    fitted or the grade's): over a flight of minutes one random bias per axis, so the
    statistics that are a signed mean of it are one draw of it (``SimEffect.ensemble``),
    and the comparison takes their spread between draws of the base model (also where the
    fit was not significant: docs/compare_sim.md)."""
    return any(p.name == "gyro_gm_sigma" and p.simulated > 0.0 for p in fit.parameters)


def gyrocompass_resolves(fit: BaseFit, lat_rad: float) -> bool:
    """Whether step 0's gyro drift (``gyro_gm_sigma``, its fitted value) is below the Earth
    rate's horizontal part at ``lat_rad`` (11.5 deg/h at 40 deg): above it no static
    alignment can find north, and A as configured for a better gyro gyrocompasses tens of
    degrees off and diverges (:func:`pospp.compare_sim.compare_log` then re-runs it tuned to
    the fitted levels). A drift fitted above the grade's but below that (step 0 over-read a
    1.5 deg/h drift as 3.4 on one Monte Carlo seed, where A's resets came from a coloured
    GNSS error) leaves A as configured: re-tuned, A and its spread between draws hid every
    gap."""
    gm = {p.name: p for p in fit.parameters}.get("gyro_gm_sigma")
    if gm is None or not math.isfinite(gm.value):
        return True
    horizontal_dph = earth.EARTH_RATE_RADPS * math.cos(lat_rad) / DEG_PER_H_RADPS
    return gm.value < horizontal_dph
