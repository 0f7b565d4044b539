"""ROS 2 message definitions and their CDR layouts as numpy structured dtypes.

The flight-log message types pospp reads and writes (Imu, NavSatFix,
TwistWithCovarianceStamped) have exactly one variable-length field, the ``header.frame_id``
string, right after the stamp. For a given frame_id length the CDR layout of the whole message
is therefore fixed, and a batch of messages sharing that length can be decoded (or encoded)
with one numpy structured dtype over the concatenated payloads. The trajectory types pospp
writes add constant strings (``child_frame_id`` of Odometry and TFMessage, ``source`` of
TimeReference), which are encoded the same way as a uint32 length and a fixed byte array;
``nav_msgs/msg/Path`` (a sequence of stamped poses) is encoded field by field (``_Cdr``).

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
    "NAV_PATH_MSGDEF",
    "NAV_PATH_TYPE",
    "ODOMETRY_MSGDEF",
    "ODOMETRY_TYPE",
    "TF_MESSAGE_MSGDEF",
    "TF_MESSAGE_TYPE",
    "TIME_REFERENCE_FIELDS",
    "TIME_REFERENCE_MSGDEF",
    "TIME_REFERENCE_TYPE",
    "cdr_dtype",
    "encode_batch",
    "encode_odometry",
    "encode_path",
    "encode_tf",
    "encode_time_reference",
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
_TWIST_WITH_COV_DEF = """\
MSG: geometry_msgs/TwistWithCovariance
geometry_msgs/Twist twist
float64[36] covariance
"""
_TWIST_DEF = """\
MSG: geometry_msgs/Twist
geometry_msgs/Vector3 linear
geometry_msgs/Vector3 angular
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
    _TWIST_WITH_COV_DEF,
    _TWIST_DEF,
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

TIME_REFERENCE_TYPE = "sensor_msgs/msg/TimeReference"
TIME_REFERENCE_MSGDEF = _msgdef(
    """\
std_msgs/Header header
builtin_interfaces/Time time_ref
string source
""",
    _HEADER_DEF,
    _TIME_DEF,
)

_POSE_DEF = """\
MSG: geometry_msgs/Pose
geometry_msgs/Point position
geometry_msgs/Quaternion orientation
"""
_POSE_STAMPED_DEF = """\
MSG: geometry_msgs/PoseStamped
std_msgs/Header header
geometry_msgs/Pose pose
"""

TF_MESSAGE_TYPE = "tf2_msgs/msg/TFMessage"
TF_MESSAGE_MSGDEF = _msgdef(
    "geometry_msgs/TransformStamped[] transforms\n",
    """\
MSG: geometry_msgs/TransformStamped
std_msgs/Header header
string child_frame_id
geometry_msgs/Transform transform
""",
    _HEADER_DEF,
    _TIME_DEF,
    """\
MSG: geometry_msgs/Transform
geometry_msgs/Vector3 translation
geometry_msgs/Quaternion rotation
""",
    _VECTOR3_DEF,
    _QUATERNION_DEF,
)

ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
ODOMETRY_MSGDEF = _msgdef(
    """\
std_msgs/Header header
string child_frame_id
geometry_msgs/PoseWithCovariance pose
geometry_msgs/TwistWithCovariance twist
""",
    _HEADER_DEF,
    _TIME_DEF,
    """\
MSG: geometry_msgs/PoseWithCovariance
geometry_msgs/Pose pose
float64[36] covariance
""",
    _POSE_DEF,
    _POINT_DEF,
    _QUATERNION_DEF,
    _TWIST_WITH_COV_DEF,
    _TWIST_DEF,
    _VECTOR3_DEF,
)

NAV_PATH_TYPE = "nav_msgs/msg/Path"
NAV_PATH_MSGDEF = _msgdef(
    """\
std_msgs/Header header
geometry_msgs/PoseStamped[] poses
""",
    _HEADER_DEF,
    _TIME_DEF,
    _POSE_STAMPED_DEF,
    _POSE_DEF,
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
TIME_REFERENCE_FIELDS: tuple[tuple[str, str, int], ...] = (
    ("time_ref_sec", "<i4", 1),
    ("time_ref_nanosec", "<u4", 1),
)
"""The fixed part of ``sensor_msgs/msg/TimeReference`` after the header (``source``, a
string, follows: the reader decodes these messages with the generic decoder)."""


def _string_fields(name: str, text: str) -> tuple[tuple[tuple[str, str, int], ...], dict]:
    """A constant CDR string as two fields (uint32 length with the NUL, then the bytes)."""
    raw = text.encode("utf-8") + b"\x00"
    return ((f"{name}_len", "<u4", 1), (name, "u1", len(raw))), {
        f"{name}_len": len(raw), name: np.frombuffer(raw, np.uint8)}


def encode_time_reference(time_ns: np.ndarray, frame_id: str, source: str) -> np.ndarray:
    """``sensor_msgs/msg/TimeReference`` payloads: header.stamp = time_ref = ``time_ns``."""
    t = np.asarray(time_ns, dtype=np.int64)
    sec, nsec = np.divmod(t, 1_000_000_000)
    sfields, svals = _string_fields("source", source)
    return encode_batch(TIME_REFERENCE_FIELDS + sfields, t, frame_id, {
        "time_ref_sec": sec, "time_ref_nanosec": nsec,
        **{k: np.broadcast_to(v, (t.shape[0], *np.shape(v))) for k, v in svals.items()}})


def encode_odometry(time_ns: np.ndarray, frame_id: str, child_frame_id: str, *,
                    position: np.ndarray, orientation_xyzw: np.ndarray,
                    pose_covariance: np.ndarray, linear: np.ndarray,
                    twist_covariance: np.ndarray) -> np.ndarray:
    """``nav_msgs/msg/Odometry`` payloads (N,): pose in ``frame_id``, twist in the child frame.

    ``pose_covariance`` / ``twist_covariance``: (N, 36) row-major 6x6 [x, y, z, rot x, rot y,
    rot z]; ``linear``: (N, 3) velocity; the angular twist is written as zero.
    """
    t = np.asarray(time_ns, dtype=np.int64)
    cfields, cvals = _string_fields("child_frame_id", child_frame_id)
    fields = cfields + (("position", "<f8", 3), ("orientation", "<f8", 4),
                        ("pose_covariance", "<f8", 36), ("linear", "<f8", 3),
                        ("angular", "<f8", 3), ("twist_covariance", "<f8", 36))
    return encode_batch(fields, t, frame_id, {
        **{k: np.broadcast_to(v, (t.shape[0], *np.shape(v))) for k, v in cvals.items()},
        "position": position, "orientation": orientation_xyzw,
        "pose_covariance": pose_covariance, "linear": linear,
        "twist_covariance": twist_covariance})


def encode_tf(time_ns: np.ndarray, frame_id: str, child_frame_id: str, *,
              translation: np.ndarray, rotation_xyzw: np.ndarray) -> np.ndarray:
    """``tf2_msgs/msg/TFMessage`` payloads (N,), one ``TransformStamped`` each.

    TFMessage has no header of its own: the body is the sequence length (1), then the
    TransformStamped, whose header leads as in any stamped message, so ``encode_batch`` lays
    it out once the sequence length is given as the first field.
    """
    t = np.asarray(time_ns, dtype=np.int64)
    cfields, cvals = _string_fields("child_frame_id", child_frame_id)
    fields = cfields + (("translation", "<f8", 3), ("rotation", "<f8", 4))
    inner = encode_batch(fields, t, frame_id, {
        **{k: np.broadcast_to(v, (t.shape[0], *np.shape(v))) for k, v in cvals.items()},
        "translation": translation, "rotation": rotation_xyzw})
    return _with_leading_count(inner, fields)


def _with_leading_count(inner: np.ndarray, fields: tuple) -> np.ndarray:
    """``inner`` (a stamped message's payloads) re-laid after a uint32 sequence length of 1.

    The length shifts the body by 4 bytes, so the doubles are re-aligned to 8 (counted from
    the body start) field by field, exactly as ``cdr_dtype`` lays them.
    """
    dt = inner.dtype
    assert dt.fields is not None  # a structured dtype
    names = ["encap", "count", "sec", "nanosec", "frame_id_len", "frame_id"]
    formats: list = [("u1", (4,)), "<u4", "<i4", "<u4", "<u4",
                     ("u1", dt.fields["frame_id"][0].shape)]
    offsets = [0, 4, 8, 12, 16, 20]
    pos = 16 + dt.fields["frame_id"][0].itemsize  # relative to the body start
    out = np.zeros(inner.shape[0], _lay(names, formats, offsets, pos, fields))
    for name in out.dtype.names:
        if name != "count":
            out[name] = inner[name]
    out["count"] = 1
    return out


class _Cdr:
    """A little-endian CDR body built field by field (for the few variable-length messages)."""

    def __init__(self) -> None:
        self.buf = bytearray()

    def _align(self, n: int) -> None:
        self.buf += b"\x00" * ((-len(self.buf)) % n)

    def u32(self, v: int) -> None:
        self._align(4)
        self.buf += int(v).to_bytes(4, "little", signed=False)

    def i32(self, v: int) -> None:
        self._align(4)
        self.buf += int(v).to_bytes(4, "little", signed=True)

    def f64s(self, vals: np.ndarray) -> None:
        self._align(8)
        self.buf += np.asarray(vals, dtype="<f8").tobytes()

    def string(self, text: str) -> None:
        raw = text.encode("utf-8") + b"\x00"
        self.u32(len(raw))
        self.buf += raw

    def header(self, time_ns: int, frame_id: str) -> None:
        sec, nsec = divmod(int(time_ns), 1_000_000_000)
        self.i32(sec)
        self.u32(nsec)
        self.string(frame_id)


def encode_path(time_ns: int, frame_id: str, pose_time_ns: np.ndarray, position: np.ndarray,
                orientation_xyzw: np.ndarray) -> bytes:
    """One ``nav_msgs/msg/Path`` payload: M poses (stamps, (M, 3) positions, (M, 4) x y z w)."""
    w = _Cdr()
    w.header(time_ns, frame_id)
    w.u32(len(pose_time_ns))
    for t, p, q in zip(np.asarray(pose_time_ns).tolist(), position, orientation_xyzw,
                       strict=True):
        w.header(t, frame_id)
        w.f64s(p)
        w.f64s(q)
    return CDR_LE_HEADER + bytes(w.buf)


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
    return _lay(names, formats, offsets, pos, fields)


def _lay(names: list, formats: list, offsets: list, pos: int,
         fields: tuple[tuple[str, str, int], ...]) -> np.dtype:
    """Append ``fields`` from body offset ``pos``, each aligned to its size; the dtype."""
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
