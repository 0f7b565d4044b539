"""comma2k19 segment exported to CSV (``imu.csv``, ``gnss_ublox.csv``, ``pose_reference.csv``).

Source (docs/realdata.md, ``comma2k19_example1``): a phone-class device (comma EON) in a car,
IMU about 104 Hz, u-blox GNSS 10 Hz, and comma's post-processed pose at 20 Hz; all stamped in
device boot seconds, the pose also in GPS week / time of week, the GNSS also in UTC ms.

Conversion
----------
- Axes: the device frame is [forward, right, down] = FRD; specific force about -9.66 m/s^2 on
  down when level; gyro rad/s. The device is taken as the body (the reference pose is of the
  same frame); its small mounting relative to the car is estimated and reported, not applied.
- Gyro: ``gyro="calibrated"`` (default) takes Android's bias-compensated gyro (like
  ArduPilot's boot de-biasing), ``"uncalibrated"`` the raw gyro (biases near 0.07 rad/s).
- Sample convention: Android sensor events are instantaneous (low-pass filtered) samples; a
  sample at t is taken as the mean over the interval centred on t, so it is stamped at the end
  of that interval, t + dt/2 (dt the median interval, 9.58 ms).
- Time: boot s -> GPS time by the constant offset of the pose records (gps_week * 604800 +
  gps_tow_s - t_boot_s, identical for all rows); GPS -> UTC minus 18 leap seconds. The u-blox
  ``utc_ms`` is the fix's UTC epoch, used as its stamp; its boot stamp is its arrival (about
  0.2 s later, reported as ``ublox_arrival_latency_s``).
- Height: the u-blox ``alt_m`` agrees with the ellipsoidal height of the reference pose to about
  1 m (median difference reported), 32 m away from an MSL height here (EGM96 N about -32 m near
  San Francisco), so it is taken as ellipsoidal.
- GNSS velocity: north / east from ``speed_m_s`` and ``bearing_deg``; down from central
  differences of the height (the source has no vertical velocity), with a sigma of 0.5 m/s.
  Nominal sigmas (not logged here): position 2 m horizontal, 4 m vertical; velocity 0.2 m/s.
- Reference: ECEF position / velocity -> geodetic and NED; the quaternion (Hamilton,
  scalar-first) is the orientation of the device frame in ECEF, ``v_e = q v_b q*`` (checked:
  its forward axis lies along the ECEF velocity, cosine 0.998; the other reading gives 0.85),
  so ``C_nb = C_ne C_eb``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pospp import earth, rotation
from pospp.io.converters._common import (
    SECONDS_PER_WEEK,
    ConversionError,
    MountingInput,
    ParsedLog,
    check_gravity,
    check_increasing,
    diag_cov,
    gps_to_unix_ns,
    read_csv,
    require_file,
    velocity_from_positions,
)
from pospp.types import GnssFixes, GnssVelocities, ImuSamples, ReferenceTrajectory

__all__ = ["parse_comma2k19"]


def _pose_reference(pose: pd.DataFrame, pose_p: Path, ref_ns: np.ndarray,
                    checks: dict[str, float]) -> ReferenceTrajectory:
    """The ECEF pose records as a reference trajectory (NED velocity, z-y-x attitude); the
    quaternion's forward axis must lie along the velocity."""
    r_e = pose[["ecef_x_m", "ecef_y_m", "ecef_z_m"]].to_numpy(dtype=float)
    v_e = pose[["ecef_vx_m_s", "ecef_vy_m_s", "ecef_vz_m_s"]].to_numpy(dtype=float)
    lat, lon, h = earth.ecef_to_llh(r_e)
    c_en = earth.dcm_en(lat, lon)
    v_n_ref = np.einsum("nji,nj->ni", c_en, v_e)
    q_eb = pose[["q_w", "q_x", "q_y", "q_z"]].to_numpy(dtype=float)
    c_eb = rotation.dcm_from_quat(q_eb)
    fwd_cos = float(np.median(np.sum(c_eb[:, :, 0] * v_e, axis=1)
                              / np.linalg.norm(v_e, axis=1)))
    if fwd_cos < 0.9:
        raise ConversionError(f"{pose_p}: the quaternion's forward axis is not along the "
                              f"velocity (median cosine {fwd_cos:.3f}); convention changed?")
    checks["reference_forward_axis_cosine"] = fwd_cos
    c_nb = np.einsum("nji,njk->nik", c_en, c_eb)
    ref = ReferenceTrajectory(time_ns=ref_ns, lat_rad=lat, lon_rad=lon, height_m=h,
                              v_n_mps=v_n_ref, rpy_rad=rotation.euler_from_dcm(c_nb))
    return ref


def _ublox_gnss(gnss: pd.DataFrame, gnss_p: Path, fix_ns: np.ndarray,
                ref: ReferenceTrajectory, checks: dict[str, float]
                ) -> tuple[GnssFixes, GnssVelocities]:
    """The u-blox records as fixes and velocities (nominal sigmas; vertical velocity from the
    heights); alt_m must be ellipsoidal (checked against the reference)."""
    lat_g = np.radians(gnss["lat_deg"].to_numpy(dtype=float))
    lon_g = np.radians(gnss["lon_deg"].to_numpy(dtype=float))
    h_g = gnss["alt_m"].to_numpy(dtype=float)
    t_fix_s = (fix_ns - fix_ns[0]) * 1e-9
    h_ref_at_fix = np.interp(t_fix_s, (ref.time_ns - fix_ns[0]) * 1e-9, ref.height_m)
    checks["ublox_alt_minus_ellipsoidal_ref_m"] = float(np.median(h_g - h_ref_at_fix))
    if abs(checks["ublox_alt_minus_ellipsoidal_ref_m"]) > 10.0:
        raise ConversionError(f"{gnss_p}: alt_m differs from the reference's ellipsoidal height "
                              f"by {checks['ublox_alt_minus_ellipsoidal_ref_m']:.1f} m; is it "
                              "MSL? (expected ellipsoidal)")
    spd = gnss["speed_m_s"].to_numpy(dtype=float)
    brg = np.radians(gnss["bearing_deg"].to_numpy(dtype=float))
    vd = velocity_from_positions(t_fix_s, lat_g, lon_g, h_g)[:, 2]
    v_n = np.column_stack([spd * np.cos(brg), spd * np.sin(brg), vd])
    n_fix = len(fix_ns)
    fix = GnssFixes(time_ns=fix_ns, lat_rad=lat_g, lon_rad=lon_g, height_m=h_g,
                    pos_cov_ned_m2=diag_cov([2.0, 2.0, 4.0], n_fix),
                    status=np.zeros(n_fix, dtype=np.int8))
    vel = GnssVelocities(time_ns=fix_ns, v_n_mps=v_n,
                         vel_cov_ned_m2ps2=diag_cov([0.2, 0.2, 0.5], n_fix))
    return fix, vel


def parse_comma2k19(
    source: str | Path,
    *,
    gyro: str = "calibrated",
) -> ParsedLog:
    """Parse a comma2k19 CSV export in folder ``source`` into the data contract.

    The device-to-car mounting is not estimated here: ``mounting`` holds its inputs, and
    ``pospp.convert`` reports the estimate (not applied).

    Parameters
    ----------
    source : path-like
        Folder with ``imu.csv``, ``gnss_ublox.csv`` and ``pose_reference.csv``.
    gyro : {"calibrated", "uncalibrated"}
        Which gyro columns to write (module docstring).

    Returns
    -------
    ParsedLog
    """
    if gyro not in ("calibrated", "uncalibrated"):
        raise ValueError(f"gyro must be 'calibrated' or 'uncalibrated'; got {gyro!r}")
    src = Path(source)
    imu_p, gnss_p, pose_p = (require_file(src, n) for n in
                             ("imu.csv", "gnss_ublox.csv", "pose_reference.csv"))
    tag = "cal" if gyro == "calibrated" else "unc"
    wcols = [f"gyro_{tag}_{a}_rad_s" for a in ("fwd", "right", "down")]
    fcols = [f"acc_{a}_m_s2" for a in ("fwd", "right", "down")]
    imu = read_csv(imu_p, ["t_boot_s", *wcols, *fcols])
    gnss = read_csv(gnss_p, ["t_boot_s", "lat_deg", "lon_deg", "speed_m_s", "utc_ms", "alt_m",
                             "bearing_deg"])
    pcols = ["t_boot_s", "gps_week", "gps_tow_s", "ecef_x_m", "ecef_y_m", "ecef_z_m",
             "ecef_vx_m_s", "ecef_vy_m_s", "ecef_vz_m_s", "q_w", "q_x", "q_y", "q_z"]
    pose = read_csv(pose_p, pcols)
    t_imu = imu["t_boot_s"].to_numpy(dtype=float)
    check_increasing(imu_p, "t_boot_s", t_imu)
    w = imu[wcols].to_numpy(dtype=float)
    f = imu[fcols].to_numpy(dtype=float)
    g_med = check_gravity(imu_p, f, "acc_*_m_s2")
    if np.mean(f[:, 2]) > -0.8 * g_med:
        raise ConversionError(f"{imu_p}: mean acc_down_m_s2 {np.mean(f[:, 2]):.2f}; expected "
                              "about -g (device frame forward-right-down)")
    # time bases
    t_pose = pose["t_boot_s"].to_numpy(dtype=float)
    check_increasing(pose_p, "t_boot_s", t_pose)
    gps_pose = (pose["gps_week"].to_numpy(dtype=float) * SECONDS_PER_WEEK
                + pose["gps_tow_s"].to_numpy(dtype=float))
    off = gps_pose - t_pose
    if np.ptp(off) > 1e-3:
        raise ConversionError(f"{pose_p}: GPS time minus boot time varies by {np.ptp(off):.4f} s;"
                              " expected one constant offset")
    offset_s = float(np.median(off))
    dt = float(np.median(np.diff(t_imu)))
    imu_ns = gps_to_unix_ns(t_imu + 0.5 * dt + offset_s)
    ref_ns = gps_to_unix_ns(gps_pose)
    utc_ms = gnss["utc_ms"].to_numpy(dtype=float)
    fix_ns = np.round(utc_ms).astype(np.int64) * 1_000_000
    check_increasing(gnss_p, "utc_ms", fix_ns)
    checks: dict[str, float] = {"gravity_median_mps2": g_med}
    # arrival latency of the u-blox records: boot stamp minus the utc epoch on the boot base
    utc_on_boot_s = (fix_ns - ref_ns[0]) * 1e-9 + t_pose[0]
    checks["ublox_arrival_latency_s"] = float(np.median(gnss["t_boot_s"].to_numpy(float)
                                                        - utc_on_boot_s))
    ref = _pose_reference(pose, pose_p, ref_ns, checks)
    fix, vel = _ublox_gnss(gnss, gnss_p, fix_ns, ref, checks)
    t_fix_s = (fix_ns - fix_ns[0]) * 1e-9
    samples = ImuSamples(time_ns=imu_ns, w_ib_b_radps=w, f_ib_b_mps2=f, frame_id="device")
    # device-to-car mounting (reported, not applied): level + forward axis from the GNSS track
    mounting = MountingInput(
        t_s=(imu_ns - fix_ns[0]) * 1e-9, f_s_mps2=f, t_vel_s=t_fix_s, v_n_mps=vel.v_n_mps,
        lat_rad=float(fix.lat_rad[0]), height_m=float(fix.height_m[0]), body_rpy_rad=None,
        options={"window_s": 1.0, "max_static_accel_mps2": 0.3,
                 "min_horizontal_accel_mps2": 0.3},
        apply=False, description="device-to-car mounting")
    time_system = ("UTC ns since the Unix epoch: boot s + (GPS - boot) offset of the pose "
                   "records, GPS -> UTC minus 18 leap seconds; GNSS stamped at its utc_ms")
    datum = "WGS-84 ellipsoid (u-blox alt_m checked against the ECEF reference)"
    imu_conv = "instantaneous samples stamped at t + dt/2 (interval centred on the sample)"
    axes = "device [forward, right, down] = FRD (identity); device taken as body"
    meta = {"converter": "pospp.io.converters.comma2k19", "source": str(src),
            "time_system": time_system, "height_datum": datum, "imu_convention": imu_conv,
            "axes": axes, "gyro": gyro,
            "gnss_sigma": "nominal: pos 2/2/4 m NED, vel 0.2/0.2/0.5 m/s (vd from heights)"}
    return ParsedLog(
        fmt="comma2k19", source=str(src), imu=samples, fix=fix, vel=vel, reference=ref,
        time_system=time_system, height_datum=datum, imu_convention=imu_conv, axes=axes,
        metadata=meta, reference_metadata={
            "source": str(pose_p), "frame": "device FRD w.r.t. NED",
            "time_system": "UTC ns from GPS week/TOW minus 18 s"},
        imu_frame_id="device", checks=checks, mounting=mounting,
    )
