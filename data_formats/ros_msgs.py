"""ROS 2 message definitions, as MCAP ``ros2msg`` schemas, and the conversions we need.

Each schema is the full concatenated definition ROS 2 tools write (rosbag2's MCAP plugin does the
same): the type's own ``.msg`` text, then for every type it depends on, directly or not, a
separator line of 80 ``=``, a ``MSG: pkg/Type`` line and that type's ``.msg`` text. Field names,
order and types are those of ROS 2 (Humble and later); comments are left out.
"""

from __future__ import annotations

import math

import numpy as np

from aslam.core import se2

SEPARATOR = "=" * 80

# The .msg text of every type used here (ROS 2 Humble), without comments.
_MSG_TEXT: dict[str, str] = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\nPose pose\n",
    "geometry_msgs/PoseWithCovariance": "Pose pose\nfloat64[36] covariance\n",
    "geometry_msgs/PoseWithCovarianceStamped": "std_msgs/Header header\nPoseWithCovariance pose\n",
    "geometry_msgs/Twist": "Vector3 linear\nVector3 angular\n",
    "geometry_msgs/TwistWithCovariance": "Twist twist\nfloat64[36] covariance\n",
    "nav_msgs/Odometry": (
        "std_msgs/Header header\n"
        "string child_frame_id\n"
        "geometry_msgs/PoseWithCovariance pose\n"
        "geometry_msgs/TwistWithCovariance twist\n"
    ),
    "sensor_msgs/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data\n",
    "sensor_msgs/Image": (
        "std_msgs/Header header\n"
        "uint32 height\n"
        "uint32 width\n"
        "string encoding\n"
        "uint8 is_bigendian\n"
        "uint32 step\n"
        "uint8[] data\n"
    ),
    "sensor_msgs/RegionOfInterest": (
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n"
    ),
    "sensor_msgs/CameraInfo": (
        "std_msgs/Header header\n"
        "uint32 height\n"
        "uint32 width\n"
        "string distortion_model\n"
        "float64[] d\n"
        "float64[9] k\n"
        "float64[9] r\n"
        "float64[12] p\n"
        "uint32 binning_x\n"
        "uint32 binning_y\n"
        "RegionOfInterest roi\n"
    ),
}

# Direct dependencies of each compound type, in field order.
_DEPENDS: dict[str, tuple[str, ...]] = {
    "std_msgs/Header": ("builtin_interfaces/Time",),
    "geometry_msgs/Pose": ("geometry_msgs/Point", "geometry_msgs/Quaternion"),
    "geometry_msgs/PoseStamped": ("std_msgs/Header", "geometry_msgs/Pose"),
    "geometry_msgs/PoseWithCovariance": ("geometry_msgs/Pose",),
    "geometry_msgs/PoseWithCovarianceStamped": ("std_msgs/Header", "geometry_msgs/PoseWithCovariance"),
    "geometry_msgs/Twist": ("geometry_msgs/Vector3",),
    "geometry_msgs/TwistWithCovariance": ("geometry_msgs/Twist",),
    "nav_msgs/Odometry": (
        "std_msgs/Header",
        "geometry_msgs/PoseWithCovariance",
        "geometry_msgs/TwistWithCovariance",
    ),
    "sensor_msgs/CompressedImage": ("std_msgs/Header",),
    "sensor_msgs/Image": ("std_msgs/Header",),
    "sensor_msgs/CameraInfo": ("std_msgs/Header", "sensor_msgs/RegionOfInterest"),
}

COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
RAW_IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"

IMAGE_TYPES = (COMPRESSED_IMAGE, RAW_IMAGE)
# Types a pose can be read from, on the odometry or the ground-truth topic.
POSE_TYPES = (ODOMETRY, POSE_STAMPED, POSE_WITH_COVARIANCE_STAMPED)


def _short(datatype: str) -> str:
    """``pkg/msg/Type`` → ``pkg/Type``."""
    pkg, _, name = datatype.partition("/msg/")
    return f"{pkg}/{name}" if name else datatype


def _dependencies(short: str) -> list[str]:
    """Every type ``short`` depends on, depth first in field order, each once."""
    seen: list[str] = []

    def visit(name: str) -> None:
        for dep in _DEPENDS.get(name, ()):
            if dep not in seen:
                seen.append(dep)
                visit(dep)

    visit(short)
    return seen


def message_definition(datatype: str) -> str:
    """The full concatenated ROS 2 definition of ``datatype`` (``pkg/msg/Type``)."""
    short = _short(datatype)
    parts = [_MSG_TEXT[short]]
    for dep in _dependencies(short):
        parts.append(f"{SEPARATOR}\nMSG: {dep}\n{_MSG_TEXT[dep]}")
    return "".join(parts)


# --- conversions --------------------------------------------------------------------------------

NS_PER_S = 1_000_000_000
LAST_STAMP_NS = 2**31 * NS_PER_S - 1
"""The last instant a ROS time holds (``int32 sec``: 2038-01-19 03:14:07 UTC)."""


def stamp_msg(stamp_ns: int) -> dict[str, int]:
    """``builtin_interfaces/Time`` of an integer-nanosecond stamp (floor division keeps nanosec ≥ 0)."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return {"sec": sec, "nanosec": nanosec}


class StampError(ValueError):
    """A ``builtin_interfaces/Time`` that is no time; the readers name the file and the topic."""


def stamp_ns_of(stamp: object) -> int:
    """Integer nanoseconds of a decoded ``builtin_interfaces/Time``. A ``nanosec`` of a whole second
    or more is no time (:class:`StampError`): it was added to the seconds, an image shifted in time
    in silence, an odometry message said to go backwards."""
    nanosec = int(stamp.nanosec)  # type: ignore[attr-defined]
    if not 0 <= nanosec < NS_PER_S:
        raise StampError(f"its header stamp's nanosec is {nanosec}, not under 10⁹")
    return int(stamp.sec) * NS_PER_S + nanosec  # type: ignore[attr-defined]


def header_msg(stamp_ns: int, frame_id: str) -> dict[str, object]:
    return {"stamp": stamp_msg(stamp_ns), "frame_id": frame_id}


def yaw_of_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Yaw (rotation about +z) of a quaternion, in (-π, π]. One that is not of unit length (a driver's
    rounding aside) is normalised first; a zero one is ValueError: it is no rotation."""
    norm2 = x * x + y * y + z * z + w * w
    if not norm2 > 1e-12:
        raise ValueError("the orientation quaternion is zero")
    if norm2 == math.inf:  # squared, 1e200 overflowed, and a 90° yaw read 0: scaled down first
        largest = max(abs(x), abs(y), abs(z), abs(w))
        x, y, z, w = x / largest, y / largest, z / largest, w / largest
        norm2 = x * x + y * y + z * z + w * w
    if abs(norm2 - 1.0) > 1e-6:
        scale = 1.0 / math.sqrt(norm2)
        x, y, z, w = x * scale, y * scale, z * scale, w * scale
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def planar_pose_msg(pose_xy_yaw: np.ndarray) -> dict[str, object]:
    """``geometry_msgs/Pose`` of a planar pose ``(x_m, y_m, yaw_rad)``: z = 0, yaw-only quaternion."""
    x, y, yaw = (float(v) for v in pose_xy_yaw)
    qw, qx, qy, qz = se2.yaw_quaternion(yaw)
    return {"position": {"x": x, "y": y, "z": 0.0}, "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}


def planar_pose_of(pose: object) -> np.ndarray:
    """``(x_m, y_m, yaw_rad)`` of a decoded ``geometry_msgs/Pose`` (z, roll and pitch ignored).

    Non-finite values are passed through; the reader checks them and names the stamp.
    """
    p = pose.position  # type: ignore[attr-defined]
    q = pose.orientation  # type: ignore[attr-defined]
    values = (float(p.x), float(p.y), float(q.x), float(q.y), float(q.z), float(q.w))
    if not all(math.isfinite(v) for v in values):
        return np.array([math.nan, math.nan, math.nan])
    return np.array([values[0], values[1], yaw_of_quaternion(*values[2:])])


def pose_of_message(datatype: str, msg: object) -> np.ndarray:
    """The planar pose carried by an Odometry, PoseStamped or PoseWithCovarianceStamped message."""
    if datatype in (ODOMETRY, POSE_WITH_COVARIANCE_STAMPED):
        return planar_pose_of(msg.pose.pose)  # type: ignore[attr-defined]
    return planar_pose_of(msg.pose)  # type: ignore[attr-defined]
