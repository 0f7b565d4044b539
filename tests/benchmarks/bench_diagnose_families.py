"""Power of the effect families on shapes the library was not first built from (issue 34).

    PYTHONPATH=. python tests/benchmarks/bench_diagnose_families.py \
        --cases accel:ramp:1000,accel:walk:300 --seeds 10 [--first-seed 1] [--crossing --n-legs 4]

Flights: tests/unit/test_diagnose_power.py's (pospp's simulator, paper_vehicle grade, three
wandering 180 s legs at 60 m/s after an S-turn, 1 Hz GNSS at 0.05 m / 0.025 m/s, the grade's
drift configured; ``--crossing``: the box of crossing lines at 40 / 80 m/s), seeds 1..N, with
one effect added to the simulated IMU samples afterwards (the GNSS is the true trajectory's,
so an IMU-side change is exactly a sensor error, and a change of the specific force by
``C_bn (g0 xi, g0 eta, 0)`` at the true position exactly a deflection (xi, eta) of the
vertical that normal gravity leaves out: the true g_n is ``(-g0 xi, -g0 eta, g)``):

``accel:ramp:R``  R ug/h on body x and -R/2 on y, from the first IMU stamp.
``accel:walk:S``  a random walk of the x and y biases whose RMS change over the flight is S ug
                  (Brownian paths, seeded by the flight's seed + 1000).
``accel:step:S``  S ug on x and -S/2 on y at the flight's middle.
``gyro:ramp:R``   R deg/h per hour on x and -R/2 on y.
``gyro:step:S``   S deg/h on x and -S/2 on y at the flight's middle.
``gravity:wave:A``  a deflection wave of amplitude A arcsec along the first leg's heading,
                  wavelength 30 km (the disturbing potential's cosine: xi, eta along it).
``gravity:bump:A``  a Gaussian bump of the potential (8 km radius) centred on the legs' mean
                  position, peak deflection A arcsec.

The pipeline's whole diagnosis (``pipeline.diagnose_calibration`` with the log and A, 6 null
realisations), then the refit. Per case: how often the family is named (in any shape), the
shapes named, the size error (the named effect's response on B minus A against the true one,
``rms(named - true) / rms(true)`` over the legs' samples; the true response from the known
change along B: :mod:`pospp.diagnose.sensor_families`, or the true field along each leg's
nominal track), and the calibrated gyro bias error before and after the refit [deg/h, norm of
x and y]. The detection limit of a shape: the smallest size named in at least 9 of 10 seeds.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "unit")]

import test_diagnose_power as tp  # noqa: E402
from _missions import SimLog  # noqa: E402

from pospp import earth, pipeline, rotation  # noqa: E402
from pospp.calib.null_covariance import with_null_covariance  # noqa: E402
from pospp.calib.replay import forced_response  # noqa: E402
from pospp.diagnose.refit import refit_calibration  # noqa: E402
from pospp.diagnose.sensor_families import sensor_family  # noqa: E402
from pospp.sim.api import simulate  # noqa: E402
from pospp.sim.gnss import GnssModel  # noqa: E402
from pospp.sim.profile import parse_profile  # noqa: E402
from pospp.sim.sensors import imu_grade  # noqa: E402
from pospp.units import ARCSEC_RAD, DEG_PER_H_RADPS, G0_MPS2, UG_MPS2  # noqa: E402

FAMILY = {"accel": "accel_bias_change", "gyro": "gyro_bias_change",
          "gravity": "gravity_disturbance"}
WAVELENGTH_M = 30_000.0
BUMP_RADIUS_M = 8_000.0


def _sensor_change(kind: str, shape: str, size: float, t: np.ndarray, seed: int) -> np.ndarray:
    """The body x, y bias change (N, 2) [SI] at run times ``t``."""
    unit = UG_MPS2 if kind == "accel" else DEG_PER_H_RADPS
    d = np.array([1.0, -0.5]) * size * unit
    if shape == "ramp":
        return np.outer(t / 3600.0, d)
    if shape == "step":
        return np.outer(t > 0.5 * t[-1], d)
    if shape == "walk":
        w = np.cumsum(np.random.default_rng(seed + 1000).normal(size=(t.size, 2)), axis=0)
        w -= w[0]
        return w / np.sqrt(np.mean(w**2)) * size * unit
    raise ValueError(shape)


def _deflection(shape: str, size: float, ne: np.ndarray, heading_rad: float,
                centre: np.ndarray) -> np.ndarray:
    """(xi, eta) [rad] at north/east positions ``ne`` (N, 2) [m]."""
    a = size * ARCSEC_RAD
    if shape == "wave":  # potential ~ cos(k s): deflection along the wave's direction
        u = np.array([np.cos(heading_rad), np.sin(heading_rad)])
        s = ne @ u
        return np.outer(a * np.sin(2 * np.pi * s / WAVELENGTH_M), u)
    if shape == "bump":  # potential ~ exp(-r^2 / 2 L^2): its gradient peaks at r = L
        r = ne - centre
        q = np.exp(-np.sum(r**2, axis=1) / (2 * BUMP_RADIUS_M**2))
        return a * np.sqrt(np.e) * r / BUMP_RADIUS_M * q[:, None]
    raise ValueError(shape)


def _ne(lat, lon, lat0, lon0) -> np.ndarray:
    """North and east of (lat0, lon0) [m], (N, 2) (a scalar position: (1, 2))."""
    r_m, r_n = earth.principal_radii_m(lat0)
    lat, lon = np.atleast_1d(lat), np.atleast_1d(lon)
    return np.stack([(lat - lat0) * r_m, (lon - lon0) * r_n * np.cos(lat0)], axis=1)


def flight(case: tuple[str, str, float], seed: int, crossing: bool, n_legs: int):
    """(log, config, simulation, true: callable(replays) -> the effect's response on B minus A
    per leg (M, 2) [m/s])."""
    kind, shape, size = case
    prof = tp.profile(180.0, n_legs, crossing=crossing)
    gnss = GnssModel(rate_hz=1.0, pos_noise_m=(0.05, 0.1), vel_noise_mps=(0.025, 0.05))
    sim = simulate(parse_profile(prof), imu_grade=imu_grade(tp.GRADE), gnss=gnss, seed=seed)
    imu = sim.imu
    t = (imu.time_ns - imu.time_ns[0]) * 1e-9
    tr = sim.truth
    lat0, lon0 = float(tr.lat_rad[0]), float(tr.lon_rad[0])
    if kind in ("accel", "gyro"):
        ch = _sensor_change(kind, shape, size, t, seed)
        name = "f_ib_b_mps2" if kind == "accel" else "w_ib_b_radps"
        arr = getattr(imu, name).copy()
        arr[:, 0:2] += ch
        imu = dataclasses.replace(imu, **{name: arr})

        def true(reps):
            c = [np.stack([np.interp(r.t0_s + r.t_s, t, ch[:, k]) for k in range(2)], axis=1)
                 for r in reps]
            # the gyro's constant part over the legs is the calibration's own bias
            mean = np.mean(np.concatenate(c), axis=0) if kind == "gyro" else 0.0
            fn = sensor_family(FAMILY[kind]).response_along_b
            return [fn(r, x - mean, x[0]) for r, x in zip(reps, c, strict=True)], mean
    else:
        mid = 0.5 * (tr.lat_rad[1:] + tr.lat_rad[:-1]), 0.5 * (tr.lon_rad[1:] + tr.lon_rad[:-1])
        ne = _ne(mid[0], mid[1], lat0, lon0)
        centre = np.mean([_ne(np.interp(lg.start_s, tr.t_s, tr.lat_rad),
                              np.interp(lg.start_s, tr.t_s, tr.lon_rad), lat0, lon0)[0]
                          for lg in sim.legs], axis=0)
        heading = np.radians(prof["start"]["heading_deg"])
        c_nb = rotation.dcm_from_quat(tr.q_nb[1:])  # at each sample's end
        g_n = np.zeros((t.size, 3))
        g_n[:, 0:2] = G0_MPS2 * _deflection(shape, size, ne, heading, centre)
        f = imu.f_ib_b_mps2 + np.einsum("kji,kj->ki", c_nb, g_n)  # f_b += C_bn (g0 xi, ...)
        imu = dataclasses.replace(imu, f_ib_b_mps2=f)

        def true(reps):
            out = []
            for r in reps:
                o = _ne(np.interp(r.t0_s, tr.t_s, tr.lat_rad),
                        np.interp(r.t0_s, tr.t_s, tr.lon_rad), lat0, lon0)[0]
                pos = o + r.v_n0_mps[None, 0:2] * r.t_s[:, None]
                dg = -G0_MPS2 * _deflection(shape, size, pos, heading, centre)  # true dg_h
                g = np.zeros((r.t_s.size, 15, 1))
                g[:, 3:5, 0] = -(dg - dg[0])
                out.append(forced_response(r, g)[:, :, 0])
            return out, 0.0
    return SimLog(imu, sim.fix, sim.vel), tp._config(180.0), sim, true


def one(case, seed: int, crossing: bool, n_legs: int) -> dict:
    kind = case[0]
    log, cfg, sim, true = flight(case, seed, crossing, n_legs)
    nav = pipeline.navigate(log, cfg)
    imu = pipeline.imu_increments(log)
    run, ref = pipeline.calibrate_from_a(imu, nav, cfg)
    null = pipeline.null_realisations(log, nav, run, cfg, tp.N_NULL, seed=seed)
    run = with_null_covariance(run, null)
    d = pipeline.diagnose_calibration(run, imu, ref, cfg, log=log, nav=nav, null_dv=null)
    reps = [run.replays[i] for i in sorted(run.replays)]
    fam = FAMILY[kind]
    out = {"named": fam in d.named, "shape": d.step_of(fam).shape if fam in d.named else "",
           "all": d.named, "closing": d.conclusion}
    resp_true, mean = true(reps)
    rms_true = float(np.sqrt(np.mean(np.concatenate(resp_true) ** 2)))
    resp = {r.effect: r for r in d.responses}
    if fam in resp and rms_true > 0:  # an accelerometer step between legs leaves B as it is
        err = np.concatenate([a - b for a, b in zip(resp[fam].curves(), resp_true,
                                                     strict=True)])
        out["size_error"] = float(np.sqrt(np.mean(err**2))) / rms_true
    truth_b = np.radians(np.asarray(sim.params["imu_errors"]["gyro_bias_dph"], float)) / 3600
    truth_b[0:2] += mean  # a gyro change: the bias at the legs' mean
    out["bias_error_dph"] = float(np.hypot(*(run.gyro_bias_b_radps - truth_b)[:2])
                                  / DEG_PER_H_RADPS)
    refit = refit_calibration(run, d.responses)
    out["refit_error_dph"] = (float(np.hypot(*(refit.bias_b_radps - truth_b)[:2])
                                    / DEG_PER_H_RADPS) if refit is not None else
                              out["bias_error_dph"])
    out["true_mps"] = rms_true
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", required=True, help="kind:shape:size,...")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=1, help="seeds first..first+N-1")
    ap.add_argument("--crossing", action="store_true")
    ap.add_argument("--n-legs", type=int, default=3)
    a = ap.parse_args()
    cases = [(k, s, float(v)) for k, s, v in (c.split(":") for c in a.cases.split(","))]
    print("| family | shape hidden | size | named (of N) | shapes named | size error (median, "
          "max) | gyro bias error: calibration -> refit [deg/h, median] | closing rows |")
    print("|---|---|---|---|---|---|---|---|")
    for case in cases:
        rows = []
        for s in range(a.first_seed, a.first_seed + a.seeds):
            t0 = time.time()
            try:
                rows.append(one(case, s, a.crossing, a.n_legs))
            except ValueError as exc:  # A or the calibration failed on the flight
                print(f"  {case} seed {s}: failed: {exc}", file=sys.stderr, flush=True)
                continue
            r = rows[-1]
            print(f"  {case} seed {s}: {r} ({time.time() - t0:.0f} s)", file=sys.stderr,
                  flush=True)
        named = [r for r in rows if r["named"]]
        errs = [r["size_error"] for r in named if "size_error" in r]
        shapes = ", ".join(f"{sh} {sum(r['shape'] == sh for r in named)}"
                           for sh in sorted({r["shape"] for r in named}))
        err = f"{np.median(errs):.2f}, {np.max(errs):.2f}" if errs else "-"
        bias = (f"{np.median([r['bias_error_dph'] for r in rows]):.3f} -> "
                f"{np.nanmedian([r['refit_error_dph'] for r in rows]):.3f}")
        closing = ", ".join(f"{c} {sum(r['closing'] == c for r in rows)}"
                            for c in sorted({r["closing"] for r in rows}))
        print(f"| {FAMILY[case[0]]} | {case[1]} | {case[2]:g} | {len(named)} / {len(rows)} | "
              f"{shapes or '-'} | {err} | {bias} | {closing} |", flush=True)


if __name__ == "__main__":
    main()
