"""Write a navigation solution to MCAP for viewing beside the raw log (Foxglove, ROS tools).

Two ROS 2 topics, CDR encoded, stamped with the solution's time:

- ``/pospp/fix``: ``sensor_msgs/msg/NavSatFix``: latitude, longitude [deg], ellipsoidal
  height [m], position covariance in ENU [m^2] (diagonal from the solution's NED sigmas).
- ``/pospp/pose``: ``geometry_msgs/msg/PoseStamped`` in frame ``map``: position in a local
  ENU tangent frame at the first epoch [m] and the orientation of the body as ROS expects it,
  FLU body w.r.t. ENU (REP-103), quaternion x, y, z, w.

NED/FRD -> ENU/FLU happens here, in one place: C_enu_flu = T C_nb D with T = ENU<-NED and
D = FRD<-FLU (both signed permutations).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer

from pospp import earth, rotation
from pospp.io import ros_messages as rm
from pospp.io.mcap_reader import ENU_TO_NED, FLU_TO_FRD
from pospp.io.parquet_tables import atomic_path

__all__ = ["write_trajectory_mcap"]


def _register(writer: Writer, topic: str, name: str, text: str) -> int:
    sid = writer.register_schema(name=name, encoding="ros2msg", data=text.encode("utf-8"))
    return writer.register_channel(topic=topic, message_encoding="cdr", schema_id=sid)


def write_trajectory_mcap(path: str | Path, solution: Any, epoch_ns: int, *,
                          rate_hz: float | None = None) -> Path:
    """Write ``solution`` (a NavSolution: t_s, lat/lon/height, q_nb, pos_sigma_ned_m) to MCAP.

    ``rate_hz`` thins the epochs to about that rate (every k-th epoch; all when None or when
    the solution is slower). Returns the written path (atomic: temporary name, then rename).
    """
    keep = slice(None)
    if rate_hz is not None and len(solution.t_s) > 1:
        dt_s = float(np.median(np.diff(solution.t_s)))
        keep = slice(None, None, max(1, int(round(1.0 / (rate_hz * dt_s)))))
    t_s = solution.t_s[keep]
    time_ns = np.int64(epoch_ns) + np.round(t_s * 1e9).astype(np.int64)
    lat, lon, h = solution.lat_rad[keep], solution.lon_rad[keep], solution.height_m[keep]
    q_nb = solution.q_nb[keep]
    var_ned = solution.pos_sigma_ned_m[keep] ** 2
    cov_enu = np.zeros((len(time_ns), 9))
    cov_enu[:, 0], cov_enu[:, 4], cov_enu[:, 8] = var_ned[:, 1], var_ned[:, 0], var_ned[:, 2]
    r_ned = earth.llh_to_ned_m(lat, lon, h, lat[0], lon[0], h[0])
    r_enu = r_ned @ ENU_TO_NED.T  # ENU_TO_NED is symmetric and its own inverse
    c_enu_flu = ENU_TO_NED @ rotation.dcm_from_quat(q_nb) @ FLU_TO_FRD
    q_wxyz = rotation.quat_from_dcm(c_enu_flu)
    fix = rm.encode_batch(rm.NAVSATFIX_FIELDS, time_ns, "pospp", {
        "status": np.zeros(len(time_ns), np.int8),
        "service": np.ones(len(time_ns), np.uint16),
        "latitude": np.degrees(lat), "longitude": np.degrees(lon), "altitude": h,
        "position_covariance": cov_enu,
        "position_covariance_type": np.full(len(time_ns), 2, np.uint8),  # DIAGONAL_KNOWN
    })
    pose = rm.encode_batch(rm.POSE_STAMPED_FIELDS, time_ns, "map", {
        "position": r_enu, "orientation": q_wxyz[:, [1, 2, 3, 0]],
    })
    out = Path(path)
    with atomic_path(out) as tmp, open(tmp, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="pospp")
        ch_fix = _register(writer, "/pospp/fix", rm.NAVSATFIX_TYPE, rm.NAVSATFIX_MSGDEF)
        ch_pose = _register(writer, "/pospp/pose", rm.POSE_STAMPED_TYPE, rm.POSE_STAMPED_MSGDEF)
        fb, pb = fix.tobytes(), pose.tobytes()
        fs, ps = fix.dtype.itemsize, pose.dtype.itemsize
        for i, t in enumerate(time_ns.tolist()):
            writer.add_message(ch_fix, log_time=t, publish_time=t, sequence=i,
                               data=fb[i * fs:(i + 1) * fs])
            writer.add_message(ch_pose, log_time=t, publish_time=t, sequence=i,
                               data=pb[i * ps:(i + 1) * ps])
        writer.finish()
    return out
