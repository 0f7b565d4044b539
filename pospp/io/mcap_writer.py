"""Write a flight log to a ROS 2 MCAP file per the data contract (inverse of the reader).

The one way out of pospp into MCAP for flight data: the simulator and the converters of
measured logs both write through :func:`write_flight_log`, so every file pospp makes is read by
:func:`pospp.io.mcap_reader.read_flight_log` and by any ROS 2 MCAP tool alike.

Frames and units (the inverse of ``pospp.io.mcap_reader``)
-----------------------------------------------------------
- IMU: ``w_ib_b`` [rad/s] and ``f_ib_b`` [m/s^2] in body FRD are rotated into the sensor frame
  s with ``C_sb = C_bs^T`` (default sensor frame FLU, REP-103) and written as
  ``angular_velocity`` / ``linear_acceleration``: mean rate and specific force over the
  interval that ends at ``header.stamp``.
- GNSS fix: latitude / longitude [deg], altitude above the WGS-84 ellipsoid [m], covariance
  NED -> ENU (``position_covariance_type`` 3, COVARIANCE_TYPE_KNOWN).
- GNSS velocity: ``twist.linear`` ENU [m/s], the linear 3x3 block of the 6x6 covariance ENU;
  the angular block is marked unknown with a large variance.
- Log time = header stamp; messages of all topics are written merged in log-time order (as a
  recorder writes them), so a truncated file loses the end of every topic, not whole topics.
  Chunks are zstd-compressed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from mcap.writer import CompressionType, Writer

from pospp.io import ros_messages as rm
from pospp.io.files import atomic_path
from pospp.types import (
    ENU_TO_NED,
    FLU_TO_FRD,
    GnssFixes,
    GnssVelocities,
    ImuSamples,
    apply_rotation,
    check_dcm,
    rotate_covariance,
)

__all__ = ["write_flight_log"]

_UNKNOWN_VARIANCE = 1.0e6
"""Variance written where a quantity is not measured (angular block of the GNSS twist)."""


def _cov_ned_to_enu(p_ned: np.ndarray) -> np.ndarray:
    """(N, 3, 3) NED covariance -> ENU, flattened row-major (N, 9); exact (a permutation)."""
    return rotate_covariance(ENU_TO_NED.T, np.asarray(p_ned, dtype=float)).reshape(-1, 9)


class _Topic:
    """One topic's channel and its encoded payloads, ready to be merged in time order."""

    def __init__(
        self,
        writer: Writer,
        topic: str,
        schema_name: str,
        schema_text: str,
        payloads: np.ndarray,
        time_ns: np.ndarray,
    ) -> None:
        schema_id = writer.register_schema(
            name=schema_name, encoding="ros2msg", data=schema_text.encode("utf-8")
        )
        self.channel_id = writer.register_channel(
            topic=topic, message_encoding="cdr", schema_id=schema_id
        )
        self.raw = payloads.tobytes()
        self.size = payloads.dtype.itemsize
        self.time_ns = np.asarray(time_ns, dtype=np.int64)


def _write_merged(writer: Writer, topics: list[_Topic]) -> None:
    """Add all messages merged in log-time order, as a recorder would; sequence numbers count
    per channel.

    Each topic keeps its own order (the merge key is the running maximum of its stamps, ties
    broken by topic, then position), so stamps that go backwards stay where they were given.
    """
    times = np.concatenate([tp.time_ns for tp in topics])
    key = np.concatenate([np.maximum.accumulate(tp.time_ns) if len(tp.time_ns) else tp.time_ns
                          for tp in topics])
    which = np.concatenate([np.full(len(tp.time_ns), k) for k, tp in enumerate(topics)])
    local = np.concatenate([np.arange(len(tp.time_ns)) for tp in topics])
    order = np.lexsort((local, which, key))
    add = writer.add_message
    for t, k, i in zip(times[order].tolist(), which[order].tolist(), local[order].tolist(),
                       strict=True):
        tp = topics[k]
        add(channel_id=tp.channel_id, log_time=t, publish_time=t, sequence=i,
            data=tp.raw[i * tp.size : (i + 1) * tp.size])


def write_flight_log(
    path: str | Path,
    imu: ImuSamples,
    fix: GnssFixes,
    vel: GnssVelocities | None = None,
    *,
    imu_topic: str = "/imu/data",
    fix_topic: str = "/gnss/fix",
    vel_topic: str = "/gnss/vel",
    c_bs: np.ndarray = FLU_TO_FRD,
    imu_frame_id: str = "imu_link",
    gnss_frame_id: str = "gnss_antenna",
    metadata: dict[str, str] | None = None,
    events_ns: np.ndarray | None = None,
    events_topic: str = "/events",
    events_frame_id: str = "trigger",
) -> Path:
    """Write IMU samples and GNSS fixes / velocities to an MCAP file, atomically.

    Parameters
    ----------
    path : path-like
        Output ``.mcap``; written under a temporary name and renamed when complete.
    imu : ImuSamples
        Body-frame (FRD) mean rates and specific forces.
    fix : GnssFixes
        Antenna positions with NED covariances.
    vel : GnssVelocities, optional
        Antenna velocities (NED) with covariances; no velocity topic when None or empty.
    c_bs : ndarray, shape (3, 3)
        Mounting DCM sensor -> body, as given to the reader (default FLU -> FRD).
    metadata : dict, optional
        Written as an MCAP metadata record named ``pospp`` (e.g. how the file was made).
    events_ns : (M,) int64, optional
        Trigger stamps, written to ``events_topic`` as ``sensor_msgs/msg/TimeReference``
        (header.stamp = time_ref = the stamp, source ``events_frame_id``).

    Returns
    -------
    Path
        The written file.
    """
    c_sb = check_dcm(c_bs).T
    out = Path(path)
    with atomic_path(out) as tmp, open(tmp, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="pospp")
        def topic_of(name: str, schema_name: str, schema_text: str, fields: tuple,
                     time_ns: np.ndarray, frame_id: str, values: dict) -> _Topic:
            payloads = rm.encode_batch(fields, np.asarray(time_ns, np.int64), frame_id, values)
            return _Topic(writer, name, schema_name, schema_text, payloads, time_ns)

        topics = [topic_of(
            imu_topic, rm.IMU_TYPE, rm.IMU_MSGDEF, rm.IMU_FIELDS,
            np.asarray(imu.time_ns, dtype=np.int64), imu_frame_id,
            {
                "orientation_covariance": np.tile([-1.0] + [0.0] * 8, (len(imu), 1)),
                "angular_velocity": apply_rotation(c_sb, imu.w_ib_b_radps),
                "linear_acceleration": apply_rotation(c_sb, imu.f_ib_b_mps2),
            },
        )]
        topics.append(topic_of(
            fix_topic, rm.NAVSATFIX_TYPE, rm.NAVSATFIX_MSGDEF, rm.NAVSATFIX_FIELDS,
            np.asarray(fix.time_ns, dtype=np.int64), gnss_frame_id,
            {
                "status": np.asarray(fix.status, dtype=np.int8),
                "service": np.ones(len(fix), dtype=np.uint16),
                "latitude": np.rad2deg(fix.lat_rad),
                "longitude": np.rad2deg(fix.lon_rad),
                "altitude": np.asarray(fix.height_m, dtype=float),
                "position_covariance": _cov_ned_to_enu(fix.pos_cov_ned_m2),
                "position_covariance_type": np.full(len(fix), 3, dtype=np.uint8),
            },
        ))
        if vel is not None and len(vel):
            cov6 = np.zeros((len(vel), 6, 6))
            cov6[:, :3, :3] = _cov_ned_to_enu(vel.vel_cov_ned_m2ps2).reshape(-1, 3, 3)
            cov6[:, 3, 3] = cov6[:, 4, 4] = cov6[:, 5, 5] = _UNKNOWN_VARIANCE
            topics.append(topic_of(
                vel_topic, rm.TWIST_COV_STAMPED_TYPE, rm.TWIST_COV_STAMPED_MSGDEF,
                rm.TWIST_COV_STAMPED_FIELDS, np.asarray(vel.time_ns, dtype=np.int64),
                gnss_frame_id,
                {
                    "linear": apply_rotation(ENU_TO_NED.T, vel.v_n_mps),
                    "covariance": cov6.reshape(-1, 36),
                },
            ))
        if events_ns is not None:
            ev = rm.encode_time_reference(np.asarray(events_ns, np.int64), events_frame_id,
                                          events_frame_id)
            topics.append(_Topic(writer, events_topic, rm.TIME_REFERENCE_TYPE,
                                 rm.TIME_REFERENCE_MSGDEF, ev, events_ns))
        _write_merged(writer, topics)
        if metadata:
            writer.add_metadata("pospp", {str(k): str(v) for k, v in metadata.items()})
        writer.finish()
    return out
