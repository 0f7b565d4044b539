"""ROS 2 message definitions and their CDR layouts as numpy structured dtypes.

The message types pospp reads and writes all have exactly one variable-length field, the
``header.frame_id`` string, right after the stamp. For a given frame_id length the CDR layout
of the whole message is therefore fixed, and a batch of messages sharing that length can be
decoded (or encoded) with one numpy structured dtype over the concatenated payloads.

CDR (XCDR1, as written by ROS 2 rmw implementations and by ``mcap_ros2``)
-----------------------------------------------------------------------
- bytes 0-3: encapsulation header; ``00 01 00 00`` = plain CDR, little-endian (``CDR_LE``).
  ``00 00`` is big-endian; those messages are left to the generic ``mcap_ros2`` decoder.
- the body starts at byte 4; every primitive is aligned to its own size (max 8) counted from the
  body start; strings are ``uint32 length (including the NUL)`` + chars + NUL; fixed arrays are
  packed primitives; no trailing padding.

For ``sensor_msgs/msg/Imu`` with ``frame_id="imu_link"`` (length 9) the body is
``sec@0 nanosec@4 len@8 chars@12..21 pad orientation@24 orientation_covariance@56
angular_velocity@128 angular_velocity_covariance@152 linear_acceleration@224
linear_acceleration_covariance@248``, 320 bytes, 324 with the encapsulation header.

The message definition texts below follow the ROS 2 (rosbag2 / MCAP ``ros2msg``) convention:
the top-level definition, then each dependency after a line of 80 ``=`` and a ``MSG: pkg/Type``
line.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "CDR_LE_HEADER",
    "IMU_FIELDS",
    "IMU_MSGDEF",
    "IMU_TYPE",
    "NAVSATFIX_FIELDS",
    "NAVSATFIX_MSGDEF",
    "NAVSATFIX_TYPE",
    "POSE_STAMPED_FIELDS",
    "POSE_STAMPED_MSGDEF",
    "POSE_STAMPED_TYPE",
    "TWIST_COV_STAMPED_FIELDS",
    "TWIST_COV_STAMPED_MSGDEF",
    "TWIST_COV_STAMPED_TYPE",
    "cdr_dtype",
    "encode_batch",
    "stamp_ns",
]

CDR_LE_HEADER = b"\x00\x01\x00\x00"
"""Encapsulation header of plain little-endian CDR."""

_SEP = "=" * 80

_HEADER_DEF = """\
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
"""
_TIME_DEF = """\
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
_VECTOR3_DEF = """\
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
"""
_QUATERNION_DEF = """\
MSG: geometry_msgs/Quaternion
float64 x 0
float64 y 0
float64 z 0
float64 w 1
"""
_POINT_DEF = """\
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
"""


def _msgdef(top: str, *deps: str) -> str:
    return "\n".join([top] + [f"{_SEP}\n{d}" for d in deps])


IMU_TYPE = "sensor_msgs/msg/Imu"
IMU_MSGDEF = _msgdef(
    """\
std_msgs/Header header
geometry_msgs/Quaternion orientation
float64[9] orientation_covariance
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance
""",
    _HEADER_DEF,
    _TIME_DEF,
    _QUATERNION_DEF,
    _VECTOR3_DEF,
)

NAVSATFIX_TYPE = "sensor_msgs/msg/NavSatFix"
NAVSATFIX_MSGDEF = _msgdef(
    """\
std_msgs/Header header
sensor_msgs/NavSatStatus status
float64 latitude
float64 longitude
float64 altitude
float64[9] position_covariance
uint8 COVARIANCE_TYPE_UNKNOWN = 0
uint8 COVARIANCE_TYPE_APPROXIMATED = 1
uint8 COVARIANCE_TYPE_DIAGONAL_KNOWN = 2
uint8 COVARIANCE_TYPE_KNOWN = 3
uint8 position_covariance_type
""",
    _HEADER_DEF,
    _TIME_DEF,
    """\
MSG: sensor_msgs/NavSatStatus
int8 STATUS_NO_FIX = -1
int8 STATUS_FIX = 0
int8 STATUS_SBAS_FIX = 1
int8 STATUS_GBAS_FIX = 2
int8 status
uint16 SERVICE_GPS = 1
uint16 SERVICE_GLONASS = 2
uint16 SERVICE_COMPASS = 4
uint16 SERVICE_GALILEO = 8
uint16 service
""",
)

TWIST_COV_STAMPED_TYPE = "geometry_msgs/msg/TwistWithCovarianceStamped"
TWIST_COV_STAMPED_MSGDEF = _msgdef(
    """\
std_msgs/Header header
geometry_msgs/TwistWithCovariance twist
""",
    _HEADER_DEF,
    _TIME_DEF,
    """\
MSG: geometry_msgs/TwistWithCovariance
geometry_msgs/Twist twist
float64[36] covariance
""",
    """\
MSG: geometry_msgs/Twist
geometry_msgs/Vector3 linear
geometry_msgs/Vector3 angular
""",
    _VECTOR3_DEF,
)

POSE_STAMPED_TYPE = "geometry_msgs/msg/PoseStamped"
POSE_STAMPED_MSGDEF = _msgdef(
    """\
std_msgs/Header header
geometry_msgs/Pose pose
""",
    _HEADER_DEF,
    _TIME_DEF,
    """\
MSG: geometry_msgs/Pose
geometry_msgs/Point position
geometry_msgs/Quaternion orientation
""",
    _POINT_DEF,
    _QUATERNION_DEF,
)

# Fields after the header, in CDR order: (name, little-endian numpy type, count).
# Nested messages are flattened (Vector3 -> 3 float64, Quaternion -> x, y, z, w).
IMU_FIELDS: tuple[tuple[str, str, int], ...] = (
    ("orientation", "<f8", 4),
    ("orientation_covariance", "<f8", 9),
    ("angular_velocity", "<f8", 3),
    ("angular_velocity_covariance", "<f8", 9),
    ("linear_acceleration", "<f8", 3),
    ("linear_acceleration_covariance", "<f8", 9),
)
NAVSATFIX_FIELDS: tuple[tuple[str, str, int], ...] = (
    ("status", "i1", 1),
    ("service", "<u2", 1),
    ("latitude", "<f8", 1),
    ("longitude", "<f8", 1),
    ("altitude", "<f8", 1),
    ("position_covariance", "<f8", 9),
    ("position_covariance_type", "u1", 1),
)
TWIST_COV_STAMPED_FIELDS: tuple[tuple[str, str, int], ...] = (
    ("linear", "<f8", 3),
    ("angular", "<f8", 3),
    ("covariance", "<f8", 36),
)
POSE_STAMPED_FIELDS: tuple[tuple[str, str, int], ...] = (
    ("position", "<f8", 3),
    ("orientation", "<f8", 4),
)


def cdr_dtype(fields: tuple[tuple[str, str, int], ...], frame_id_len: int) -> np.dtype:
    """Structured dtype of one whole CDR_LE payload (encapsulation header included).

    Parameters
    ----------
    fields : tuple of (name, numpy type, count)
        The fields after ``std_msgs/Header``, in CDR order.
    frame_id_len : int
        The CDR string length of ``header.frame_id`` (characters + 1 for the NUL), >= 1.

    Returns
    -------
    numpy.dtype
        Fields ``encap`` (4 u1), ``sec`` (<i4), ``nanosec`` (<u4), ``frame_id_len`` (<u4),
        ``frame_id`` (``frame_id_len`` u1, NUL included) and then ``fields`` at their aligned
        offsets; ``itemsize`` equals the payload length in bytes.
    """
    if frame_id_len < 1:
        raise ValueError(f"frame_id_len must be >= 1 (chars + NUL), got {frame_id_len}")
    names = ["encap", "sec", "nanosec", "frame_id_len", "frame_id"]
    formats: list = [("u1", (4,)), "<i4", "<u4", "<u4", ("u1", (frame_id_len,))]
    offsets = [0, 4, 8, 12, 16]
    pos = 12 + frame_id_len  # relative to the CDR body start (byte 4)
    for name, typ, count in fields:
        size = np.dtype(typ).itemsize
        pos += (-pos) % size
        names.append(name)
        formats.append(typ if count == 1 else (typ, (count,)))
        offsets.append(4 + pos)
        pos += size * count
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": 4 + pos})


def stamp_ns(sec: np.ndarray, nanosec: np.ndarray) -> np.ndarray:
    """``builtin_interfaces/Time`` -> int64 nanoseconds: ``sec * 1e9 + nanosec``."""
    return np.asarray(sec, dtype=np.int64) * 1_000_000_000 + np.asarray(nanosec, dtype=np.int64)


def encode_batch(
    fields: tuple[tuple[str, str, int], ...],
    time_ns: np.ndarray,
    frame_id: str,
    values: dict[str, np.ndarray],
) -> np.ndarray:
    """Encode N messages at once into a structured array of CDR_LE payloads.

    Parameters
    ----------
    fields : tuple of (name, numpy type, count)
        Layout, e.g. ``IMU_FIELDS``.
    time_ns : (N,) int64
        Header stamps [ns]; negative stamps are allowed (``sec`` is the floor).
    frame_id : str
        ``header.frame_id`` for every message.
    values : dict
        Field name -> array of shape (N,) or (N, count); missing fields are zero, except a
        quaternion ``orientation`` which defaults to identity (w = 1).

    Returns
    -------
    numpy.ndarray
        Shape (N,), dtype ``cdr_dtype(fields, len(frame_id) + 1)``; ``arr[i].tobytes()`` is the
        payload of message i (padding bytes are zero, as ``mcap_ros2`` writes them).
    """
    fid = frame_id.encode("utf-8") + b"\x00"
    dt = cdr_dtype(fields, len(fid))
    t = np.asarray(time_ns, dtype=np.int64)
    out = np.zeros(t.shape[0], dtype=dt)
    out["encap"] = np.frombuffer(CDR_LE_HEADER, dtype=np.uint8)
    sec, nsec = np.divmod(t, 1_000_000_000)
    if np.any((sec < np.iinfo(np.int32).min) | (sec > np.iinfo(np.int32).max)):
        raise ValueError("time_ns out of the int32-seconds range of builtin_interfaces/Time")
    out["sec"] = sec
    out["nanosec"] = nsec
    out["frame_id_len"] = len(fid)
    out["frame_id"] = np.frombuffer(fid, dtype=np.uint8)
    known = {name for name, _, _ in fields}
    unknown = set(values) - known
    if unknown:
        raise KeyError(f"unknown field(s) {sorted(unknown)}; layout has {sorted(known)}")
    if "orientation" in known and "orientation" not in values:
        out["orientation"][:, 3] = 1.0
    for name, arr in values.items():
        out[name] = arr
    return out
