"""Short survey missions with Gauss-Markov gyro drift for the calibration's Monte Carlo.

Shared by tests/unit/test_calib_gm_montecarlo.py, tests/benchmarks/bench_calib_gm.py and
tests/benchmarks/bench_drift_sensitivity.py (:func:`run_modes`: the drift's correlation time
varied, and the causal compensation from a filter's forward bias estimate).
A mission: 30 s static, accelerate, then three 300 s survey legs joined by 180 deg turns
(flight: 60 m/s at 2600 m, 3 deg/s turns; vehicle: 9 m/s, 15 deg/s U-turns), 100 Hz, with
an IMU grade of pospp/presets/imu.toml (``paper_flight``, ``paper_vehicle``: constant drift +
first-order Gauss-Markov drift, ARW, accelerometer bias). Algorithm A is the simulation
truth with the accelerometer bias known (a converged filter's bias states).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pospp.calib.compensate import (
    causal_gyro_bias_b_radps,
    compensate_legs,
    prior_sigma_b_radps,
)
from pospp.calib.replay import ImuIncrements, ReplayOptions, solution_a_from_trajectory
from pospp.calib.solve import FitOptions, fit_calibration
from pospp.calib.stage import CalibrationOptions, calibrate_flight
from pospp.nav.filter import run_integrated_navigation
from pospp.nav.strapdown import increments_from_rates
from pospp.nav.tuning import tuning_preset
from pospp.sim.api import simulate
from pospp.sim.sensors import ImuErrorModel, imu_grade

G0_MPS2 = 9.80665
UG_MPS2 = 1e-6 * G0_MPS2

PROFILE = {
    "flight": """name = "gm_flight"
imu_rate_hz = 100
[start]
lat_deg = 34.25
lon_deg = 108.95
height_m = 2600.0
heading_deg = 0.0
[options]
turn_bank = "coordinated"
blend_s = 5.0
[[segment]]
type = "static"
duration_s = 30.0
[[segment]]
type = "accelerate"
to_speed_mps = 60.0
duration_s = 40.0
[[segment]]
type = "survey"
legs = 3
heading_deg = 0.0
leg_duration_s = 300.0
turn_rate_dps = 3.0
turn_direction = "alternate"
""",
    "vehicle": """name = "gm_vehicle"
imu_rate_hz = 100
[start]
lat_deg = 34.25
lon_deg = 108.95
height_m = 400.0
heading_deg = 30.0
[options]
turn_bank = "none"
blend_s = 3.0
[[segment]]
type = "static"
duration_s = 30.0
[[segment]]
type = "accelerate"
to_speed_mps = 9.0
duration_s = 20.0
[[segment]]
type = "survey"
legs = 3
heading_deg = 30.0
leg_duration_s = 300.0
turn_rate_dps = 15.0
turn_direction = "alternate"
""",
}
GRADE = {"flight": "paper_flight", "vehicle": "paper_vehicle"}
TUNING = {"flight": "flight", "vehicle": "vehicle"}  # pospp.nav.tuning presets of those IMUs


@dataclass(frozen=True)
class GmRun:
    """One Monte Carlo run: the constant bias's error and sigma, and B at the horizon."""

    err_b_radps: np.ndarray  # (2,) estimate minus the constant (turn-on) bias, x and y
    sigma_b_radps: np.ndarray  # (2,)
    gm_sigma_radps: float  # the noise model's Gauss-Markov sigma (given or REML)
    dv_mps: dict  # RMS over legs at the horizon: before, constant, per_leg, oracle
    dp_m: dict
    leg_drift_err_radps: np.ndarray  # per-leg (constant + smoothed drift) minus true mean, (L, 2)
    leg_const_err_radps: np.ndarray  # per-leg constant minus true mean, (L, 2)


def profile_path(kind: str, folder: Path) -> Path:
    p = Path(folder) / f"gm_{kind}.toml"
    p.write_text(PROFILE[kind])
    return p


def run_once(kind: str, seed: int, folder: Path, *, estimate_gm_sigma: bool = False) -> GmRun:
    """Simulate one mission and calibrate it with the Gauss-Markov noise model."""
    grade = GRADE[kind]
    sim = simulate(profile_path(kind, folder), imu_grade=grade, seed=seed, imu_rate_hz=100.0)
    t, dth, dv = increments_from_rates(sim.imu.time_ns, sim.imu.w_ib_b_radps,
                                       sim.imu.f_ib_b_mps2, epoch_ns=sim.start_time_ns)
    imu = ImuIncrements(t, dth, dv)
    model = ImuErrorModel.from_dict(sim.params["config"]["imu_errors"])
    ba = np.array(model.accel_bias_ug) * UG_MPS2
    a = solution_a_from_trajectory(sim.truth, v_sigma_n_mps=[0.02, 0.02, 0.03],
                                  accel_bias_b_mps2=ba)
    tun = tuning_preset(TUNING[kind])
    run = calibrate_flight(imu, a, CalibrationOptions(
        formulations=("body",), gyro_arw_dpsh=tun.gyro_arw_dpsh,
        gyro_gm_sigma_dph=None if estimate_gm_sigma else tun.gyro_gm_sigma_dph,
        gyro_gm_tau_s=tun.gyro_gm_tau_s))
    assert run.calibrated, run.reason
    cal = run.chosen
    const = np.array(model.gyro_bias_dph) * (np.pi / 180.0 / 3600.0)
    est = run.gyro_bias_b_radps
    sig = run.gyro_bias_sigma_b_radps
    # true realised mean bias over each leg (IMU interval k spans (t[k], t[k+1]])
    bias = sim.imu_errors.gyro_bias_radps
    true_mean, leg_drift, leg_const = {}, [], []
    for lid, rep in run.replays.items():
        k0 = int(np.searchsorted(t, rep.t0_s))
        k1 = int(np.searchsorted(t, rep.t0_s + rep.t_s[-1]))
        true_mean[lid] = bias[k0:k1].mean(axis=0)
        leg_drift.append((est + cal.leg_drift_b_radps(rep) - true_mean[lid])[0:2])
        leg_const.append((est - true_mean[lid])[0:2])
    kw = {"replay": ReplayOptions(horizon_s=300.0)}
    _, per_leg = compensate_legs(imu, a, run.replays, cal, per_leg_drift=True, **kw)
    _, oracle = compensate_legs(imu, a, run.replays, cal, gyro_bias_by_leg=true_mean, **kw)
    _, smooth = compensate_legs(imu, a, run.replays, cal, smoothed_drift=True, **kw)
    # prediction: calibrate on the first two legs only, compensate the last (not in the fit)
    ids = sorted(run.replays)
    pair = fit_calibration((run.replays[ids[0]], run.replays[ids[1]]), "body",
                           FitOptions(gyro_arw_radpsqrts=tun.gyro_arw_dpsh * np.pi / 180.0 / 60.0,
                                      gyro_gm_sigma_radps=cal.gyro_gm_sigma_radps,
                                      gyro_gm_tau_s=tun.gyro_gm_tau_s))
    last = {ids[-1]: run.replays[ids[-1]]}
    held = {k: compensate_legs(imu, a, last, pair, **kw, **opt)[1][0] for k, opt in (
        ("held_constant", {}), ("held_per_leg", {"per_leg_drift": True}),
        ("held_oracle", {"gyro_bias_by_leg": true_mean}))}

    def rms(vals):
        return float(np.sqrt(np.mean(np.square(vals))))

    dv_ = {"before": rms([i.vel_before_mps for i in run.improvements]),
           "constant": rms([i.vel_after_mps for i in run.improvements]),
           "per_leg": rms([i.vel_after_mps for i in per_leg]),
           "oracle": rms([i.vel_after_mps for i in oracle]),
           "smoothed": rms([i.vel_after_mps for i in smooth]),
           "held_before": held["held_constant"].vel_before_mps,
           **{k: v.vel_after_mps for k, v in held.items()}}
    dp_ = {"before": rms([i.pos_before_m for i in run.improvements]),
           "constant": rms([i.pos_after_m for i in run.improvements]),
           "per_leg": rms([i.pos_after_m for i in per_leg]),
           "oracle": rms([i.pos_after_m for i in oracle]),
           "smoothed": rms([i.pos_after_m for i in smooth]),
           "held_before": held["held_constant"].pos_before_m,
           **{k: v.pos_after_m for k, v in held.items()}}
    return GmRun(est[0:2] - const[0:2], sig[0:2], cal.gyro_gm_sigma_radps, dv_, dp_,
                 np.array(leg_drift), np.array(leg_const))


MODES = ("constant", "per_leg", "oracle", "causal", "weakened", "forward")
"""Compensation modes of :func:`run_modes` (see pospp.calib.compensate); "weakened" is the
causal mode with the calibrated prior's sigma times :data:`WEAKENED_PRIOR_FACTOR`, "forward"
the causal mode without the calibrated prior (A's forward estimate alone)."""
WEAKENED_PRIOR_FACTOR = 3.0


def run_modes(kind: str, seed: int, folder: Path, *, gm_tau_s: float | None = None,
              causal: bool = True) -> dict[str, float]:
    """B's error ratios at 300 s, before / after, per compensation mode, in-sample and held out.

    The mission of :func:`run_once` with the grade's Gauss-Markov correlation time replaced by
    ``gm_tau_s`` (the grade's when None); the calibration's noise model and the filter are
    given that same tau (the matched case: what each mode can reach when the drift's
    correlation time is known). A for B is the truth with the accelerometer bias known; the
    causal mode takes only the gyro-bias history of pospp's forward filter run on the
    simulated GNSS (grade tuning, tau replaced), fused with the calibrated bias as its prior.

    Returns
    -------
    dict
        ``"{in|held}_{mode}_{v|p}"``: ratio of B's horizontal velocity (position) error at
        300 s before / after; in-sample: RMS over the three legs of a joint fit; held out:
        the last leg, predicted from a fit of the first two. Also ``"in_before_v"`` etc.
    """
    grade = GRADE[kind]
    tun = tuning_preset(TUNING[kind])
    model = imu_grade(grade)
    if gm_tau_s is not None:
        model = dataclasses.replace(model, gyro_gm_tau_s=float(gm_tau_s))
        tun = dataclasses.replace(tun, gyro_gm_tau_s=float(gm_tau_s))
    sim = simulate(profile_path(kind, folder), imu_grade=model, seed=seed, imu_rate_hz=100.0)
    t, dth, dv = increments_from_rates(sim.imu.time_ns, sim.imu.w_ib_b_radps,
                                       sim.imu.f_ib_b_mps2, epoch_ns=sim.start_time_ns)
    imu = ImuIncrements(t, dth, dv)
    ba = np.array(model.accel_bias_ug) * UG_MPS2
    a = solution_a_from_trajectory(sim.truth, v_sigma_n_mps=[0.02, 0.02, 0.03],
                                  accel_bias_b_mps2=ba)
    gm_kw = {"gyro_arw_dpsh": tun.gyro_arw_dpsh, "gyro_gm_sigma_dph": tun.gyro_gm_sigma_dph,
             "gyro_gm_tau_s": tun.gyro_gm_tau_s}
    run = calibrate_flight(imu, a, CalibrationOptions(formulations=("body",), **gm_kw))
    assert run.calibrated, run.reason
    cal = run.chosen
    bias = sim.imu_errors.gyro_bias_radps
    true_mean = {}
    for lid, rep in run.replays.items():
        k0 = int(np.searchsorted(t, rep.t0_s))
        k1 = int(np.searchsorted(t, rep.t0_s + rep.t_s[-1]))
        true_mean[lid] = bias[k0:k1].mean(axis=0)
    ids = sorted(run.replays)
    pair = fit_calibration((run.replays[ids[0]], run.replays[ids[1]]), "body",
                           FitOptions(gyro_arw_radpsqrts=tun.gyro_arw_dpsh * np.pi / 180.0 / 60.0,
                                      gyro_gm_sigma_radps=cal.gyro_gm_sigma_radps,
                                      gyro_gm_tau_s=tun.gyro_gm_tau_s))
    pair_sigma = np.array([pair.sigma_of("gyro_bias_x"), pair.sigma_of("gyro_bias_y"), np.inf])
    fits = {"in": (cal, run.replays, run.gyro_bias_b_radps, run.gyro_bias_sigma_b_radps),
            "held": (pair, {ids[-1]: run.replays[ids[-1]]}, pair.gyro_bias_b_radps(),
                     pair_sigma)}
    fwd = None
    if causal:
        nav = run_integrated_navigation(sim.imu, sim.fix, sim.vel, tun,
                                        epoch_ns=sim.start_time_ns, output_rate_hz=10.0)
        fwd = nav.forward_biases
    out: dict[str, float] = {}
    kw = {"replay": ReplayOptions(horizon_s=300.0)}
    for where, (c, reps, b0, s0) in fits.items():
        opts: dict[str, dict] = {"constant": {}, "per_leg": {"per_leg_drift": True},
                                 "oracle": {"gyro_bias_by_leg": true_mean}}
        if fwd is not None:
            fused = causal_gyro_bias_b_radps(fwd.gyro_b_radps, fwd.gyro_sigma_b_radps, b0,
                                             prior_sigma_b_radps(s0, c))
            opts["causal"] = {"gyro_bias_history": (fwd.t_s, fused)}
            weak = causal_gyro_bias_b_radps(
                fwd.gyro_b_radps, fwd.gyro_sigma_b_radps, b0,
                WEAKENED_PRIOR_FACTOR * prior_sigma_b_radps(s0, c))
            opts["weakened"] = {"gyro_bias_history": (fwd.t_s, weak)}
            opts["forward"] = {"gyro_bias_history": (fwd.t_s, fwd.gyro_b_radps)}
        for mode, o in opts.items():
            _, imp = compensate_legs(imu, a, reps, c, **kw, **o)
            v0 = _rms([i.vel_before_mps for i in imp])
            p0 = _rms([i.pos_before_m for i in imp])
            out[f"{where}_before_v"], out[f"{where}_before_p"] = v0, p0
            out[f"{where}_{mode}_v"] = v0 / _rms([i.vel_after_mps for i in imp])
            out[f"{where}_{mode}_p"] = p0 / _rms([i.pos_after_m for i in imp])
    return out


def _rms(vals) -> float:
    return float(np.sqrt(np.mean(np.square(vals))))

