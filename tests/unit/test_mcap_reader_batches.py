"""The reader's compiled batch decoding and its array allocation (issue 18, reader).

The arrays are sized from the summary's Statistics when there is one, and grown otherwise;
each channel's fixed CDR layout is checked once against mcap_ros2's generic decoder and then
reused batch to batch, one compiled pass per batch and frame_id length. The files here are
written by the mcap libraries (``mcap_ros2``'s message encoder, ``mcap``'s Writer), not by
pospp, and the values read must equal those written bit for bit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from mcap.writer import CompressionType
from mcap_ros2.writer import Writer as Ros2Writer
from test_mcap_reader import make_log, write_with_library

from pospp.io import ros_messages as rm
from pospp.io._blockwise import rotation_sums, row_norms
from pospp.io.mcap_reader import read_flight_log
from pospp.types import FLU_TO_FRD


def _stamp(t_ns: int) -> dict:
    return {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}


def test_frame_id_changes_within_and_between_chunks(tmp_path: Path) -> None:
    """IMU frame_ids of three lengths (so three CDR layouts), changing between chunks and
    alternating within them: every value and stamp read as written, every frame_id noted
    (a warning lists them), and the first is the log's frame_id."""
    imu, fix, _ = make_log(duration_s=15.0, rate_hz=100.0, seed=11)
    n = len(imu)
    w_s = imu.w_ib_b_radps @ FLU_TO_FRD  # sensor FLU as logged (FLU_TO_FRD is its own inverse)
    f_s = imu.f_ib_b_mps2 @ FLU_TO_FRD
    frames = np.where(np.arange(n) < n // 3, "imu",
                      np.where(np.arange(n) < 2 * n // 3, "imu_link_long",
                               np.where(np.arange(n) % 2 == 0, "imu_a", "imu_b")))
    path = tmp_path / "frames.mcap"
    with open(path, "wb") as fh:
        wr = Ros2Writer(fh, chunk_size=16 * 1024, compression=CompressionType.ZSTD)
        s_imu = wr.register_msgdef(rm.IMU_TYPE, rm.IMU_MSGDEF)
        s_fix = wr.register_msgdef(rm.NAVSATFIX_TYPE, rm.NAVSATFIX_MSGDEF)
        j = 0
        for i, t in enumerate(imu.time_ns.tolist()):
            while j < len(fix) and int(fix.time_ns[j]) <= t:  # interleaved like a recorder
                tj = int(fix.time_ns[j])
                wr.write_message("/gnss/fix", s_fix, {
                    "header": {"stamp": _stamp(tj), "frame_id": "gnss"},
                    "status": {"status": 0, "service": 1},
                    "latitude": float(np.rad2deg(fix.lat_rad[j])),
                    "longitude": float(np.rad2deg(fix.lon_rad[j])),
                    "altitude": float(fix.height_m[j]),
                    "position_covariance": fix.pos_cov_ned_m2[j].ravel().tolist(),
                    "position_covariance_type": 2}, log_time=tj, publish_time=tj)
                j += 1
            wr.write_message("/imu/data", s_imu, {
                "header": {"stamp": _stamp(t), "frame_id": str(frames[i])},
                "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                "orientation_covariance": [0.0] * 9,
                "angular_velocity": dict(zip("xyz", w_s[i].tolist(), strict=True)),
                "angular_velocity_covariance": [0.0] * 9,
                "linear_acceleration": dict(zip("xyz", f_s[i].tolist(), strict=True)),
                "linear_acceleration_covariance": [0.0] * 9}, log_time=t, publish_time=t)
        wr.finish()
    log = read_flight_log(path)
    assert log.complete
    np.testing.assert_array_equal(log.imu.time_ns, imu.time_ns)
    np.testing.assert_array_equal(log.imu.w_ib_b_radps, imu.w_ib_b_radps)
    np.testing.assert_array_equal(log.imu.f_ib_b_mps2, imu.f_ib_b_mps2)
    np.testing.assert_array_equal(log.fix.height_m, fix.height_m)
    assert log.imu.frame_id == "imu"
    [warn] = [i for i in log.issues if "frame_ids" in i.message]
    assert all(f"'{f}'" in warn.message for f in ("imu", "imu_link_long", "imu_a", "imu_b"))
    assert not [i for i in log.issues if "generic decoder" in i.message]


def test_without_statistics_the_arrays_grow_to_the_same_values(tmp_path: Path) -> None:
    """No Statistics record (nothing to size the arrays from): 6000 IMU messages, more than
    the first allocation of 4096 rows, read the same as from the file that has one."""
    imu, fix, _ = make_log(duration_s=60.0, rate_hz=100.0, seed=5)
    with_stats = read_flight_log(write_with_library(tmp_path / "a.mcap", imu, fix,
                                                    chunk_size=32 * 1024))
    no_stats = read_flight_log(write_with_library(tmp_path / "b.mcap", imu, fix,
                                                  chunk_size=32 * 1024, use_statistics=False))
    assert with_stats.complete and no_stats.complete and len(no_stats.imu) == len(imu) == 6000
    for a, b in ((with_stats.imu, no_stats.imu), (with_stats.fix, no_stats.fix)):
        for name, v in vars(a).items():
            if isinstance(v, np.ndarray):
                np.testing.assert_array_equal(v, getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(no_stats.imu.w_ib_b_radps, imu.w_ib_b_radps)


def test_block_wise_check_helpers_match_numpy_bit_for_bit() -> None:
    """The unit checks' block-wise row norms and running rotation sums equal numpy's whole-
    array ``linalg.norm`` and ``cumsum`` exactly, across block edges."""
    rng = np.random.default_rng(3)
    n = 150_001  # more than two blocks of 65536 rows
    w = rng.normal(0.0, 0.3, (n, 3))
    t = 10**18 + np.cumsum(rng.integers(4_000_000, 6_000_000, n))
    np.testing.assert_array_equal(row_norms(w), np.linalg.norm(w, axis=1))
    dt = np.diff(t, prepend=t[0] - (t[1] - t[0])) * 1e-9
    cum = np.vstack([np.zeros((1, 3)), np.cumsum(w * dt[:, None], axis=0)])
    at = np.r_[0, 1, 65535, 65536, 65537, 131072, n, rng.integers(0, n + 1, 100)]
    np.testing.assert_array_equal(rotation_sums(w, t, at), cum[at])
