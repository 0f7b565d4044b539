"""IMU grade presets and the noise parameters the integrated filter derives from them.

A preset (:class:`ImuTuning`) holds datasheet-style numbers with units in their names
(deg/h, deg/sqrt(h), ug, m/s/sqrt(h), s), the same keys as the ``[imu]`` section of a pipeline
configuration (:class:`pospp.config.ImuConfig`). :meth:`ImuTuning.noise` converts them once to
SI (:class:`NoiseParameters`), which is all the filter sees.

Bias model
----------
Each sensor bias is a random constant (turn-on bias, sigma ``*_bias_sigma_*``) plus a
first-order Gauss-Markov drift (sigma ``*_gm_sigma_*``, correlation time ``*_gm_tau_s``;
b_gm' = -b_gm / tau + w, PSD of w = 2 sigma_gm^2 / tau). By default the filter carries both
parts as states (constant: no process noise; Gauss-Markov: decay 1/tau and that PSD). With
``FilterOptions(gauss_markov_states=False)`` it carries one state per axis instead, a random
constant driven by white noise of PSD q = 2 sigma_gm^2 / tau (the short-term behaviour of
the drift) with initial variance sigma_bias^2 + sigma_gm^2 (cheaper, slightly conservative
over a few correlation times).

Scale factors (optional filter states): random constants with initial sigma
``*_sf_sigma_ppm`` (1 ppm = 1e-6), no process noise.

White noise: angle random walk ARW [deg/sqrt(h)] -> sqrt(PSD) [rad/sqrt(s)] = ARW * pi/180 / 60;
velocity random walk VRW [m/s/sqrt(h)] -> [m/s/sqrt(s)] = VRW / 60.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from pospp.units import DEG_PER_H_RADPS, UG_MPS2

"""One micro-g [m/s^2] (conventional g0)."""


@dataclass(frozen=True)
class NoiseParameters:
    """Filter noise model in SI units (per axis, identical on the three axes).

    Attributes
    ----------
    gyro_arw_radpsqrts : float
        Gyro white noise, sqrt(PSD) [rad/sqrt(s)] (angle random walk).
    accel_vrw_mpspsqrts : float
        Accelerometer white noise, sqrt(PSD) [m/s/sqrt(s)] (velocity random walk).
    gyro_bias_sigma_radps, accel_bias_sigma_mps2 : float
        Initial standard deviation of the bias states [rad/s], [m/s^2].
    gyro_bias_psd_radps2ps, accel_bias_psd_mps4ps : float
        PSD of the white noise driving the bias states [rad^2/s^3], [m^2/s^5].
    gyro_sf_sigma, accel_sf_sigma : float
        Initial standard deviation of the scale-factor states (dimensionless, 1e-6 = 1 ppm).
    gyro_turn_on_sigma_radps, accel_turn_on_sigma_mps2 : float
        The constant (turn-on) part of the biases, 1 sigma.
    gyro_gm_sigma_radps, accel_gm_sigma_mps2, gyro_gm_tau_s, accel_gm_tau_s : float
        The first-order Gauss-Markov part: steady-state sigma and correlation time [s].
    """

    gyro_arw_radpsqrts: float
    accel_vrw_mpspsqrts: float
    gyro_bias_sigma_radps: float
    accel_bias_sigma_mps2: float
    gyro_bias_psd_radps2ps: float
    accel_bias_psd_mps4ps: float
    gyro_sf_sigma: float = 0.0
    accel_sf_sigma: float = 0.0
    gyro_turn_on_sigma_radps: float = 0.0
    accel_turn_on_sigma_mps2: float = 0.0
    gyro_gm_sigma_radps: float = 0.0
    accel_gm_sigma_mps2: float = 0.0
    gyro_gm_tau_s: float = math.inf
    accel_gm_tau_s: float = math.inf


@dataclass(frozen=True)
class ImuTuning:
    """An IMU grade: datasheet numbers used to tune the integrated filter.

    Attributes
    ----------
    name : str
        Preset name.
    gyro_bias_sigma_dph : float
        Turn-on gyro bias, 1 sigma [deg/h].
    gyro_arw_dpsh : float
        Angle random walk [deg/sqrt(h)].
    gyro_gm_sigma_dph, gyro_gm_tau_s : float
        In-run gyro drift (first-order Gauss-Markov) sigma [deg/h] and correlation time [s].
    accel_bias_sigma_ug : float
        Turn-on accelerometer bias, 1 sigma [ug].
    accel_vrw_mpsph : float
        Velocity random walk [m/s/sqrt(h)].
    accel_gm_sigma_ug, accel_gm_tau_s : float
        In-run accelerometer drift sigma [ug] and correlation time [s].
    gyro_sf_sigma_ppm, accel_sf_sigma_ppm : float
        Scale-factor error, 1 sigma [ppm] (used only when the filter estimates scale factors).
    """

    name: str
    gyro_bias_sigma_dph: float
    gyro_arw_dpsh: float
    gyro_gm_sigma_dph: float
    gyro_gm_tau_s: float
    accel_bias_sigma_ug: float
    accel_vrw_mpsph: float
    accel_gm_sigma_ug: float
    accel_gm_tau_s: float
    gyro_sf_sigma_ppm: float = 100.0
    accel_sf_sigma_ppm: float = 100.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            if f.name == "name":
                continue
            value = getattr(self, f.name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0.0):
                raise ValueError(
                    f"ImuTuning.{f.name}: expected a finite number >= 0, got {value!r}")
        for tau in ("gyro_gm_tau_s", "accel_gm_tau_s"):
            if getattr(self, tau) <= 0.0:
                raise ValueError(f"ImuTuning.{tau}: expected > 0 s, got {getattr(self, tau)!r}")

    def with_overrides(self, **overrides: float | None) -> ImuTuning:
        """A copy with the given fields replaced; ``None`` values are ignored (config keys)."""
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise ValueError(
                f"ImuTuning: unknown field(s) {unknown}; expected some of {sorted(names)}")
        changes: dict[str, Any] = {k: float(v) for k, v in overrides.items() if v is not None}
        return dataclasses.replace(self, **changes)

    def noise(self) -> NoiseParameters:
        """Convert to SI filter parameters (see the module docstring for the bias model)."""
        deg = math.pi / 180.0
        g_gm = self.gyro_gm_sigma_dph * DEG_PER_H_RADPS
        a_gm = self.accel_gm_sigma_ug * UG_MPS2
        g_bias = self.gyro_bias_sigma_dph * DEG_PER_H_RADPS
        a_bias = self.accel_bias_sigma_ug * UG_MPS2
        return NoiseParameters(
            gyro_arw_radpsqrts=self.gyro_arw_dpsh * deg / 60.0,
            accel_vrw_mpspsqrts=self.accel_vrw_mpsph / 60.0,
            gyro_bias_sigma_radps=math.hypot(g_bias, g_gm),
            accel_bias_sigma_mps2=math.hypot(a_bias, a_gm),
            gyro_bias_psd_radps2ps=2.0 * g_gm**2 / self.gyro_gm_tau_s,
            accel_bias_psd_mps4ps=2.0 * a_gm**2 / self.accel_gm_tau_s,
            gyro_sf_sigma=self.gyro_sf_sigma_ppm * 1e-6,
            accel_sf_sigma=self.accel_sf_sigma_ppm * 1e-6,
            gyro_turn_on_sigma_radps=g_bias,
            accel_turn_on_sigma_mps2=a_bias,
            gyro_gm_sigma_radps=g_gm,
            accel_gm_sigma_mps2=a_gm,
            gyro_gm_tau_s=self.gyro_gm_tau_s,
            accel_gm_tau_s=self.accel_gm_tau_s,
        )


PRESETS: dict[str, ImuTuning] = {
    # the paper's flight IMU (Liu & Fang 2012): 1 deg/h constant drift, 0.5 deg/h random drift
    # (a Gauss-Markov process of 300 s, the convention of pospp.sim and the reference cases);
    # the accelerometer sigma covers the 20 ug of the reference case
    "flight": ImuTuning(
        name="flight",
        gyro_bias_sigma_dph=1.0,
        gyro_arw_dpsh=0.01,
        gyro_gm_sigma_dph=0.5,
        gyro_gm_tau_s=300.0,
        accel_bias_sigma_ug=30.0,
        accel_vrw_mpsph=0.01,
        accel_gm_sigma_ug=5.0,
        accel_gm_tau_s=3600.0,
        gyro_sf_sigma_ppm=10.0,
        accel_sf_sigma_ppm=50.0,
    ),
    # land-vehicle POS with a better gyro (0.1 deg/h) used by the vehicle mission
    "vehicle": ImuTuning(
        name="vehicle",
        gyro_bias_sigma_dph=0.1,
        gyro_arw_dpsh=0.005,
        gyro_gm_sigma_dph=0.05,
        gyro_gm_tau_s=300.0,
        accel_bias_sigma_ug=30.0,
        accel_vrw_mpsph=0.01,
        accel_gm_sigma_ug=5.0,
        accel_gm_tau_s=3600.0,
        gyro_sf_sigma_ppm=10.0,
        accel_sf_sigma_ppm=50.0,
    ),
    # tactical grade (MEMS/FOG ~1-10 deg/h)
    "tactical": ImuTuning(
        name="tactical",
        gyro_bias_sigma_dph=10.0,
        gyro_arw_dpsh=0.15,
        gyro_gm_sigma_dph=1.0,
        gyro_gm_tau_s=600.0,
        accel_bias_sigma_ug=1000.0,
        accel_vrw_mpsph=0.06,
        accel_gm_sigma_ug=100.0,
        accel_gm_tau_s=600.0,
        gyro_sf_sigma_ppm=300.0,
        accel_sf_sigma_ppm=300.0,
    ),
    # consumer MEMS (deg/s-level turn-on biases, large random walks)
    "mems": ImuTuning(
        name="mems",
        gyro_bias_sigma_dph=1800.0,
        gyro_arw_dpsh=0.6,
        gyro_gm_sigma_dph=30.0,
        gyro_gm_tau_s=300.0,
        accel_bias_sigma_ug=20000.0,
        accel_vrw_mpsph=0.3,
        accel_gm_sigma_ug=1000.0,
        accel_gm_tau_s=300.0,
        gyro_sf_sigma_ppm=5000.0,
        accel_sf_sigma_ppm=5000.0,
    ),
}
"""IMU grade presets by name."""

ALIASES: dict[str, str] = {"consumer": "mems"}
"""Other names accepted by :func:`tuning_preset`."""


def tuning_preset(grade: str, **overrides: float | None) -> ImuTuning:
    """The preset ``grade`` ("flight", "vehicle", "tactical", "mems"/"consumer") with overrides.

    Overrides use the field names of :class:`ImuTuning` (the ``[imu]`` config keys); ``None``
    keeps the preset value.
    """
    try:
        base = PRESETS[ALIASES.get(grade, grade)]
    except KeyError:
        names = sorted([*PRESETS, *ALIASES])
        raise ValueError(f"unknown IMU grade {grade!r}; expected one of {names}") from None
    return base.with_overrides(**overrides)
