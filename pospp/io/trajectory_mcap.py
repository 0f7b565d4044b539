"""Write a navigation solution to MCAP for viewing beside the raw log (Foxglove, ROS tools).

ROS 2 topics, CDR encoded, stamped with the solution's time:

- ``/pospp/fix``: ``sensor_msgs/msg/NavSatFix``: latitude, longitude [deg], ellipsoidal
  height [m], position covariance in ENU [m^2] (diagonal from the solution's NED sigmas).
- ``/pospp/pose``: ``geometry_msgs/msg/PoseStamped`` in frame ``map``: position in a local
  ENU tangent frame at the first epoch [m] and the orientation of the body as ROS expects it,
  FLU body w.r.t. ENU (REP-103), quaternion x, y, z, w.
- ``/tf``: ``tf2_msgs/msg/TFMessage``, one transform ``map`` -> ``base_link`` per epoch (the
  same pose), so Foxglove's 3D panel follows the body.
- ``/pospp/odom``: ``nav_msgs/msg/Odometry``, frame ``map``, child ``base_link``: the pose
  with its 6x6 covariance (position ENU [m^2], then the attitude error about the map's E, N, U
  axes [rad^2], from the solution's NED blocks), the velocity in ``base_link`` (FLU) with its
  3x3 covariance (angular part unknown: variance 1e6).
- ``/pospp/legs``: ``nav_msgs/msg/Path``, one message per straight leg (stamped at its end;
  poses at about 1 Hz from the leg's start to end), when the legs are given.
- an MCAP metadata record ``pospp`` (pospp version, and the caller's: input SHA-256, status...),
  after the messages: :func:`trajectory_messages` writes the messages (in memory) before the
  caller knows its metadata, :meth:`TrajectoryMcap.finish` the rest and the file.

NED/FRD -> ENU/FLU happens here, in one place: C_enu_flu = T C_nb D with T = ENU<-NED and
D = FRD<-FLU (both signed permutations).
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from mcap.writer import CompressionType, Writer
from numpy.typing import ArrayLike, NDArray

from pospp import __version__, earth, rotation
from pospp.io import ros_messages as rm
from pospp.io.files import atomic_path
from pospp.types import ENU_TO_NED, FLU_TO_FRD
from pospp.units import time_ns_from_t_s

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["TrajectoryMcap", "thin_indices", "trajectory_messages", "write_trajectory_mcap"]

_UNKNOWN_VARIANCE = 1.0e6
"""Variance written where a quantity is not estimated (angular velocity of the odometry)."""
_LEG_PATH_RATE_HZ = 1.0


def thin_indices(t_s: np.ndarray, rate_hz: float | None) -> np.ndarray:
    """Indices of every k-th epoch, k = round(1 / (rate_hz * median dt)) >= 1 (all if None)."""
    n = len(t_s)
    if rate_hz is None or n < 2:
        return np.arange(n)
    dt_s = float(np.median(np.diff(t_s)))
    return np.arange(0, n, max(1, int(round(1.0 / (rate_hz * dt_s)))))


def _register(writer: Writer, topic: str, name: str, text: str) -> int:
    sid = writer.register_schema(name=name, encoding="ros2msg", data=text.encode("utf-8"))
    return writer.register_channel(topic=topic, message_encoding="cdr", schema_id=sid)


class SolutionLike(Protocol):
    """What the writer reads of a navigation solution (``pospp.nav.solution.NavSolution`` is one;
    io does not import nav): time-major arrays, NED, rad, SI."""

    @property
    def t_s(self) -> NDArray: ...
    @property
    def lat_rad(self) -> NDArray: ...
    @property
    def lon_rad(self) -> NDArray: ...
    @property
    def height_m(self) -> NDArray: ...
    @property
    def v_n_mps(self) -> NDArray: ...
    @property
    def q_nb(self) -> NDArray: ...
    @property
    def pos_sigma_ned_m(self) -> NDArray: ...
    @property
    def pos_cov_ned_m2(self) -> NDArray: ...
    @property
    def vel_cov_ned_m2ps2(self) -> NDArray: ...
    @property
    def att_cov_ned_rad2(self) -> NDArray: ...


def write_trajectory_mcap(path: str | Path, solution: SolutionLike, epoch_ns: int, *,
                          rate_hz: float | None = None,
                          legs: Mapping[str, ArrayLike] | pd.DataFrame | None = None,
                          metadata: dict[str, Any] | None = None) -> Path:
    """Write ``solution`` (a NavSolution: t_s, lat/lon/height, q_nb, covariances) to MCAP.

    ``rate_hz`` thins the epochs to about that rate (every k-th epoch; all when None or when
    the solution is slower). ``legs``: a table with ``leg_id``, ``start_ns``, ``end_ns`` (the
    legs table) for ``/pospp/legs``. ``metadata`` goes, with the pospp version, into the
    ``pospp`` metadata record. Returns the written path (atomic: temporary name, then rename).
    :func:`trajectory_messages` then :meth:`TrajectoryMcap.finish`.
    """
    return trajectory_messages(solution, epoch_ns, rate_hz=rate_hz, legs=legs).finish(
        path, metadata)


class TrajectoryMcap:
    """A trajectory MCAP whose messages are written (in memory) and whose ``pospp`` metadata
    record, summary and footer are not (:func:`trajectory_messages`): a run writes the
    messages while it still works out its status, which the metadata holds."""

    def __init__(self, writer: Writer, stream: io.BytesIO, meta: dict[str, str]) -> None:
        self._writer: Writer | None = writer
        self._stream, self._meta = stream, meta

    def finish(self, path: str | Path, metadata: dict[str, Any] | None = None) -> Path:
        """The metadata record (the pospp version and frame, then ``metadata``), summary and
        footer, and the file written at ``path`` atomically (temporary name, then rename);
        once."""
        if self._writer is None:
            raise RuntimeError("TrajectoryMcap.finish: already finished")
        meta = dict(self._meta)
        meta.update({str(k): str(v) for k, v in (metadata or {}).items()})
        self._writer.add_metadata("pospp", meta)
        self._writer.finish()
        out = Path(path)
        with atomic_path(out) as tmp:
            tmp.write_bytes(self._stream.getbuffer())
        self._writer, self._stream = None, io.BytesIO()
        return out


def trajectory_messages(solution: SolutionLike, epoch_ns: int, *,
                        rate_hz: float | None = None,
                        legs: Mapping[str, ArrayLike] | pd.DataFrame | None = None
                        ) -> TrajectoryMcap:
    """Every message of :func:`write_trajectory_mcap` (same arguments) in an MCAP written in
    memory up to its metadata record (a few MB: the 1.5 h flight's is 4.2 MB)."""
    keep = thin_indices(solution.t_s, rate_hz)
    t_s = solution.t_s[keep]
    n = len(t_s)
    time_ns = time_ns_from_t_s(t_s, epoch_ns)
    lat, lon, h = solution.lat_rad[keep], solution.lon_rad[keep], solution.height_m[keep]
    q_nb = solution.q_nb[keep]
    var_ned = solution.pos_sigma_ned_m[keep] ** 2
    cov_enu = np.zeros((n, 9))
    cov_enu[:, 0], cov_enu[:, 4], cov_enu[:, 8] = var_ned[:, 1], var_ned[:, 0], var_ned[:, 2]
    r_ned = earth.llh_to_ned_m(lat, lon, h, lat[0], lon[0], h[0])
    r_enu = r_ned @ ENU_TO_NED.T  # ENU_TO_NED is symmetric and its own inverse
    c_enu_flu = ENU_TO_NED @ rotation.dcm_from_quat(q_nb) @ FLU_TO_FRD
    q_xyzw = rotation.quat_from_dcm(c_enu_flu)[:, [1, 2, 3, 0]]
    fix = rm.encode_batch(rm.NAVSATFIX_FIELDS, time_ns, "pospp", {
        "status": np.zeros(n, np.int8),
        "service": np.ones(n, np.uint16),
        "latitude": np.degrees(lat), "longitude": np.degrees(lon), "altitude": h,
        "position_covariance": cov_enu,
        "position_covariance_type": np.full(n, 2, np.uint8),  # DIAGONAL_KNOWN
    })
    pose = rm.encode_batch(rm.POSE_STAMPED_FIELDS, time_ns, "map", {
        "position": r_enu, "orientation": q_xyzw,
    })
    tf = rm.encode_tf(time_ns, "map", "base_link", translation=r_enu, rotation_xyzw=q_xyzw)
    pose_cov = np.zeros((n, 6, 6))
    pose_cov[:, :3, :3] = ENU_TO_NED @ solution.pos_cov_ned_m2[keep] @ ENU_TO_NED
    pose_cov[:, 3:, 3:] = ENU_TO_NED @ solution.att_cov_ned_rad2[keep] @ ENU_TO_NED
    c_flu_enu = np.swapaxes(c_enu_flu, 1, 2)
    v_flu = np.einsum("kij,kj->ki", c_flu_enu, solution.v_n_mps[keep] @ ENU_TO_NED)
    twist_cov = np.zeros((n, 6, 6))
    twist_cov[:, :3, :3] = c_flu_enu @ ENU_TO_NED @ solution.vel_cov_ned_m2ps2[keep] \
        @ ENU_TO_NED @ c_enu_flu
    twist_cov[:, 3, 3] = twist_cov[:, 4, 4] = twist_cov[:, 5, 5] = _UNKNOWN_VARIANCE
    odom = rm.encode_odometry(time_ns, "map", "base_link", position=r_enu,
                              orientation_xyzw=q_xyzw, pose_covariance=pose_cov.reshape(n, 36),
                              linear=v_flu, twist_covariance=twist_cov.reshape(n, 36))
    paths = _leg_paths(legs, solution, epoch_ns, r_enu_of=lambda k: earth.llh_to_ned_m(
        solution.lat_rad[k], solution.lon_rad[k], solution.height_m[k], lat[0], lon[0], h[0])
        @ ENU_TO_NED.T, q_of=lambda k: rotation.quat_from_dcm(
        ENU_TO_NED @ rotation.dcm_from_quat(solution.q_nb[k]) @ FLU_TO_FRD)[:, [1, 2, 3, 0]])
    stream = io.BytesIO()
    writer = Writer(stream, compression=CompressionType.ZSTD)
    writer.start(profile="ros2", library="pospp")
    streams = [
        (_register(writer, "/pospp/fix", rm.NAVSATFIX_TYPE, rm.NAVSATFIX_MSGDEF), fix),
        (_register(writer, "/pospp/pose", rm.POSE_STAMPED_TYPE, rm.POSE_STAMPED_MSGDEF), pose),
        (_register(writer, "/tf", rm.TF_MESSAGE_TYPE, rm.TF_MESSAGE_MSGDEF), tf),
        (_register(writer, "/pospp/odom", rm.ODOMETRY_TYPE, rm.ODOMETRY_MSGDEF), odom),
    ]
    raw = [(ch, arr.tobytes(), arr.dtype.itemsize) for ch, arr in streams]
    for i, t in enumerate(time_ns.tolist()):
        for ch, b, size in raw:
            writer.add_message(ch, log_time=t, publish_time=t, sequence=i,
                               data=b[i * size:(i + 1) * size])
    if paths:
        ch_legs = _register(writer, "/pospp/legs", rm.NAV_PATH_TYPE, rm.NAV_PATH_MSGDEF)
        for i, (t, payload) in enumerate(paths):
            writer.add_message(ch_legs, log_time=t, publish_time=t, sequence=i, data=payload)
    return TrajectoryMcap(writer, stream, {
        "pospp_version": __version__, "frame": "map = ENU tangent plane at "
        f"lat {np.degrees(lat[0]):.9f} deg, lon {np.degrees(lon[0]):.9f} deg, "
        f"h {h[0]:.3f} m; base_link = FLU body"})


def _leg_paths(legs: Mapping[str, ArrayLike] | pd.DataFrame | None, solution: SolutionLike,
               epoch_ns: int, *, r_enu_of: Callable[[NDArray], NDArray],
               q_of: Callable[[NDArray], NDArray]
               ) -> list[tuple[int, bytes]]:
    """(stamp, Path payload) per leg: the solution's poses at about 1 Hz over the leg."""
    if legs is None or len(legs) == 0:
        return []
    sol_ns = time_ns_from_t_s(solution.t_s, epoch_ns)
    step = thin_indices(solution.t_s, _LEG_PATH_RATE_HZ)
    out = []
    for start, end in zip(np.asarray(legs["start_ns"], np.int64),
                          np.asarray(legs["end_ns"], np.int64), strict=True):
        k = step[(sol_ns[step] >= start) & (sol_ns[step] <= end)]
        if k.size == 0:
            continue
        out.append((int(end), rm.encode_path(int(end), "map", sol_ns[k], r_enu_of(k), q_of(k))))
    return sorted(out, key=lambda p: p[0])
